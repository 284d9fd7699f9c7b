"""Breaklines: a prior mean with a step across each line a surveyor knows the ground breaks on.

An ice cliff, a calving front, a moraine's edge or a fault scarp is a step a stationary
kernel cannot hold: fitted through it, the kernel gains a short rough part everywhere, so the
1-sigma is too wide away from the step and too narrow along it (docs/terrain.md "Ground a
bicubic site cannot have"). DEM production handles such lines as *breaklines* (hard edges
of a TIN, or of a lidar DEM's hydro-flattening). Here each breakline adds one column to a
linear prior mean (R&W Section 2.7, :mod:`terrain.linear_mean`)::

    m(x) = h_base(x)^T beta_base + sum_j c_j S_j(x),   S_j(x) = expit(d_j(x) / w_j)

with ``d_j`` the signed distance (m) from ``x`` to line ``j``, positive on its left (looking
along the line from its first vertex), so ``c_j`` is the step's height (m), up to the left.
The GP estimates every coefficient by generalised least squares with its uncertainty
(:mod:`terrain.gp_mean`), which ``elevation_std`` carries. The kernel then fits the ground
on either side. Each step's width ``w_j`` is given, or chosen by least squares on the
samples beside its line (``width="auto"``, :meth:`BreaklineMean.choose_widths`).

A breakline must cross the survey: both its ends outside the samples' bounding box. Beyond
its ends it is taken as running straight on, so a line that stopped inside the survey would
put a step where there is none.
"""

from __future__ import annotations

import copy
from numbers import Real
from typing import Any

import numpy as np
from scipy.special import expit

from .errors import NotFittedError, bad_input
from .linear_mean import (
    check_coefficients,
    check_xy,
    check_z,
    format_coefficients,
    ols_coefficients,
)

__all__ = ["BreaklineMean"]

#: How far beyond its ends a breakline is run on straight to split the plane, m.
_REACH_M = 1e7
#: Distance in widths beyond which a step is flat: expit(40) is 1 to double precision.
_FLAT = 40.0
#: Step widths ``width="auto"`` tries, m (those up to a quarter of the samples' reach).
WIDTHS = (0.25, 0.35, 0.5, 0.7, 1.0, 1.4, 2.0, 2.8, 4.0)


def _plane(xy: np.ndarray) -> np.ndarray | None:
    """Columns of a plane through samples ``xy`` (m, 2) beside a line, (m, 3): 1, dx, dy
    about their centre, from 6 samples; (m, 2): 1 and the distance along their own line when
    4 or more lie on one (a single straight track across the breakline); else None."""
    c = xy - xy.mean(axis=0)
    plane = np.column_stack([np.ones(len(xy)), c])
    rank = np.linalg.matrix_rank(plane)
    if len(xy) >= 6 and rank == 3:
        return plane
    if len(xy) < 4 or rank != 2:
        return None
    along = c @ np.linalg.svd(c, full_matrices=False)[2][0]  # on their principal axis, m
    return np.column_stack([plane[:, 0], along]) if np.ptp(along) > 0 else None


def _positive(value: Any) -> bool:
    return isinstance(value, Real) and not isinstance(value, bool) and 0 < value < np.inf


def _line_coords(line: Any, j: int) -> np.ndarray:
    coords = getattr(line, "coords", line)  # a shapely LineString, or (k, 2) vertices
    xy = np.asarray(coords, dtype=float)
    if xy.ndim != 2 or xy.shape[0] < 2 or xy.shape[1] != 2 or not np.all(np.isfinite(xy)):
        raise bad_input(
            f"lines[{j}]",
            getattr(xy, "shape", xy),
            "a line of at least 2 finite (x, y) vertices in the samples' CRS, m",
            "pass a shapely LineString or an array of shape (k, 2)",
        )
    if np.any(np.hypot(*np.diff(xy, axis=0).T) == 0):
        raise bad_input(f"lines[{j}]", "repeated vertex", "distinct consecutive vertices", "")
    return xy


