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
samples beside its line (``width="auto"``, :meth:`BreaklineMean.choose_shape`).

An end outside the samples' bounding box is taken as running straight on. An end inside it
is *open*: the step dies out over the last ``T`` metres before it (the taper, given or chosen
like the width), and the column is the double layer of :mod:`terrain.breakline_geometry`,
continuous round the end, so a cliff that fades out inside the survey puts no step beyond it.
Such a line also has a hinge column (the lift carried on past the taper, less the double
layer's): its coefficient lets the GLS weigh how far the lifted side's tilt runs on.
"""

from __future__ import annotations

import copy
import hashlib
from typing import Any

import numpy as np
from scipy.optimize import minimize_scalar
from scipy.spatial import cKDTree
from scipy.special import expit

from .breakline_geometry import (
    arc_positions,
    double_layer,
    left_side,
    line_coords,
    median_spacing,
    run_on,
    signed_distances,
    taper_of,
)
from .breakline_local import local_fit, near_samples
from .breakline_settings import per_line, read_ends, setting_repr
from .dem_reading import coarse_columns, reads_steps
from .errors import NotFittedError, bad_input
from .linear_mean import (
    check_coefficients,
    check_xy,
    check_z,
    format_coefficients,
    ols_coefficients,
)

__all__ = ["BreaklineMean"]

#: Distance in widths beyond which a step is flat: expit(40) is 1 to double precision.
_FLAT = 40.0
#: Step widths ``width="auto"`` tries, m (those up to a quarter of the samples' reach).
WIDTHS = (0.25, 0.35, 0.5, 0.7, 1.0, 1.4, 2.0, 2.8, 4.0)
#: Taper lengths ``taper="auto"`` tries at an end inside the survey, m (sqrt(2) apart); the
#: first guess.
TAPERS = (5.0, 7.0, 10.0, 14.0, 20.0, 28.0, 40.0, 56.0, 80.0, 113.0, 160.0)
_TAPER_START = 40.0


class BreaklineMean:
    """A linear prior mean with a step across each breakline (see the module notes).

    Parameters
    ----------
    lines : sequence of shapely.LineString or array of shape (k, 2)
        Breaklines in the samples' CRS, metres, none crossing itself. An end outside the
        samples' bounding box runs on straight; an end inside it is open: the step dies out
        towards it over the taper.
    base : mean, default "constant"
        The mean the steps are added to; anything :class:`terrain.TerrainGP` takes as
        ``mean`` whose coefficients are estimated (a constant, ``RasterMean(...,
        offset="fit")``, a coarse DEM).
    width : float, sequence of float or "auto", default "auto"
        Scale of each step's logistic, m: it rises from 12 % to 88 % over 4 x ``width``.
        ``"auto"``: each line's own, from :data:`WIDTHS`, the one whose step and planes fit
        the samples beside it best (least squares; :meth:`fit`). A step's fitted height is
        the ground's only at the ground's width.
    taper : float, sequence of float or "auto", default "auto"
        Length (m, along the line) over which a step dies out before an open end, by a
        smoothstep; used only by lines with an end inside the survey. ``"auto"``: from
        :data:`TAPERS`, by the same least squares as the width.
    ends : "auto", "open" or sequence of (bool, bool), default "auto"
        Which ends are open: inside the fitted samples' box (``"auto"``), every end (a cliff
        that stops between the survey and the map's edge), or per line (first, last vertex).

    Attributes
    ----------
    coef_ : ndarray of shape (n_coef,) or None
        The base's coefficients, then each step's height (m, up to the line's left; at full
        strength, away from an open end's taper).
    coef_cov_ : ndarray of shape (n_coef, n_coef) or None
        Their covariance.
    widths_ : tuple of float or None
        Each line's step width, m (chosen by :meth:`fit` with ``width="auto"``, then refined
        with its 1-sigma ``widths_sd_`` by the map's evidence: terrain.breakline_evidence).
    open_ends_ : tuple of (bool, bool) or None
        Per line, whether its first and last vertex are open (set by :meth:`fit` from
        ``ends``; before it every end runs on unless ``ends`` says).
    tapers_ : tuple of float or None
        Each line's taper, m (chosen by :meth:`fit` with ``taper="auto"`` for the lines with
        an open end).
    coarse_steps_ : bool or None
        Whether :meth:`fit` found a base DEM that smooths the steps over its pixels (a
        bound :class:`terrain.RasterMean` with pixels >= 4 widths): then each step's column
        is split in two, what the DEM cannot hold and its reading of the step, with the
        coefficients ``step1_m``... and ``coarse_step1_m``... (``terrain.dem_reading``).
    """

    def __init__(
        self,
        lines: Any,
        base: Any = "constant",
        width: float | str = "auto",
        taper: float | str = "auto",
        ends: Any = "auto",
    ) -> None:
        from .prior import as_mean_function  # here: prior imports this module

        if isinstance(lines, np.ndarray) and lines.ndim == 2:
            lines = [lines]
        self.lines = tuple(line_coords(line, j) for j, line in enumerate(lines))
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
        n = len(self.lines)
        self.width, self.widths_ = per_line(width, "width", n, '"auto"')
        self.taper, self.tapers_ = per_line(taper, "taper", n, '"auto" or 40.0', True)
        self.ends = read_ends(ends, n)
        self.open_ends_: tuple[tuple[bool, bool], ...] | None = None
        self.coarse_steps_: bool | None = None  # set by fit: terrain.dem_reading
        self.coef_: np.ndarray | None = None
        self.coef_cov_: np.ndarray | None = None
        import shapely  # here: a dependency of the breaklines only

        for j, xy in enumerate(self.lines):
            if not shapely.LineString(xy).is_simple:
                raise bad_input(
                    f"lines[{j}]",
                    "a line that crosses itself",
                    "a line that does not cross itself",
                    "split it into lines that do not cross themselves",
                )

    # -- the linear-mean protocol (terrain.linear_mean) -------------------------------------
    @property
    def n_coef(self) -> int:
        coarse = len(self.lines) if self.coarse_steps_ else 0  # terrain.dem_reading
        return int(self.base.n_coef) + len(self.lines) + len(self._hinged()) + coarse

    @property
    def coef_names(self) -> tuple[str, ...]:
        steps = tuple(f"step{j + 1}_m" for j in range(len(self.lines)))
        hinges = tuple(f"hinge{j + 1}_m" for j in self._hinged())
        n = len(self.lines) if self.coarse_steps_ else 0  # terrain.dem_reading
        coarse = tuple(f"coarse_step{j + 1}_m" for j in range(n))
        return tuple(self.base.coef_names) + steps + hinges + coarse

    def _hinged(self) -> list[int]:
        """The lines with an open end: each has a hinge column besides its step."""
        return [j for j, ends in enumerate(self._open()) if any(ends)]

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
        if name.startswith("_") or name in _OWN:
            raise AttributeError(name)
        return getattr(self.base, name)

    def _open(self) -> tuple[tuple[bool, bool], ...]:
        if self.open_ends_ is not None:
            return self.open_ends_
        return self.ends if isinstance(self.ends, tuple) else ((False, False),) * len(self.lines)

    def with_ends(self, ends: Any) -> BreaklineMean:
        """An unfitted copy whose ends are ``ends`` (:func:`read_ends`): the held-out check's
        folds keep the map's open ends, whatever box their samples leave."""
        out = copy.copy(self)
        out.ends = read_ends(ends, len(self.lines))
        out.open_ends_ = out.coef_ = out.coef_cov_ = out.coarse_steps_ = None
        return out

    def signed_distances(self, xy: np.ndarray, within: float) -> np.ndarray:
        """Signed distance (m, positive left) from ``xy`` (n, 2) to each line, shape
        (n, n_lines): exact (shapely) within ``within`` m of a line; beyond, +-inf (a step
        is flat there). The side is that of the line run on straight beyond its ends."""
        xy = check_xy(xy)
        return np.column_stack(
            [signed_distances(xy, c, self._side(j)[1], within) for j, c in enumerate(self.lines)]
        )

    def _side(self, j: int) -> tuple[Any, Any]:
        """Line ``j``'s run-on directions and the side it leaves left (kept per open ends:
        an open end's ray may turn off a line that curls back, :func:`run_on`)."""
        ends = self._open()[j]
        cache = self.__dict__.setdefault("_side_cache", {})  # shared by copies
        if (j, ends) not in cache:
            directions = run_on(self.lines[j], ends)
            cache[(j, ends)] = (directions, left_side(self.lines[j], directions))
        return cache[(j, ends)]

    def _geometry(self, xy: np.ndarray, within: float) -> dict[str, Any]:
        """What the step columns need at ``xy`` (n, 2): signed distances within ``within``
        m, room for the arc positions of the points' nearest points on the lines (_arcs)."""
        D = self.signed_distances(xy, within)
        arcs = [np.full(len(xy), np.nan) for _ in self.lines]
        return {"xy": xy, "D": D, "s": arcs, "layers": {}}

    def _arcs(self, geom: dict[str, Any], j: int, idx: np.ndarray) -> np.ndarray:
        """Arc positions (m) on line ``j`` of ``geom``'s points ``idx``, found once."""
        s = geom["s"][j]
        todo = idx[np.isnan(s[idx])]
        s[todo] = arc_positions(geom["xy"][todo], self.lines[j])
        return s[idx]

    def _columns(
        self, geom: dict[str, Any], widths: Any, tapers: Any
    ) -> tuple[np.ndarray, np.ndarray]:
        """The step columns, (n, n_lines), and the hinge columns, (n, n_open), on
        :meth:`_geometry`'s points. A line run on at both ends: ``expit(d / w)``. One with
        an open end: the double layer ``J`` whose strength tapers off
        (:mod:`terrain.breakline_geometry`), given its width near it; its hinge column
        ``H tau_band - J`` is continuous (the two jump alike) and smooth off the line: the
        step's lift carried on perpendicular to the line past its taper (a hinge) less the
        lift that dies away round the end. The GLS weighs the two by the data."""
        D = geom["D"]
        S = expit(D / np.asarray(widths, dtype=float))
        hinges = []
        for j in self._hinged():
            if tapers is None or tapers[j] is None:
                raise NotFittedError(
                    'BreaklineMean(taper="auto") chooses its tapers in fit. Fix: let '
                    "TerrainGP fit it, call mean.fit(xy, z) first, or give a taper in m."
                )
            sharp, near, tau, hinge = self._layer(geom, j, float(tapers[j]))
            logistic = S[near, j]  # the jump given the step's width near the line
            S[:, j] = sharp
            S[near, j] += tau * (logistic - (D[near, j] > 0))
            hinges.append(hinge)
        return S, np.column_stack(hinges) if hinges else np.zeros((len(D), 0))

    def _layer(self, geom: dict[str, Any], j: int, length: float):
        """What line ``j``'s columns at a taper of ``length`` m take from ``geom``'s points
        whatever the width (kept for the width's ladder): the sharp step ``H - layer`` (the
        double layer of the tapered strength, :mod:`terrain.breakline_geometry`), the points
        within reach of the line and ``tau`` of their nearest points on it, and the hinge
        column ``layer - H (1 - band)``."""
        key = (j, length)
        if key not in geom["layers"]:
            tapers = self.__dict__.setdefault("_taper_cache", {})  # shared by copies
            ckey = (j, length, self._open()[j])
            if ckey not in tapers:
                ends, directions = self._open()[j], self._side(j)[0]
                tapers[ckey] = taper_of(self.lines[j], ends, length, directions)
            t, D = tapers[ckey], geom["D"][:, j]
            layer = double_layer(geom["xy"], t.a, t.b, t.wa, t.wb)
            H = (D > 0).astype(float)
            near = np.flatnonzero(np.isfinite(D))
            # tau of each point's nearest point on the line: 1 off the taper, i.e. where
            # the taper's nodes lie farther than the line plus half a piece
            tau = np.ones(near.size)
            reach = np.abs(D[near]) + t.piece
            bound = float(reach.max()) if near.size else 0.0
            on = cKDTree(t.zone).query(geom["xy"][near], distance_upper_bound=bound)[0]
            on = np.flatnonzero(on <= reach)
            tau[on] = t.at(self._arcs(geom, j, near[on]))
            hinge = layer - H * (1.0 - t.band(geom["xy"]))
            geom["layers"][key] = (H - layer, near, tau, hinge)
        return geom["layers"][key]

    def steps(self, xy: np.ndarray, widths: Any = None, tapers: Any = None) -> np.ndarray:
        """The step columns ``S_j(x)``, shape (n, n_lines), in [0, 1] (0 far on a line's
        right, 1 far on its left; a line with an open end: less round the end), at
        ``widths`` and ``tapers`` (m, one per line; default :attr:`widths_`,
        :attr:`tapers_`). For a line run on at both ends ``S = expit(d / w)``; beyond
        ``_FLAT`` widths of a line ``expit`` is 0 or 1 to double precision, so distances are
        exact only within them."""
        return self._steps_and_hinges(xy, widths, tapers)[0]

    def _steps_and_hinges(self, xy, widths=None, tapers=None) -> tuple[np.ndarray, np.ndarray]:
        widths = self.widths_ if widths is None else widths
        if widths is None:
            raise NotFittedError(
                'BreaklineMean(width="auto") chooses its widths in fit. Fix: let TerrainGP '
                "fit it, call mean.fit(xy, z) first, or give a width in m."
            )
        xy = np.ascontiguousarray(check_xy(xy))
        tapers = self.tapers_ if tapers is None else tapers
        # the GP asks for the samples' and the grid's columns more than once: kept (the last
        # four point sets, by content) on every copy of this mean
        digest = hashlib.blake2b(xy.tobytes(), digest_size=16).digest()
        key = (digest, xy.shape, tuple(map(float, widths)), tuple(tapers or ()), self._open())
        cache = self.__dict__.setdefault("_columns_cache", {})
        if key not in cache:
            if len(cache) >= 4:
                cache.pop(next(iter(cache)))
            geom = self._geometry(xy, _FLAT * float(np.max(widths)))
            cache[key] = self._columns(geom, widths, tapers)
        return cache[key][0].copy(), cache[key][1].copy()

    def basis(self, xy: np.ndarray) -> np.ndarray:
        """Design matrix ``[h_base(x), S_1(x), ..., hinges]``, shape (n, n_coef): the
        base's columns, each line's step, then a hinge column for each line with an open
        end (:meth:`_columns`). On a coarse DEM prior (:attr:`coarse_steps_`) each step's
        column is less the DEM's reading of it, and that reading follows the hinges with a
        coefficient of its own (``coarse_step1_m``...: ``terrain.dem_reading``)."""
        S, F = self._steps_and_hinges(xy)
        base = np.asarray(self.base.basis(xy), float)  # binds a raster base first
        S, coarse = coarse_columns(self, xy, S)
        return np.column_stack([base, S, F, coarse])

    def open_ends(self, xy: np.ndarray) -> tuple[tuple[bool, bool], ...]:
        """Per line, whether its first and last vertex lie inside the bounding box of
        ``xy`` (n, 2): the ends at which its step dies out."""
        lo, hi = check_xy(xy).min(axis=0), xy.max(axis=0)
        inside = [
            tuple(bool(np.all(end > lo) and np.all(end < hi)) for end in (c[0], c[-1]))
            for c in self.lines
        ]
        return tuple(inside)

    def fit(self, xy: np.ndarray, z: np.ndarray) -> BreaklineMean:
        """A fitted copy: which ends are open (:meth:`open_ends`), then with ``"auto"``
        each line's width and taper (:meth:`choose_shape`); each step's height from the
        samples beside its line (:meth:`local_steps`), then the base's coefficients by
        least squares on ``z`` less the steps. The GP's kernel is searched on those
        residuals and every coefficient then re-estimated by GLS. A global least-squares
        start would not do: a step splits the site in two, and the halves' trend difference
        (9 m on a 25 m site) read as step height left a step in the residuals that the
        kernel search fitted as rough ground."""
        xy, z = check_z(xy, z)
        out = copy.copy(self)
        ends, n = self.ends, len(self.lines)
        out.open_ends_ = {"auto": self.open_ends(xy), "open": ((True, True),) * n}.get(ends, ends)
        spacing = median_spacing(xy)  # the samples' median spacing, m: both reaches
        out.widths_, out.tapers_ = out.choose_shape(xy, z, spacing)
        steps, steps_cov = out.local_steps(xy, z, spacing)
        S, F = out._steps_and_hinges(xy)
        base = np.asarray(self.base.basis(xy), float)  # and the hinges: smooth, like it
        out.coarse_steps_ = reads_steps(self.base, out.widths_)  # the base bound by now
        tilt = (xy - xy.mean(axis=0)) / 100.0 if F.shape[1] else np.zeros((len(z), 0))
        p, q = base.shape[1], len(steps)
        # beside a plane, which they drop: the site's tilt is not a hinge's (on bei a
        # harmonic scarp's hinge started at 3.3 m without it, and the kernel search on those
        # residuals chose another family: over-confident, 91.6 % at 95)
        beta, beta_cov = ols_coefficients(np.column_stack([base, F, tilt]), z - S @ steps)
        keep = p + F.shape[1]
        beta, beta_cov = beta[:keep], beta_cov[:keep, :keep]
        # the coarse steps start as the steps (together: the bare step, as the start saw it)
        coarse = steps if out.coarse_steps_ else np.zeros(0)
        coef = np.concatenate([beta[:p], steps, beta[p:], coarse])
        cov = np.zeros((out.n_coef, out.n_coef))
        other = np.r_[0:p, p + q : keep + q]
        both = np.r_[p : p + q, keep + q : out.n_coef]  # the steps and the coarse steps
        cov[np.ix_(other, other)] = beta_cov
        cov[np.ix_(both, both)] = np.tile(steps_cov, (len(both) // q,) * 2)
        return out.with_coefficients(coef, cov)

    def choose_shape(
        self, xy: np.ndarray, z: np.ndarray, spacing: float | None = None
    ) -> tuple[tuple[float, ...], tuple[float | None, ...]]:
        """Each line's width from :data:`WIDTHS` (those up to a quarter of the reach ``R`` =
        3 x the samples' median spacing, at least 16 m: every rung on a rover's survey), then
        for a line with an open end its taper from :data:`TAPERS`, where ``"auto"``: the
        one whose step and planes (:meth:`local_steps`' model, on the samples within ``R``)
        leave the least squared residual, line by line, from 1 m and 40 m; the width then
        refined between the rung's neighbours (bounded Brent, to 1 cm). On a synthetic draw
        with steps 0.5, 1, 1.5 and 3 m wide: 0.49, 0.91, 1.33 and 2.55 m (1,500 samples on
        300 m: few on the ramp); on the 50k scarp sites 1.55 m for 1.5 (docs/terrain.md).
        Returns ``(widths, tapers)``, a taper ``None`` for a line run on at both ends."""
        spacing = median_spacing(xy) if spacing is None else spacing
        opened = [any(ends) for ends in self._open()]
        given = self.tapers_ or (None,) * len(self.lines)
        choose = [o and given[j] is None for j, o in enumerate(opened)]  # "auto" or None
        widths = list(self.widths_ or [1.0] * len(self.lines))
        tapers = [(given[j] or _TAPER_START) if o else None for j, o in enumerate(opened)]
        if self.width != "auto" and not any(choose):
            return tuple(widths), tuple(tapers)
        reach = max(3.0 * spacing, 16.0)
        near = near_samples(self, xy, reach)

        def rss(j: int, w: float | None = None, t: float | None = None) -> float:
            ws = [*widths[:j], w, *widths[j + 1 :]] if w is not None else widths
            ts = [*tapers[:j], t, *tapers[j + 1 :]] if t is not None else tapers
            return local_fit(self, z, ws, ts, near)[2]

        for j in range(len(self.lines)):
            if self.width == "auto":  # the best rung, then between its neighbours (1 cm)
                rung = min((w for w in WIDTHS if 4.0 * w <= reach), key=lambda w: rss(j, w))
                lo, hi = max(rung / 2**0.5, WIDTHS[0]), min(rung * 2**0.5, reach / 4.0)
                best = minimize_scalar(
                    lambda u, j=j: rss(j, float(np.exp(u))),
                    bounds=(np.log(lo), np.log(hi)),
                    method="bounded",
                    options={"xatol": 0.005},
                )
                widths[j] = round(float(np.exp(best.x)), 2)
            if choose[j]:
                tapers[j] = min(TAPERS, key=lambda t: rss(j, t=t))
        return tuple(widths), tuple(tapers)

    def local_steps(
        self, xy: np.ndarray, z: np.ndarray, spacing: float | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Each step's height (m) and their covariance from the samples within ``R`` of the
        lines, the ground there a plane of its own on every stretch of ``2 R`` along each
        line (least squares of ``z`` on ``[planes, S]``; ``R`` = 5 widths or 3 x the
        samples' median spacing, at least 10 m).

        Raises an ``InputError`` naming the line when no stretch has samples on both sides.
        """
        spacing = median_spacing(xy) if spacing is None else spacing
        reach = max(5.0 * max(self.widths_), 3.0 * spacing, 10.0)
        near = near_samples(self, xy, reach)
        return local_fit(self, z, self.widths_, self.tapers_, near)[:2]

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
        shape = setting_repr("width", self.width, self.widths_)
        if any(any(ends) for ends in self._open()):
            shape += ", " + setting_repr("taper", self.taper, self.tapers_)
        if self.coef_ is None:
            return f"BreaklineMean({n} line(s), {shape}, base={base!r})"
        p = int(base.n_coef)  # the base with its own coefficients, then the steps
        base = base.with_coefficients(self.coef_[:p], self.coef_cov_[:p, :p])
        steps = format_coefficients(self.coef_names[p:], self.coef_[p:], self.coef_cov_[p:, p:])
        return f"BreaklineMean({n} line(s), {shape}, base={base!r}, {steps})"

    def geojson(self) -> dict[str, Any]:
        """The lines as a GeoJSON Feature (a MultiLineString in the samples' CRS, m) with the
        steps' ``widths_m`` and ``tapers_m`` (None before a fit chose them; a taper None for
        a line run on at both ends) and ``open_ends`` in its properties: what a product
        records so that the mean can be rebuilt (``glacimap change``)."""
        widths = None if self.widths_ is None else [float(w) for w in self.widths_]
        tapers = None if self.tapers_ is None else [t and float(t) for t in self.tapers_]
        ends = None if self.open_ends_ is None else [list(e) for e in self.open_ends_]
        return {
            "type": "Feature",
            "geometry": {
                "type": "MultiLineString",
                "coordinates": [xy.tolist() for xy in self.lines],
            },
            "properties": {"widths_m": widths, "tapers_m": tapers, "open_ends": ends},
        }


#: Attributes of the mean itself, never read through to its base.
_OWN = ("base", "lines", "width", "widths_", "taper", "tapers_", "ends", "open_ends_", "coef_")
