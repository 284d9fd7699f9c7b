"""Synthetic glacier terrains: the ground truth that reconstructions are scored against.

The large-scale trend follows the paper's Fig. 7 ("slowly-varying, continuous elevation
trends"): a random plane plus a handful of broad Gaussian hills and valleys. Optional
rover-scale features (snow dunes, crevasse-like troughs, melt pools) mimic the "local scale
hazards" of the simulated Mendenhall site (paper, Section II-E, Figs. 3-4: snow dunes,
crevasses, melt-water pools).

Every random parameter is drawn from one ``np.random.default_rng(seed)`` *before* anything is
evaluated, and scaled by the grid's extent only, so one seed defines one continuous surface
(:class:`TerrainFunction`) that can be sampled at any resolution or at arbitrary points. Only
the final affine rescale to the exact ``relief`` depends on which cells were sampled.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np
import xarray as xr

from .errors import bad_input
from .grid import DEFAULT_CRS, Grid

__all__ = ["DEFAULT_SITE_BOUNDS", "TerrainFeatures", "TerrainFunction", "default_site"]
__all__ += ["default_site_function", "random_terrain", "terrain_function"]

GENERATOR = "glacimap.terrain.synthetic"
GENERATOR_VERSION = "1"
#: Bounds (west, south, east, north) of the default 600 m x 600 m site, UTM 8N metres,
#: on Mendenhall Glacier near Juneau, AK (the paper's field site).
DEFAULT_SITE_BOUNDS = (526000.0, 6475000.0, 526600.0, 6475600.0)
_DEFAULT_SITE_SEED = 20100
_REF = 64  # reference lattice (per side) used to size the trend; independent of the grid
Range = tuple[float, float]


@dataclass(frozen=True)
class TerrainFeatures:
    """Rover-scale features added on top of the smooth trend; lengths and depths in metres.

    Each pair is a ``(low, high)`` range that the value is drawn uniformly from; counts are
    integer ranges, both ends included. ``dune_azimuth`` is the wind direction (degrees
    clockwise from north); ``None`` draws it at random.
    """

    dunes: bool = True
    dune_wavelength: Range = (25.0, 60.0)
    dune_amplitude: Range = (0.3, 1.0)
    dune_azimuth: float | None = None
    crevasses: tuple[int, int] = (2, 4)
    crevasse_width: Range = (2.0, 5.0)
    crevasse_depth: Range = (1.0, 3.0)
    crevasse_length: Range = (40.0, 150.0)
    melt_pools: tuple[int, int] = (1, 3)
    pool_radius: Range = (8.0, 25.0)
    pool_depth: Range = (0.5, 2.0)

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not isinstance(value, tuple):
                continue
            count = f.name in ("crevasses", "melt_pools")  # counts may be 0, sizes not
            ok = len(value) == 2 and np.all(np.isfinite(value)) and value[0] <= value[1]
            if not (ok and (value[0] >= 0 if count else value[0] > 0)):
                expected = "a (low, high) range with 0 < low <= high (counts: 0 <= low)"
                raise bad_input(f"features.{f.name}", value, expected, "e.g. (2.0, 5.0)")


@dataclass(frozen=True, eq=False)
class TerrainFunction:
    """A continuous synthetic terrain, ``xy (n, 2) -> z (n,)`` metres (easting/northing).

    ``z = base + scale * (raw(xy) - raw_min)``: :meth:`raw` is the continuous surface defined
    by the seed and the site extent; ``scale``/``raw_min`` make the sampled grid's relief
    exact (see :func:`terrain_function`). Build it with :func:`terrain_function`.
    """

    centre: tuple[float, float]
    plane: tuple[float, float]  # gradient (d/dx, d/dy) of the raw surface, m/m
    hills: np.ndarray  # (k, 5): x0, y0 (relative to centre), sx, sy, amplitude
    dunes: tuple[float, ...] | None  # amplitude, kx, ky, phase, env kx, ky, phases
    crevasses: np.ndarray  # (c, 7): cx, cy, angle, half-length, curvature, sigma, depth
    pools: np.ndarray  # (p, 4): cx, cy, radius, depth
    base: float = 0.0
    scale: float = 1.0
    raw_min: float = 0.0
    meta: dict[str, Any] = field(default_factory=dict)

    def __call__(self, xy: np.ndarray) -> np.ndarray:
        """Elevation (m) at ``xy``, shape (n, 2) -> (n,)."""
        return self.base + self.scale * (self.raw(xy) - self.raw_min)

    def raw(self, xy: np.ndarray) -> np.ndarray:
        """The continuous surface before the final rescale, shape (n, 2) -> (n,)."""
        xy = np.asarray(xy, float)
        if xy.ndim != 2 or xy.shape[1] != 2:
            raise bad_input("xy", xy.shape, "shape (n, 2) easting/northing", "stack x and y")
        u, v = xy[:, 0] - self.centre[0], xy[:, 1] - self.centre[1]
        z = self.plane[0] * u + self.plane[1] * v
        for x0, y0, sx, sy, a in self.hills:
            z = z + a * _gauss(u, x0, sx) * _gauss(v, y0, sy)
        if self.dunes is not None:
            a, kx, ky, ph, ex, ey, px, py = self.dunes
            z = z + a * _env(u, ex, px) * _env(v, ey, py) * np.sin(kx * u + ky * v + ph)
        return z + self._local(np.column_stack([u, v]))

    def raw_grid(self, grid: Grid) -> np.ndarray:
        """:meth:`raw` on every cell centre of ``grid``, shape (ny, nx), cheaply.

        The trend and dunes are separable (sums of outer products); crevasses and pools have
        compact support and are evaluated only on the window of cells they touch.
        """
        u, v = grid.x - self.centre[0], grid.y - self.centre[1]
        h = self.hills
        gx = _gauss(u[:, None], h[:, 0], h[:, 2])  # (nx, k)
        gy = _gauss(v[:, None], h[:, 1], h[:, 3]) * h[:, 4]  # (ny, k)
        z = gy @ gx.T + (self.plane[1] * v)[:, None] + (self.plane[0] * u)[None, :]
        if self.dunes is not None:  # sin(a + b) = sin a cos b + cos a sin b: rank 2
            a, kx, ky, ph, ex, ey, px, py = self.dunes
            eu, ev = a * _env(u, ex, px), _env(v, ey, py)
            z += np.outer(ev * np.cos(ky * v), eu * np.sin(kx * u + ph))
            z += np.outer(ev * np.sin(ky * v), eu * np.cos(kx * u + ph))
        for i, (lo, hi) in enumerate(self._boxes()):
            cols = np.flatnonzero((u >= lo[0]) & (u <= hi[0]))
            rows = np.flatnonzero((v >= lo[1]) & (v <= hi[1]))
            if cols.size and rows.size:
                uu, vv = np.meshgrid(u[cols], v[rows])
                block = self._local(np.column_stack([uu.ravel(), vv.ravel()]), only=i)
                z[rows[0] : rows[-1] + 1, cols[0] : cols[-1] + 1] += block.reshape(uu.shape)
        return z

    def on_grid(self, grid: Grid) -> np.ndarray:
        """Elevation (m) on every cell centre of ``grid``, shape (ny, nx)."""
        return self.base + self.scale * (self.raw_grid(grid) - self.raw_min)

    def _local(self, uv: np.ndarray, only: int | None = None) -> np.ndarray:
        """Crevasse troughs then melt pools (compact support) at centred points (n, 2).

        ``only`` selects one of them (crevasses first), as numbered by :meth:`_boxes`.
        """
        z = np.zeros(len(uv))
        nc = len(self.crevasses)
        for i, (cx, cy, ang, half, curv, sig, depth) in enumerate(self.crevasses):
            if only is not None and only != i:
                continue
            du, dv = uv[:, 0] - cx, uv[:, 1] - cy
            s = du * np.cos(ang) + dv * np.sin(ang)  # along the crack
            t = -du * np.sin(ang) + dv * np.cos(ang) - curv * s**2  # across, curved line
            a = np.clip((half - np.abs(s)) / (0.2 * half), 0.0, 1.0)  # tapered ends
            cut = np.exp(-8.0)  # the Gaussian is cut to zero (continuously) at 4 sigma
            g = np.clip((np.exp(-0.5 * (t / sig) ** 2) - cut) / (1 - cut), 0.0, None)
            z -= depth * a * a * (3 - 2 * a) * g
        for i, (cx, cy, r, depth) in enumerate(self.pools, start=nc):
            if only is None or only == i:
                q = ((uv[:, 0] - cx) ** 2 + (uv[:, 1] - cy) ** 2) / r**2
                z -= depth * np.clip(1 - q, 0.0, None) ** 2
        return z

    def _boxes(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """Axis-aligned (lo, hi) boxes, centred coordinates, outside which _local is 0."""
        out = []
        for cx, cy, ang, half, curv, sig, _ in self.crevasses:
            sag = curv * half**2
            s, t = np.meshgrid([-half, half], [min(0, sag) - 4 * sig, max(0, sag) + 4 * sig])
            s, t = s.ravel(), t.ravel()
            px = s * np.cos(ang) - t * np.sin(ang) + cx
            py = s * np.sin(ang) + t * np.cos(ang) + cy
            out.append(
                (np.array([px.min(), py.min()]) - 1e-9, np.array([px.max(), py.max()]) + 1e-9)
            )
        for cx, cy, r, _ in self.pools:
            out.append((np.array([cx - r, cy - r]), np.array([cx + r, cy + r])))
        return out


def _gauss(u: np.ndarray, c: np.ndarray | float, s: np.ndarray | float) -> np.ndarray:
    return np.exp(-0.5 * ((u - c) / s) ** 2)


def _env(u: np.ndarray, k: float, phase: float) -> np.ndarray:
    """Smooth dune envelope between 0.3 and 1."""
    return 0.65 + 0.35 * np.sin(k * u + phase)


def _check_relief(relief: float) -> float:
    try:
        r = float(relief)
    except (TypeError, ValueError) as exc:
        raise bad_input("relief", relief, "a positive number of metres", "e.g. 25.0") from exc
    if not (np.isfinite(r) and r > 0):
        fix = "pass e.g. relief=25.0 (the paper's site varies by about 25 m)"
        raise bad_input("relief", relief, "a positive finite max - min in metres", fix)
    return r


def terrain_function(
    grid: Grid,
    relief: float = 25.0,
    seed: int | np.random.Generator | None = 0,
    features: bool | TerrainFeatures = False,
    slope: float | None = None,
    *,
    base: float = 100.0,
    downhill_azimuth: float | None = None,
) -> TerrainFunction:
    """The continuous surface behind :func:`random_terrain`, rescaled to ``grid``.

    Same parameters as :func:`random_terrain`. The returned callable evaluates the very
    surface that ``random_terrain`` rasterises, at any points (e.g. off-grid samples).
    """
    relief = _check_relief(relief)
    if isinstance(features, bool):
        features = TerrainFeatures() if features else None
    elif not isinstance(features, TerrainFeatures):
        fix = "pass features=True for the defaults"
        raise bad_input("features", features, "a bool or a TerrainFeatures", fix)
    if isinstance(seed, np.random.Generator):
        rng, seed_attr = seed, "Generator"
    else:
        if seed is None:  # draw one so the terrain can be reproduced from its attrs
            seed = int(np.random.SeedSequence().generate_state(1, np.uint64)[0] >> 1)
        try:
            rng, seed_attr = np.random.default_rng(seed), int(seed)
        except (TypeError, ValueError) as exc:
            fix = "pass e.g. seed=0"
            raise bad_input("seed", seed, "a non-negative int, a Generator or None", fix) from exc
    w, s, e, n = grid.bounds
    ext = max(e - w, n - s)  # every random length below is scaled by this extent only
    # Trend (Fig. 7): a plane plus 6-12 broad Gaussian hills/valleys, widths ~80-300 m per
    # 600 m of site, centres allowed ~15% beyond the edges.
    az = rng.uniform(0, 360) if downhill_azimuth is None else float(downhill_azimuth)
    g = rng.uniform(0.2, 0.6) * relief / ext if slope is None else float(slope)
    if not (np.isfinite(g) and g >= 0):
        raise bad_input("slope", slope, "a finite gradient >= 0 (m/m)", "e.g. slope=0.02")
    k = int(rng.integers(6, 13))
    centres, widths = rng.uniform(-0.65, 0.65, (k, 2)), rng.uniform(80 / 600, 0.5, (k, 2))
    amp = rng.choice([-1.0, 1.0], k) * rng.uniform(0.3, 1.0, k)
    hills = np.column_stack([centres * ext, widths * ext, amp])
    f = features
    dunes, crev, pools = None, np.zeros((0, 7)), np.zeros((0, 4))
    if f is not None and f.dunes:
        wind = np.deg2rad(rng.uniform(0, 360) if f.dune_azimuth is None else f.dune_azimuth)
        kk = 2 * np.pi / rng.uniform(*f.dune_wavelength)
        ek = 2 * np.pi / rng.uniform(150.0, 400.0, 2)  # envelope wavelengths, m
        amp_d, phase = rng.uniform(*f.dune_amplitude), rng.uniform(0, 2 * np.pi, 3)
        dunes = (amp_d, kk * np.sin(wind), kk * np.cos(wind), phase[0], *ek, *phase[1:])
    if f is not None:
        c = int(rng.integers(f.crevasses[0], f.crevasses[1] + 1))
        where, angle = rng.uniform(-0.4, 0.4, (c, 2)) * ext, rng.uniform(0, np.pi, c)
        half = rng.uniform(*f.crevasse_length, c) / 2
        curv = rng.uniform(-0.15, 0.15, c) / half  # sag at the ends <= 15% of half-length
        sig, depth = rng.uniform(*f.crevasse_width, c) / 2, rng.uniform(*f.crevasse_depth, c)
        crev = np.column_stack([where, angle, half, curv, sig, depth])
        p = int(rng.integers(f.melt_pools[0], f.melt_pools[1] + 1))
        where, r = rng.uniform(-0.4, 0.4, (p, 2)) * ext, rng.uniform(*f.pool_radius, p)
        pools = np.column_stack([where, r, rng.uniform(*f.pool_depth, p)])
    # No more draws. Size the hills so the trend spans `relief` on a fixed reference lattice
    # over the extent (not the output grid): with the plane gradient g kept as given.
    rad = np.deg2rad(az)
    plane = (-g * np.sin(rad), -g * np.cos(rad))  # descends toward azimuth `az`
    ref = Grid(w, n, ((e - w) / _REF, (n - s) / _REF), (_REF, _REF), grid.crs)
    centre = ((w + e) / 2, (s + n) / 2)
    bare = TerrainFunction(centre, plane, hills, None, np.zeros((0, 7)), np.zeros((0, 4)))
    tilt = np.ptp(replace(bare, hills=hills[:0]).raw_grid(ref))
    if tilt >= relief:
        expected = f"a plane dropping less than relief={relief} m (it drops {tilt:.3g} m)"
        raise bad_input("slope", g, expected, "use a smaller slope or a larger relief")
    lo, hi = 0.0, 1.0
    while np.ptp(replace(bare, hills=hills * [1, 1, 1, 1, hi]).raw_grid(ref)) < relief:
        lo, hi = hi, 2 * hi
    for _ in range(60):  # range(plane + h hills) is convex in h: one crossing above h = 0
        mid = 0.5 * (lo + hi)
        span = np.ptp(replace(bare, hills=hills * [1, 1, 1, 1, mid]).raw_grid(ref))
        lo, hi = (mid, hi) if span < relief else (lo, mid)
    tf = TerrainFunction(centre, plane, hills * [1, 1, 1, 1, hi], dunes, crev, pools)
    raw = tf.raw_grid(grid)
    rmin, rspan = float(raw.min()), float(np.ptp(raw))
    if not rspan > 0:
        expected = "more than one cell so the relief is defined"
        raise bad_input("grid.shape", grid.shape, expected, "use a finer resolution")
    scale = relief / rspan
    meta = dict(seed=seed_attr, relief=relief, base=float(base), generator=GENERATOR)
    meta.update(generator_version=GENERATOR_VERSION, features_added=int(f is not None))
    on = {"dunes": dunes is not None, "crevasses": len(crev) > 0, "melt_pools": len(pools) > 0}
    meta.update(features=",".join(name for name, v in on.items() if v) or "none")
    meta.update(n_hills=k, n_crevasses=len(crev), n_melt_pools=len(pools))
    meta.update(plane_slope=g * scale, plane_downhill_azimuth=az % 360)
    return replace(tf, base=float(base), scale=scale, raw_min=rmin, meta=meta)


def random_terrain(
    grid: Grid,
    relief: float = 25.0,
    seed: int | np.random.Generator | None = 0,
    features: bool | TerrainFeatures = False,
    slope: float | None = None,
    *,
    base: float = 100.0,
    downhill_azimuth: float | None = None,
) -> xr.DataArray:
    """A random, slowly varying glacier surface on ``grid`` (paper, Fig. 7).

    Parameters
    ----------
    grid : Grid
        Where to sample the surface (cell centres).
    relief : float
        Exact max - min elevation of the result, metres (> 0).
    seed : int, Generator or None
        Seed of ``np.random.default_rng``; the same seed and extent give the same continuous
        surface at any resolution. ``None`` draws a seed and records it in ``attrs["seed"]``.
    features : bool or TerrainFeatures
        Add snow dunes, crevasse-like troughs and melt pools; ``True`` uses the defaults.
    slope : float, optional
        Gradient (m/m) of the planar trend before the final rescale; random if ``None``. The
        realised gradient is in ``attrs["plane_slope"]``.
    base : float
        Minimum elevation of the result, metres.
    downhill_azimuth : float, optional
        Direction the plane descends toward, degrees clockwise from north; random if None.

    Returns
    -------
    xarray.DataArray
        ``"elevation"``, dims (y, x), shape ``grid.shape``, metres.
    """
    tf = terrain_function(
        grid, relief, seed, features, slope, base=base, downhill_azimuth=downhill_azimuth
    )
    return grid.data_array(tf.on_grid(grid), "elevation", **tf.meta)


def default_site_function(resolution: float = 2.0) -> TerrainFunction:
    """The continuous surface of :func:`default_site` (rescaled for that resolution)."""
    grid = Grid.from_bounds(DEFAULT_SITE_BOUNDS, resolution, DEFAULT_CRS)
    feats = TerrainFeatures(crevasses=(2, 2), melt_pools=(1, 1), dune_azimuth=135.0)
    # The ice flows down-glacier to the south-west: a plane dropping ~21 m of the 25 m.
    return terrain_function(
        grid, 25.0, _DEFAULT_SITE_SEED, feats, slope=0.025, downhill_azimuth=225.0
    )


def default_site(resolution: float = 2.0) -> xr.DataArray:
    """A fixed 600 m x 600 m site like the paper's Mendenhall field site (Section IV).

    About 25 m of relief (exactly 25.0), sloping down toward the south-west, with snow
    dunes, two crevasses and a melt pool. UTM 8N bounds :data:`DEFAULT_SITE_BOUNDS`.

    Parameters
    ----------
    resolution : float
        Cell size in metres; 2.0 gives 300 x 300 cells.
    """
    grid = Grid.from_bounds(DEFAULT_SITE_BOUNDS, resolution, DEFAULT_CRS)
    tf = default_site_function(resolution)
    return grid.data_array(
        tf.on_grid(grid), "elevation", site="default (Mendenhall-like)", **tf.meta
    )