class BreaklineMean:
    """A linear prior mean with a step across each breakline (see the module notes).

    Parameters
    ----------
    lines : sequence of shapely.LineString or array of shape (k, 2)
        Breaklines in the samples' CRS, metres; each crosses the survey (both ends outside
        the samples' bounding box) without crossing itself.
    base : mean, default "constant"
        The mean the steps are added to; anything :class:`terrain.TerrainGP` takes as
        ``mean`` whose coefficients are estimated (a constant, ``RasterMean(...,
        offset="fit")``, a coarse DEM).
    width : float or "auto", default "auto"
        Scale of each step's logistic, m: it rises from 12 % to 88 % over 4 x ``width``.
        ``"auto"``: each line's own, from :data:`WIDTHS`, the one whose step and planes fit
        the samples beside it best (least squares; :meth:`fit`). A step's fitted height is
        the ground's only at the ground's width.

    Attributes
    ----------
    coef_ : ndarray of shape (n_coef,) or None
        The base's coefficients, then each step's height (m, up to the line's left).
    coef_cov_ : ndarray of shape (n_coef, n_coef) or None
        Their covariance.
    widths_ : tuple of float or None
        Each line's step width, m (chosen by :meth:`fit` with ``width="auto"``).
    """

    def __init__(self, lines: Any, base: Any = "constant", width: float | str = "auto") -> None:
        from .prior import as_mean_function  # here: prior imports this module

        if isinstance(lines, np.ndarray) and lines.ndim == 2:
            lines = [lines]
        self.lines = tuple(_line_coords(line, j) for j, line in enumerate(lines))
        if not self.lines:
            raise bad_input("lines", 0, "at least one breakline", "or use the base mean alone")
        self.base = as_mean_function(base)
        if int(getattr(self.base, "n_coef", 0) or 0) < 1:
            raise bad_input(
                "base",
                repr(self.base),
                "a mean whose coefficients are estimated (n_coef >= 1)",
                'e.g. base="constant", or a DEM mean with offset="fit" (a + b * DEM)',
            )
        if isinstance(width, str) and width == "auto":
            self.width, self.widths_ = "auto", None
        elif _positive(width):
            self.width = float(width)
            self.widths_ = (self.width,) * len(self.lines)
        elif (
            np.ndim(width) == 1
            and len(width) == len(self.lines)
            and all(_positive(w) for w in width)
        ):  # one per line: the widths a fit chose, given back (glacimap change rebuilds)
            self.width = self.widths_ = tuple(float(w) for w in width)
        else:
            raise bad_input(
                "width",
                width,
                f'"auto", a positive step width in m, or {len(self.lines)} of them (one per line)',
                'e.g. width="auto"',
            )
        self.coef_: np.ndarray | None = None
        self.coef_cov_: np.ndarray | None = None
        self._sides = tuple(self._left_side(xy) for xy in self.lines)

    # -- the linear-mean protocol (terrain.linear_mean) -------------------------------------
    @property
    def n_coef(self) -> int:
        return int(self.base.n_coef) + len(self.lines)

    @property
    def coef_names(self) -> tuple[str, ...]:
        steps = tuple(f"step{j + 1}_m" for j in range(len(self.lines)))
        return tuple(self.base.coef_names) + steps

    @property
    def crs(self) -> Any:
        return getattr(self.base, "crs", None)

    @property
    def bind(self):
        """``bind(crs, bounds)`` of a raster base (absent otherwise, as for a constant)."""
        if not hasattr(self.base, "bind"):
            raise AttributeError("bind")

        def bind(crs: Any, bounds: Any) -> BreaklineMean:
            out = copy.copy(self)
            out.base = self.base.bind(crs, bounds)
            return out

        return bind

    def __getattr__(self, name: str) -> Any:
        """A raster base's own settings (``for_grid``, ``cells``, ``coarse_and_own_cell_m``...)
        read through: the toolkit sets and reports them on the mean it is given."""
        if name.startswith("_") or name in ("base", "lines", "width", "widths_", "coef_"):
            raise AttributeError(name)
        return getattr(self.base, name)

    def signed_distances(self, xy: np.ndarray, within: float) -> np.ndarray:
        """Signed distance (m, positive left) from ``xy`` (n, 2) to each line, shape
        (n, n_lines): exact (shapely) within ``within`` m of a line, found by a k-d tree of
        its vertices densified every 0.25 m; beyond, +-inf (a step is flat there)."""
        import shapely
        from scipy.spatial import cKDTree

        xy = check_xy(xy)
        D = np.empty((len(xy), len(self.lines)))
        for j, (coords, left) in enumerate(zip(self.lines, self._sides, strict=True)):
            line = shapely.LineString(coords)
            dense = shapely.get_coordinates(shapely.segmentize(line, 0.25))
            d = cKDTree(dense).query(xy, distance_upper_bound=within + 0.125)[0]  # inf beyond
            near = np.isfinite(d)
            d[near] = shapely.distance(line, shapely.points(xy[near]))
            D[:, j] = np.where(shapely.contains_xy(left, xy[:, 0], xy[:, 1]), d, -d)
        return D

    def steps(self, xy: np.ndarray, widths: Any = None, D: np.ndarray | None = None) -> np.ndarray:
        """``S_j(x) = expit(d_j(x) / width_j)``, shape (n, n_lines), in [0, 1], at ``widths``
        (m, one per line; default :attr:`widths_`); ``D``: :meth:`signed_distances` when
        known. Beyond ``_FLAT`` widths of a line ``expit`` is 0 or 1 to double precision, so
        distances are exact only within them."""
        widths = self.widths_ if widths is None else widths
        if widths is None:
            raise NotFittedError(
                'BreaklineMean(width="auto") chooses its widths in fit. Fix: let TerrainGP '
                "fit it, call mean.fit(xy, z) first, or give a width in m."
            )
        widths = np.asarray(widths, dtype=float)
        if D is None:
            D = self.signed_distances(xy, _FLAT * float(widths.max()))
        return expit(D / widths)

    def basis(self, xy: np.ndarray) -> np.ndarray:
        """Design matrix ``[h_base(x), S_1(x), ...]``, shape (n, n_coef)."""
        return np.column_stack([np.asarray(self.base.basis(xy), float), self.steps(xy)])

    def check_crossing(self, xy: np.ndarray) -> None:
        """An ``InputError`` naming the line when one of its ends lies inside the bounding
        box of ``xy`` (n, 2): a breakline must cross the survey."""
        lo, hi = check_xy(xy).min(axis=0), xy.max(axis=0)
        for j, coords in enumerate(self.lines):
            for end in (coords[0], coords[-1]):
                if np.all(end > lo) and np.all(end < hi):
                    raise bad_input(
                        f"lines[{j}]",
                        f"end at ({end[0]:.1f}, {end[1]:.1f})",
                        f"both ends outside the samples' box x {lo[0]:.1f}..{hi[0]:.1f}, "
                        f"y {lo[1]:.1f}..{hi[1]:.1f}",
                        "extend the breakline across the survey (it is run on straight "
                        "beyond its ends), or leave it out",
                    )

    def fit(self, xy: np.ndarray, z: np.ndarray) -> BreaklineMean:
        """A fitted copy: with ``width="auto"`` each line's width first
        (:meth:`choose_widths`); each step's height from the samples beside its line
        (:meth:`local_steps`), then the base's coefficients by least squares on ``z`` less
        the steps. The GP's kernel is searched on those residuals and every coefficient then
        re-estimated by GLS. A global least-squares start would not do: a step splits the
        site in two, and the halves' trend difference (9 m on a 25 m site) read as step
        height left a step in the residuals that the kernel search fitted as rough ground."""
        xy, z = check_z(xy, z)
        self.check_crossing(xy)
        out = copy.copy(self)
        spacing = _spacing(xy)  # the samples' median spacing, m: both reaches
        if self.width == "auto":
            out.widths_ = self.choose_widths(xy, z, spacing)
        steps, steps_cov = out.local_steps(xy, z, spacing)
        rest = z - out.steps(xy) @ steps
        base_beta, base_cov = ols_coefficients(np.asarray(self.base.basis(xy), float), rest)
        p = base_beta.size
        cov = np.zeros((self.n_coef, self.n_coef))
        cov[:p, :p], cov[p:, p:] = base_cov, steps_cov
        return out.with_coefficients(np.concatenate([base_beta, steps]), cov)

    def choose_widths(
        self, xy: np.ndarray, z: np.ndarray, spacing: float | None = None
    ) -> tuple[float, ...]:
        """Each line's width from :data:`WIDTHS` (those up to a quarter of the reach ``R`` =
        3 x the samples' median spacing, at least 16 m: every rung on a rover's survey): the
        one whose step and planes (:meth:`local_steps`' model, on the samples within ``R``)
        leave the least squared residual, line by line from 1 m. On a synthetic draw with
        steps 0.5, 1, 1.5 and 3 m wide it picks 0.5, 1, 1.4 and 2.8 (tests)."""
        spacing = _spacing(xy) if spacing is None else spacing
        reach = max(3.0 * spacing, 16.0)
        ladder = [w for w in WIDTHS if 4.0 * w <= reach]
        near = self._near(xy, reach)
        widths = [1.0] * len(self.lines)
        for j in range(len(self.lines)):

            def rss(w: float, j: int = j) -> float:
                return self._local_fit(z, (*widths[:j], w, *widths[j + 1 :]), near)[2]

            widths[j] = min(ladder, key=rss)
        return tuple(widths)

    def local_steps(
        self, xy: np.ndarray, z: np.ndarray, spacing: float | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Each step's height (m) and their covariance from the samples within ``R`` of the
        lines, the ground there a plane of its own on every stretch of ``2 R`` along each
        line (least squares of ``z`` on ``[planes, S]``; ``R`` = 5 widths or 3 x the
        samples' median spacing, at least 10 m).

        Raises an ``InputError`` naming the line when no stretch has samples on both sides.
        """
        widths = self.widths_
        spacing = _spacing(xy) if spacing is None else spacing
        reach = max(5.0 * max(widths), 3.0 * spacing, 10.0)
        near = self._near(xy, reach)
        return self._local_fit(z, widths, near)[:2]

    def _near(self, xy: np.ndarray, reach: float) -> dict[str, Any]:
        """The samples within ``reach`` of the lines, their signed distances (exact) and
        planes."""
        import shapely

        D = self.signed_distances(xy, reach)
        planes, rows = [], np.zeros(len(xy), dtype=bool)  # (samples, their plane's columns)
        for j, coords in enumerate(self.lines):
            near = np.abs(D[:, j]) <= reach
            idx = np.flatnonzero(near)
            along = shapely.line_locate_point(shapely.LineString(coords), shapely.points(xy[idx]))
            stretch = np.floor(along / (2.0 * reach))
            both = 0
            for k in np.unique(stretch):
                m = idx[stretch == k]
                plane = _plane(xy[m])
                if plane is None:
                    near[m] = False  # too few samples for a plane of their own: not used
                    continue
                both += int(np.any(D[m, j] > 0) and np.any(D[m, j] < 0))
                planes.append((m, plane))
            if both == 0:
                raise bad_input(
                    f"lines[{j}]",
                    "no samples on both sides",
                    f"samples within {reach:.0f} m of the line on either side of it",
                    "survey across the breakline, or leave it out",
                )
            rows |= near
        return {"D": D[rows], "planes": planes, "rows": rows}

    def _local_fit(self, z, widths, near) -> tuple[np.ndarray, np.ndarray, float]:
        """(steps, their covariance, residual sum of squares) of :meth:`local_steps` on the
        samples of :meth:`_near`."""
        rows, planes = near["rows"], near["planes"]
        where = np.full(rows.size, -1)
        where[rows] = np.arange(int(rows.sum()))
        cols = np.cumsum([0] + [plane.shape[1] for _, plane in planes])
        H = np.zeros((int(rows.sum()), cols[-1] + len(self.lines)))
        for k, (idx, plane) in enumerate(planes):
            H[where[idx], cols[k] : cols[k + 1]] = plane
        H[:, cols[-1] :] = self.steps(None, widths, D=near["D"])
        beta, cov = ols_coefficients(H, z[rows])
        rss = float(np.sum((z[rows] - H @ beta) ** 2))
        n = len(self.lines)
        return beta[-n:], cov[-n:, -n:], rss

    def with_coefficients(self, beta: Any, cov: Any) -> BreaklineMean:
        """A copy whose value is ``basis(xy) @ beta`` (``beta`` (n_coef,), ``cov`` its
        covariance)."""
        beta, cov = check_coefficients(self, beta, cov)
        out = copy.copy(self)
        out.coef_, out.coef_cov_ = beta, cov
        return out

    def __call__(self, xy: np.ndarray) -> np.ndarray:
        """Mean elevation (m) at ``xy`` (n, 2) -> (n,)."""
        if self.coef_ is None:
            raise NotFittedError(
                "BreaklineMean was called before its coefficients were estimated. Fix: let "
                "TerrainGP fit it, or call mean.fit(xy, z) first."
            )
        return self.basis(xy) @ self.coef_

    def __repr__(self) -> str:
        n, base = len(self.lines), self.base
        if isinstance(self.width, tuple):
            width = "width=(" + ", ".join(f"{w:g}" for w in self.width) + ") m"
        else:
            width = "width='auto'" if self.width == "auto" else f"width={self.width:g} m"
        if self.widths_ is not None and self.width == "auto":
            width += " (" + ", ".join(f"{w:g}" for w in self.widths_) + " m)"
        if self.coef_ is None:
            return f"BreaklineMean({n} line(s), {width}, base={base!r})"
        p = int(base.n_coef)  # the base with its own coefficients, then the steps
        base = base.with_coefficients(self.coef_[:p], self.coef_cov_[:p, :p])
        steps = format_coefficients(self.coef_names[p:], self.coef_[p:], self.coef_cov_[p:, p:])
        return f"BreaklineMean({n} line(s), {width}, base={base!r}, {steps})"

    def geojson(self) -> dict[str, Any]:
        """The lines as a GeoJSON Feature (a MultiLineString in the samples' CRS, m) with the
        steps' ``widths_m`` (None before a fit with ``width="auto"``) in its properties: what
        a product records so that the mean can be rebuilt (``glacimap change``)."""
        widths = None if self.widths_ is None else [float(w) for w in self.widths_]
        return {
            "type": "Feature",
            "geometry": {
                "type": "MultiLineString",
                "coordinates": [xy.tolist() for xy in self.lines],
            },
            "properties": {"widths_m": widths},
        }

    # -- geometry ---------------------------------------------------------------------------
    @staticmethod
    def _left_side(coords: np.ndarray):
        """The half of the plane left of the line run on straight beyond its ends."""
        import shapely
        from shapely.ops import split

        head = coords[0] - _REACH_M * _unit(coords[1] - coords[0])
        tail = coords[-1] + _REACH_M * _unit(coords[-1] - coords[-2])
        line = shapely.LineString(np.vstack([head, coords, tail]))
        c = coords.mean(axis=0)
        r = 0.5 * _REACH_M  # the run-on ends lie beyond the box: the line cuts it
        plane = shapely.box(c[0] - r, c[1] - r, c[0] + r, c[1] + r)
        pieces = list(split(plane, line).geoms)
        if len(pieces) != 2:
            raise bad_input(
                "lines",
                f"{len(pieces)} pieces",
                "a line that does not cross itself (it splits the plane in two)",
                "split it into lines that do not cross themselves",
            )
        a, b = coords[0], coords[1]
        probe = (a + b) / 2 + 1e-3 * np.array([-(b - a)[1], (b - a)[0]]) / np.hypot(*(b - a))
        left = [p for p in pieces if p.contains(shapely.Point(probe))]
        piece = left[0] if left else pieces[1]
        shapely.prepare(piece)
        return piece


def _spacing(xy: np.ndarray) -> float:
    """The samples' median nearest-neighbour distance, m."""
    from scipy.spatial import cKDTree

    return float(np.median(cKDTree(xy).query(xy, k=2)[0][:, 1]))


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.hypot(*v)
