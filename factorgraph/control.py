"""Ground control: surveyed points (x, y, z, 1-sigma per axis, any CRS) that tie the map to the
ground, the check that keeps them apart from the checkpoints (ASPRS 2023), and the factors
that carry them into the localization graph (design and measurements: docs/ground-control.md).

* **Stops** -- the rover stands on a point at the keyframes whose ``control_id`` (keyframes
  table, :mod:`factorgraph.log`) names it: a position prior ``t(X_k) = p_c`` per keyframe
  (``gtsam.GPSFactor``, no bias term), 1-sigma ``sqrt(u sigma_c^2 + sigma_centring^2)``,
  ``u`` the point's number of priors, so that they carry its survey error once. With the GPS
  bias states in the graph a stop observes the bias: ``z_gps - t(X_k) = b_k + v``.
* **Targets** -- a point whose ``target_id`` is a track id (``observations.landmark_id``)
  gets ``PriorFactorPoint3`` on that landmark, if the track became one. Matched by id only.

Both are added after the online pass, before the batch refinement (one ``ISAM2.update``).
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from pyproj import CRS, Transformer

from terrain.errors import bad_input

__all__ = [
    "ControlPlan",
    "ControlPoints",
    "add_control_factors",
    "check_in_area",
    "check_independent",
    "control_report",
    "plan_control",
]


@dataclass(frozen=True)
class ControlPoints:
    """Surveyed ground control points.

    Attributes
    ----------
    ids : ndarray of shape (n,), str
        Point names, unique.
    xyz : ndarray of shape (n, 3)
        Coordinates in ``crs`` (x, y: easting/northing, or lon/lat in degrees for a
        geographic CRS) and elevation (m, same vertical datum as the GPS).
    sigma : ndarray of shape (n, 3)
        1-sigma of the survey per axis (m, east, north, up), > 0.
    crs : str
        CRS of ``xyz`` (anything pyproj understands; :meth:`to_crs` reprojects).
    target_id : ndarray of shape (n,), int
        Track id of the marked target at the point in the camera tracks; -1 for none.
    centring_sigma_m : float
        1-sigma of the rover's body origin about the mark when it stands on it (m, per axis).
    source : str
        File name or ``"arrays"``.
    """

    ids: np.ndarray
    xyz: np.ndarray
    sigma: np.ndarray
    crs: str
    target_id: np.ndarray | None = None
    centring_sigma_m: float = 0.02
    source: str = "arrays"
    notes: dict[str, list[str]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        ids = np.asarray(self.ids).astype(str).reshape(-1)
        n = ids.size
        xyz = np.asarray(self.xyz, float).reshape(-1, 3) if n else np.zeros((0, 3))
        sigma = np.broadcast_to(np.asarray(self.sigma, float), (n, 3)).copy()
        if n == 0:
            raise bad_input("control", self.source, "at least one control point", "add points")
        if xyz.shape != (n, 3):
            raise bad_input("control.xyz", xyz.shape, f"shape ({n}, 3)", "one row per id")
        dup = sorted({i for i in ids if (ids == i).sum() > 1})
        if dup:
            raise bad_input("control.id", dup, "unique point names", "rename or merge them")
        for name, a in (("x/y/z", xyz), ("sigma", sigma)):
            bad = ~np.isfinite(a).all(1)
            if name == "sigma":
                bad |= ~(a > 0).all(1)
            if bad.any():
                i = int(np.argmax(bad))
                raise bad_input(
                    f"control point {str(ids[i])!r} {name}",
                    a[i].tolist(),
                    "finite values" + (" > 0 (m)" if name == "sigma" else ""),
                    "repair the row or remove the point",
                )
        tid = np.full(n, -1, int) if self.target_id is None else np.asarray(self.target_id, int)
        if tid.shape != (n,):
            raise bad_input("control.target_id", tid.shape, f"shape ({n},)", "")
        if not (math.isfinite(self.centring_sigma_m) and self.centring_sigma_m >= 0):
            raise bad_input("centring_sigma_m", self.centring_sigma_m, "a value >= 0 (m)", "")
        try:
            crs = CRS.from_user_input(self.crs).to_string()
        except Exception as exc:  # pyproj.CRSError
            raise bad_input(
                "control.crs", self.crs, "a CRS pyproj understands", 'e.g. "EPSG:4326"'
            ) from exc
        for name, v in (("ids", ids), ("xyz", xyz), ("sigma", sigma), ("target_id", tid)):
            object.__setattr__(self, name, v)
        object.__setattr__(self, "crs", crs)

    @property
    def n(self) -> int:
        return int(self.ids.size)

    def to_crs(self, crs: Any) -> ControlPoints:
        """The same points in ``crs`` (x, y by an exact PROJ transform; z and sigma kept)."""
        dst = CRS.from_user_input(crs)
        if dst.equals(CRS.from_user_input(self.crs), ignore_axis_order=True):
            return self
        tr = Transformer.from_crs(self.crs, dst, always_xy=True)
        x, y = tr.transform(self.xyz[:, 0], self.xyz[:, 1], errcheck=False)
        xy = np.column_stack([x, y])
        if not np.isfinite(xy).all():
            i = int(np.argmax(~np.isfinite(xy).all(1)))
            raise bad_input(
                f"control point {str(self.ids[i])!r}",
                self.xyz[i, :2].tolist(),
                f"coordinates that project from {self.crs} to {dst.to_string()}",
                "check the CRS of the control file (lon/lat order, zone)",
            )
        return replace(self, xyz=np.column_stack([xy, self.xyz[:, 2]]), crs=dst.to_string())

    def table(self) -> dict[str, np.ndarray]:
        """Columns ``id, x, y, z, sigma_x, sigma_y, sigma_z, target_id`` (what
        :func:`factorgraph.control_io.read_control` reads back, with ``crs``)."""
        out: dict[str, Any] = {"id": self.ids}
        out.update({a: self.xyz[:, i] for i, a in enumerate("xyz")})
        out.update({f"sigma_{a}": self.sigma[:, i] for i, a in enumerate("xyz")})
        out["target_id"] = self.target_id
        return out

    def write_csv(self, path: str | Path) -> Path:
        """Write :meth:`table` and a ``crs`` column to ``path`` atomically."""
        from terrain.atomic import atomic_path

        cols = self.table()
        names = [*cols, "crs"]
        with atomic_path(Path(path)) as tmp, open(tmp, "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(names)
            for i in range(self.n):
                w.writerow([_cell(cols[c][i]) for c in cols] + [self.crs])
        return Path(path)


def _cell(v: Any) -> str:
    return repr(float(v)) if isinstance(v, float | np.floating) else str(v)


def check_in_area(
    control: ControlPoints, bounds: tuple[float, float, float, float], what: str = "map"
) -> None:
    """Raise an :class:`InputError` naming the first control point outside ``bounds``
    (west, south, east, north, in the control's CRS)."""
    w, s, e, n = bounds
    x, y = control.xyz[:, 0], control.xyz[:, 1]
    out = ~((x >= w) & (x <= e) & (y >= s) & (y <= n))
    if out.any():
        i = int(np.argmax(out))
        raise bad_input(
            f"control point {str(control.ids[i])!r}",
            f"({x[i]:.3f}, {y[i]:.3f}) {control.crs}; {int(out.sum())} of {control.n} outside",
            f"a point inside the {what} ({w:.1f}, {s:.1f}, {e:.1f}, {n:.1f})",
            "check its CRS and coordinates, or remove points of other sites from the file",
        )


def check_independent(control: ControlPoints, checkpoints: Any, tol_m: float = 0.5) -> None:
    """ASPRS 2023: checkpoints must be independent of control. Raise an :class:`InputError`
    naming a point that is both (same id, or within ``tol_m`` horizontally).

    ``checkpoints``: an object with ``xy`` (n, 2) or ``xyz`` (n, 3), optional ``ids`` and
    ``crs`` (``toolkit`` checkpoints, :class:`ControlPoints`), or a mapping with ``x, y[, id,
    crs]``. Checkpoints in another CRS are reprojected to the control's.
    """
    get = checkpoints.get if isinstance(checkpoints, dict) else None
    if get is not None:
        xy = np.column_stack([get("x"), get("y")]).astype(float)
        ids, crs = get("id"), get("crs")
    else:
        xy = getattr(checkpoints, "xy", None)
        xy = np.asarray(xy if xy is not None else checkpoints.xyz, float)[:, :2]
        ids, crs = getattr(checkpoints, "ids", None), getattr(checkpoints, "crs", None)
    if crs is not None and not CRS.from_user_input(crs).equals(CRS.from_user_input(control.crs)):
        tr = Transformer.from_crs(crs, control.crs, always_xy=True)
        xy = np.column_stack(tr.transform(xy[:, 0], xy[:, 1]))
    if ids is not None:
        same = sorted(set(np.asarray(ids).astype(str).tolist()) & set(control.ids.tolist()))
        if same:
            raise bad_input(
                f"checkpoint {same[0]!r}", f"also a control point ({len(same)} shared ids)",
                "checkpoints independent of the control (ASPRS 2023)",
                "use each surveyed point either as control or as checkpoint",
            )  # fmt: skip
    if len(xy):
        from scipy.spatial import cKDTree

        d, j = cKDTree(xy).query(control.xyz[:, :2])
        close = np.flatnonzero(d <= tol_m)
        if close.size:
            i = int(close[0])
            raise bad_input(
                "checkpoints",
                f"checkpoint row {int(j[i])} is {d[i]:.3f} m from control point "
                f"{str(control.ids[i])!r} ({close.size} such pairs)",
                f"checkpoints more than {tol_m} m from every control point (ASPRS 2023)",
                "use each surveyed point either as control or as checkpoint",
            )


@dataclass
class ControlPlan:
    """How each control point enters one log's graph (local ENU of the log, m)."""

    control: ControlPoints  # in the log's CRS
    local_xyz: np.ndarray  # (n, 3) relative to log.origin
    stops: dict[int, np.ndarray]  # control row -> stop keyframes
    targets: dict[int, int]  # control row -> landmark (track) id, if tracked at all
    unused: dict[str, str] = field(default_factory=dict)  # id -> reason
    used: dict[str, str] = field(default_factory=dict)  # id -> "stop" | "target" | both


def plan_control(log, control: ControlPoints, area_margin_m: float = 50.0) -> ControlPlan:
    """Match ``control`` to ``log`` (before any estimation, so that bad input fails fast).

    Reprojects to the log's CRS; raises for a point outside the survey area (the GPS fixes'
    extent padded by ``area_margin_m``), for a ``control_id`` in the keyframes naming no
    control point, and for a stop more than ``area_margin_m`` from the GPS fixes around it.
    """
    ctrl = control.to_crs(log.crs)
    local = ctrl.xyz - np.r_[log.origin, 0.0]
    if log.gps_k.size:
        lo, hi = log.gps_xyz[:, :2].min(0), log.gps_xyz[:, :2].max(0)
        o = log.origin
        area = (*(lo + o - area_margin_m), *(hi + o + area_margin_m))
        check_in_area(ctrl, (area[0], area[1], area[2], area[3]), "survey area (GPS extent)")
    row = {name: i for i, name in enumerate(ctrl.ids.tolist())}
    stops: dict[int, list[int]] = {}
    kf_ids = getattr(log, "control_id", None)
    if kf_ids is not None:
        for k in np.flatnonzero(kf_ids != ""):
            name = str(kf_ids[k])
            if name not in row:
                raise bad_input(
                    f"keyframes.control_id at k={int(k)}", name,
                    f"one of the control points {sorted(row)[:8]}",
                    "add the point to the control file or fix the id in the log",
                )  # fmt: skip
            stops.setdefault(row[name], []).append(int(k))
    for i, ks in stops.items():
        near = np.flatnonzero(np.abs(log.gps_k - np.median(ks)) <= 30)
        if near.size:
            d = np.linalg.norm(log.gps_xyz[near, :2].mean(0) - local[i, :2])
            if d > area_margin_m:
                raise bad_input(
                    f"control point {str(ctrl.ids[i])!r}",
                    f"{d:.1f} m from the GPS around its stop (keyframe {ks[0]})",
                    f"within {area_margin_m} m",
                    "check keyframes.control_id and the control file's CRS",
                )
    targets = {i: int(t) for i, t in enumerate(ctrl.target_id) if t >= 0}
    seen = set(np.unique(log.obs_id).tolist())
    plan = ControlPlan(ctrl, local, {i: np.array(v) for i, v in stops.items()}, targets)
    for i, name in enumerate(ctrl.ids.tolist()):
        if i not in stops and i in targets and targets[i] not in seen:
            plan.unused[name] = "target_not_observed"  # its track id is not in the log
        elif i not in stops and i not in targets:
            plan.unused[name] = "not_visited_or_tracked"
    return plan


def add_control_factors(plan: ControlPlan, isam, history, landmarks: set[int]) -> None:
    """Add the stop priors and target priors of ``plan`` to ``isam`` and ``history``.

    ``landmarks``: ids of the tracks that became landmarks. Updates ``plan.used`` and
    ``plan.unused`` (a target tracked but never a landmark: ``target_not_in_graph``; one
    never observed was marked ``target_not_observed`` by :func:`plan_control`).
    A point with ``u`` priors (stop keyframes, and its target) gives each ``sqrt(u)`` times
    its survey sigma: together they carry the survey error once.
    """
    import gtsam

    X, L = gtsam.symbol_shorthand.X, gtsam.symbol_shorthand.L
    graph = gtsam.NonlinearFactorGraph()
    ctrl = plan.control
    tracked = {i for i, lid in plan.targets.items() if lid in landmarks}
    uses = {i: ks.size + (i in tracked) for i, ks in plan.stops.items()}  # survey error once
    for i, ks in plan.stops.items():
        sig = np.sqrt(uses[i] * ctrl.sigma[i] ** 2 + ctrl.centring_sigma_m**2)
        noise = gtsam.noiseModel.Diagonal.Sigmas(sig)
        for k in ks:  # GPSFactor: error t(X_k) - p, a position prior with no bias term
            graph.add(gtsam.GPSFactor(X(int(k)), plan.local_xyz[i], noise))
        plan.used[str(ctrl.ids[i])] = "stop"
    for i, lid in plan.targets.items():
        name = str(ctrl.ids[i])
        if lid not in landmarks:
            if name not in plan.used and name not in plan.unused:  # observed, not triangulated
                plan.unused[name] = "target_not_in_graph"
            continue
        noise = gtsam.noiseModel.Diagonal.Sigmas(np.sqrt(uses.get(i, 1)) * ctrl.sigma[i])
        graph.add(gtsam.PriorFactorPoint3(L(lid), plan.local_xyz[i], noise))
        plan.used[name] = "stop+target" if name in plan.used else "target"
        plan.unused.pop(name, None)
    if graph.size():
        isam.update(graph, gtsam.Values())
        history.push_back(graph)


def control_report(plan: ControlPlan, result) -> dict[str, Any]:
    """Which control was used and its residuals (estimate minus control, m, E N U) at the
    final estimate: per stop point the mean of its stop keyframes (and ``online_residual_m``,
    the online estimate's, made without control: the offset the control removed), per target
    its landmark."""
    ctrl, used = plan.control, []
    lm_row = {int(j): r for r, j in enumerate(result.landmark_id)}
    for i, name in enumerate(ctrl.ids.tolist()):
        kind = plan.used.get(name)
        if kind is None:
            continue
        entry: dict[str, Any] = {"id": str(name), "kind": kind}
        if i in plan.stops:
            ks = plan.stops[i]
            res = result.keyframe_xyz[ks].mean(0) - plan.local_xyz[i]
            before = result.online_xyz[ks].mean(0) - plan.local_xyz[i]  # the filter's, no control
            entry.update(
                {
                    "keyframes": ks.tolist(),
                    "stop_residual_m": res.tolist(),
                    "online_residual_m": before.tolist(),
                }
            )
        if i in plan.targets and plan.targets[i] in lm_row:
            res = result.landmark_xyz[lm_row[plan.targets[i]]] - plan.local_xyz[i]
            entry.update({"target_id": plan.targets[i], "target_residual_m": res.tolist()})
        entry["sigma_m"] = ctrl.sigma[i].tolist()
        used.append(entry)
    return {
        "source": ctrl.source,
        "crs": ctrl.crs,
        "n_points": ctrl.n,
        "n_used": len(used),
        "used": used,
        "unused": dict(plan.unused),
        "centring_sigma_m": ctrl.centring_sigma_m,
    }
