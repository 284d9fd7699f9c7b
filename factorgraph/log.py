"""The measurement log: what a rover recorded (simulated or real), validated once.

A log is keyframe-based: the front end (visual odometry / feature tracker) has already cut
the stream into keyframes, associated features into tracks, and integrated odometry between
keyframes. Real logs enter through :func:`read_log` with the file layout below.

File layout (a folder; every table as ``NAME.csv`` or ``NAME.parquet``)
---------------------------------------------------------------------
``meta.json``
    ``{"format": "glacimap-log/1", "crs": "EPSG:32608", "origin": [E, N], "seed": int|null,
    "sensors": SensorSuite.to_dict()}``, optional ``"ingest"`` (what the field reader
    skipped, by reason). World coordinates in every table are local ENU metres
    relative to ``origin`` (projected easting/northing) and 0 m elevation.
``keyframes``
    ``k, t_s`` (strictly increasing time, s); optional truth ``true_x, true_y, true_z`` (m) and
    ``true_roll, true_pitch, true_yaw`` (rad, ZYX body-to-world); optional ``up_x, up_y, up_z``:
    the measured gravity "up" direction in the body frame (unit vector; an accelerometer or
    inclinometer, ``sensors.tilt``); optional ``control_id``: the ground-control point the rover
    stands on at that keyframe (empty for none; :mod:`factorgraph.control`).
``odometry``
    ``k`` (from keyframe k to k+1), ``rx, ry, rz`` (rotation vector, rad) and ``tx, ty, tz`` (m):
    the measured pose of keyframe k+1 in the body frame of keyframe k.
``gps``
    ``k`` (keyframe of the fix), ``x, y, z`` (antenna = body origin, local ENU m); optional
    ``sigma_x, sigma_y, sigma_z``: this fix's own white-noise 1-sigma (m, ENU; from the
    receiver's fix quality / DOP / solution sigmas, ``factorgraph.field``), used by
    ``localize`` in place of ``sensors.gps.sigma_white_m``; optional truth
    ``true_bias_x, true_bias_y, true_bias_z`` (m).
``observations``
    ``k, landmark_id, u_px, v_px``: a tracked feature seen in keyframe k.
``landmarks`` (optional, simulation truth)
    ``landmark_id, true_x, true_y, true_z`` (m).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from terrain.atomic import atomic_path, ensure_writable_dir
from terrain.errors import bad_input
from terrain.grid import as_crs

from .sensors import SensorSuite

__all__ = ["FORMAT", "MeasurementLog", "read_log", "write_log"]

FORMAT = "glacimap-log/1"


def _arr(name: str, value: Any, shape: tuple[int | None, ...], dtype: Any = float) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=dtype)
    except (TypeError, ValueError) as exc:
        raise bad_input(name, value, f"an array of shape {shape}", "pass numbers") from exc
    if a.ndim != len(shape) or any(
        s is not None and s != d for s, d in zip(shape, a.shape, strict=True)
    ):
        raise bad_input(name, a.shape, f"shape {shape}", "check the log tables")
    if a.dtype.kind == "f" and not np.isfinite(a).all():
        i = int(np.argwhere(~np.isfinite(a))[0][0])
        raise bad_input(
            name,
            f"non-finite value at row {i}",
            "finite measurements",
            "drop the row in the front end (and count it) or repair it",
        )
    return a


@dataclass
class MeasurementLog:
    """Keyframes, odometry, GPS fixes and feature observations of one traverse.

    Attributes
    ----------
    t : ndarray of shape (K,)
        Keyframe times (s), strictly increasing.
    odometry : ndarray of shape (K-1, 6)
        Measured relative pose k -> k+1 in body frame k: rotation vector (rad), translation (m).
    gps_k : ndarray of shape (G,), int
        Keyframe index of each GPS fix.
    gps_xyz : ndarray of shape (G, 3)
        GPS positions, local ENU (m).
    obs_k, obs_id : ndarray of shape (M,), int
        Keyframe and landmark (track) id of each feature observation.
    obs_uv : ndarray of shape (M, 2)
        Pixel coordinates (u right, v down).
    sensors : SensorSuite
        Stated sensor models (noise levels the estimator assumes; the camera intrinsics).
    origin : ndarray of shape (2,)
        Projected easting/northing (m) of the local frame's origin.
    crs : str
        CRS of ``origin`` (and of every product made from this log).
    truth : dict
        Optional ground truth: ``xyz (K,3)``, ``rpy (K,3)``, ``gps_bias (G,3)``,
        ``landmark_id (L,)``, ``landmark_xyz (L,3)``.
    seed : int or None
        Seed that generated a simulated log.
    control_id : ndarray of shape (K,), str, or None
        Ground-control point the rover stands on at each keyframe ("" for none).
    gps_sigma : ndarray of shape (G, 3) or None
        Per-fix white-noise 1-sigma (m, ENU); None: ``sensors.gps.sigma_white_m`` for all.
    ingest : dict
        What the field reader skipped, by reason (``IngestReport.as_dict()``); {} otherwise.
    """

    t: np.ndarray
    odometry: np.ndarray
    gps_k: np.ndarray
    gps_xyz: np.ndarray
    obs_k: np.ndarray
    obs_id: np.ndarray
    obs_uv: np.ndarray
    tilt_up: np.ndarray | None = None
    sensors: SensorSuite = field(default_factory=SensorSuite)
    origin: np.ndarray = field(default_factory=lambda: np.zeros(2))
    crs: str = "EPSG:32608"
    truth: dict[str, np.ndarray] = field(default_factory=dict)
    seed: int | None = None
    control_id: np.ndarray | None = None
    gps_sigma: np.ndarray | None = None
    ingest: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.t = _arr("keyframes.t_s", self.t, (None,))
        K = self.t.size
        if K < 2:
            raise bad_input("keyframes", K, "at least 2 keyframes", "log a longer traverse")
        dt = np.diff(self.t)
        if (dt <= 0).any():
            i = int(np.argmax(dt <= 0))
            raise bad_input(
                "keyframes.t_s",
                f"t[{i}]={self.t[i]:g} then t[{i + 1}]={self.t[i + 1]:g}",
                "strictly increasing timestamps",
                "sort the log by time and drop repeated keyframes",
            )
        self.odometry = _arr("odometry", self.odometry, (K - 1, 6))
        self.gps_k = _arr("gps.k", self.gps_k, (None,), int)
        self.gps_xyz = _arr("gps.xyz", self.gps_xyz, (self.gps_k.size, 3))
        self.obs_k = _arr("observations.k", self.obs_k, (None,), int)
        self.obs_id = _arr("observations.landmark_id", self.obs_id, (self.obs_k.size,), int)
        self.obs_uv = _arr("observations.uv", self.obs_uv, (self.obs_k.size, 2))
        if self.tilt_up is not None:
            up = _arr("keyframes.up", self.tilt_up, (K, 3))
            norm = np.linalg.norm(up, axis=1)
            if not (np.abs(norm - 1.0) < 0.1).all():
                i = int(np.argmax(np.abs(norm - 1.0) >= 0.1))
                raise bad_input(
                    "keyframes.up_x/up_y/up_z",
                    f"|up[{i}]| = {norm[i]:g}",
                    "unit vectors (gravity direction in the body frame)",
                    "normalise the accelerometer reading or drop the columns",
                )
            self.tilt_up = up / norm[:, None]
        for name, k in (("gps.k", self.gps_k), ("observations.k", self.obs_k)):
            if k.size and (k.min() < 0 or k.max() >= K):
                raise bad_input(name, (int(k.min()), int(k.max())), f"indices in [0, {K})", "")
        if self.gps_k.size and (np.diff(self.gps_k) <= 0).any():
            raise bad_input("gps.k", "repeated or unsorted", "one fix per keyframe, sorted", "")
        if self.gps_sigma is not None:
            self.gps_sigma = _arr("gps.sigma_xyz", self.gps_sigma, (self.gps_k.size, 3))
            if not (self.gps_sigma > 0).all():
                raise bad_input("gps.sigma_x/y/z", "a value <= 0", "sigmas > 0 (m)", "")
        self.origin = _arr("meta.origin", self.origin, (2,))
        self.crs = as_crs(self.crs).to_string()
        self.truth = {k: np.asarray(v) for k, v in self.truth.items()}
        if self.control_id is not None:
            self.control_id = _arr("keyframes.control_id", self.control_id, (K,), str)

    @property
    def n_keyframes(self) -> int:
        return int(self.t.size)

    @property
    def duration_s(self) -> float:
        return float(self.t[-1] - self.t[0])

    @property
    def has_truth(self) -> bool:
        return "xyz" in self.truth

    def meta(self) -> dict[str, Any]:
        return {
            "format": FORMAT,
            "crs": self.crs,
            "origin": [float(v) for v in self.origin],
            "seed": self.seed,
            "sensors": self.sensors.to_dict(),
            **({"ingest": self.ingest} if self.ingest else {}),
        }

    def tables(self) -> dict[str, dict[str, np.ndarray]]:
        """The log as named column tables (the file layout in the module docstring)."""
        K = self.n_keyframes
        kf: dict[str, np.ndarray] = {"k": np.arange(K), "t_s": self.t}
        tr = self.truth
        if "xyz" in tr:
            kf.update({f"true_{a}": tr["xyz"][:, i] for i, a in enumerate("xyz")})
            kf.update(
                {f"true_{a}": tr["rpy"][:, i] for i, a in enumerate(("roll", "pitch", "yaw"))}
            )
        if self.tilt_up is not None:
            kf.update({f"up_{a}": self.tilt_up[:, i] for i, a in enumerate("xyz")})
        if self.control_id is not None:
            kf["control_id"] = self.control_id
        od = {"k": np.arange(K - 1)}
        od.update(
            {n: self.odometry[:, i] for i, n in enumerate(("rx", "ry", "rz", "tx", "ty", "tz"))}
        )
        gps = {"k": self.gps_k}
        gps.update({a: self.gps_xyz[:, i] for i, a in enumerate("xyz")})
        if self.gps_sigma is not None:
            gps.update({f"sigma_{a}": self.gps_sigma[:, i] for i, a in enumerate("xyz")})
        if "gps_bias" in tr:
            gps.update({f"true_bias_{a}": tr["gps_bias"][:, i] for i, a in enumerate("xyz")})
        obs = {
            "k": self.obs_k,
            "landmark_id": self.obs_id,
            "u_px": self.obs_uv[:, 0],
            "v_px": self.obs_uv[:, 1],
        }
        out = {"keyframes": kf, "odometry": od, "gps": gps, "observations": obs}
        if "landmark_xyz" in tr:
            lm = {"landmark_id": tr["landmark_id"]}
            lm.update({f"true_{a}": tr["landmark_xyz"][:, i] for i, a in enumerate("xyz")})
            out["landmarks"] = lm
        return out


_REQUIRED = {
    "keyframes": ("k", "t_s"),
    "odometry": ("k", "rx", "ry", "rz", "tx", "ty", "tz"),
    "gps": ("k", "x", "y", "z"),
    "observations": ("k", "landmark_id", "u_px", "v_px"),
}


def write_log(log: MeasurementLog, folder: str | Path, fmt: str = "csv") -> Path:
    """Write ``log`` into ``folder`` (created) as ``meta.json`` plus one file per table.

    ``fmt`` is ``"csv"`` or ``"parquet"``. Each file is written atomically.
    """
    import pandas as pd

    if fmt not in ("csv", "parquet"):
        raise bad_input("fmt", fmt, "'csv' or 'parquet'", "pick one")
    out = ensure_writable_dir(folder)
    for name, cols in log.tables().items():
        df = pd.DataFrame(cols)
        with atomic_path(out / f"{name}.{fmt}") as tmp:
            if fmt == "csv":
                df.to_csv(tmp, index=False, float_format="%.9g")
            else:
                df.to_parquet(tmp, index=False)
    with atomic_path(out / "meta.json") as tmp:
        tmp.write_text(json.dumps(log.meta(), indent=2))
    return out


def _read_table(folder: Path, name: str, required: bool = True):
    import pandas as pd

    for ext, reader in (("parquet", pd.read_parquet), ("csv", pd.read_csv)):
        path = folder / f"{name}.{ext}"
        if path.exists():
            df = reader(path)
            missing = [c for c in _REQUIRED.get(name, ()) if c not in df.columns]
            if missing:
                raise bad_input(
                    f"{path.name}",
                    sorted(df.columns),
                    f"columns {missing} too",
                    "see the file layout in factorgraph/log.py",
                )
            if required and df.empty:  # a header only: no array math may see zero rows
                raise bad_input(
                    path.name,
                    "a header and no rows",
                    f"at least one {name} row",
                    f"the {name} table is empty: check the logger or the export that wrote it",
                )
            return df
    if required:
        raise bad_input(
            f"log {name}",
            str(folder),
            f"a {name}.csv or {name}.parquet file",
            "see the file layout in factorgraph/log.py",
        )
    return None


def read_log(folder: str | Path) -> MeasurementLog:
    """Read a log written by :func:`write_log` or by a real rover's exporter."""
    folder = Path(folder)
    meta_path = folder / "meta.json"
    if not meta_path.is_file():
        raise bad_input("log", str(folder), "a folder with meta.json", "point at a log folder")
    try:
        meta = json.loads(meta_path.read_text())
    except json.JSONDecodeError as exc:
        raise bad_input("meta.json", str(exc), "valid JSON", "repair the file") from exc
    if meta.get("format") != FORMAT:
        raise bad_input("meta.json format", meta.get("format"), repr(FORMAT), "")
    kf = _read_table(folder, "keyframes").sort_values("k", kind="stable")
    if not np.array_equal(kf["k"].to_numpy(), np.arange(len(kf))):
        raise bad_input("keyframes.k", "gaps", "k = 0, 1, ..., K-1", "renumber keyframes")
    od = _read_table(folder, "odometry").sort_values("k", kind="stable")
    if not np.array_equal(od["k"].to_numpy(), np.arange(len(kf) - 1)):
        raise bad_input("odometry.k", "gaps", "one row per k = 0..K-2", "")
    gps = _read_table(folder, "gps")
    obs = _read_table(folder, "observations")
    lm = _read_table(folder, "landmarks", required=False)
    truth: dict[str, np.ndarray] = {}
    if {"true_x", "true_y", "true_z"} <= set(kf.columns):
        truth["xyz"] = kf[["true_x", "true_y", "true_z"]].to_numpy(float)
        truth["rpy"] = kf[["true_roll", "true_pitch", "true_yaw"]].to_numpy(float)
    if {"true_bias_x", "true_bias_y", "true_bias_z"} <= set(gps.columns):
        truth["gps_bias"] = gps[["true_bias_x", "true_bias_y", "true_bias_z"]].to_numpy(float)
    if lm is not None:
        truth["landmark_id"] = lm["landmark_id"].to_numpy(int)
        truth["landmark_xyz"] = lm[["true_x", "true_y", "true_z"]].to_numpy(float)
    sig_cols = ["sigma_x", "sigma_y", "sigma_z"]
    gps_sigma = gps[sig_cols].to_numpy(float) if set(sig_cols) <= set(gps.columns) else None
    up_cols = ["up_x", "up_y", "up_z"]
    tilt_up = kf[up_cols].to_numpy(float) if set(up_cols) <= set(kf.columns) else None
    control_id = None
    if "control_id" in kf.columns:  # ids as written: "7" stays "7", an empty cell is ""
        control_id = kf["control_id"].map(_id_text).to_numpy(str)
    return MeasurementLog(
        t=kf["t_s"].to_numpy(float),
        tilt_up=tilt_up,
        odometry=od[["rx", "ry", "rz", "tx", "ty", "tz"]].to_numpy(float),
        gps_k=gps["k"].to_numpy(int),
        gps_xyz=gps[["x", "y", "z"]].to_numpy(float),
        obs_k=obs["k"].to_numpy(int),
        obs_id=obs["landmark_id"].to_numpy(int),
        obs_uv=obs[["u_px", "v_px"]].to_numpy(float),
        sensors=SensorSuite.from_dict(meta.get("sensors", {})),
        origin=np.asarray(meta.get("origin", [0.0, 0.0]), float),
        crs=meta.get("crs", "EPSG:32608"),
        truth=truth,
        seed=meta.get("seed"),
        control_id=control_id,
        gps_sigma=gps_sigma,
        ingest=dict(meta.get("ingest", {})),
    )


def _id_text(v: Any) -> str:
    """A control id cell as text (pandas reads "7" as 7.0 and an empty cell as NaN)."""
    if isinstance(v, float):
        return "" if v != v else (str(int(v)) if v.is_integer() else repr(v))
    return str(v).strip()
