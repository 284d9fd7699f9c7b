"""Procedural, seeded glacier surface appearance: albedo and micro-relief slopes.

Everything is a function of the local ENU position (m, the log's frame), so a feature stays
attached to the snow from one frame to the next. Two layers:

* a site raster (``base_cell_m``, default 0.25 m) over the traverse's bounding box: snow /
  firn / bare-ice zones from a low-frequency field, dirt cones (dark discs 0.3-1.5 m) and
  rocks (dark dots); mip-mapped;
* two periodic detail tiles (FFT-synthesised band-limited noise, 1.5 cm and 6.1 cm texels,
  rotated against each other so that their product never repeats inside a frame): grain
  albedo and sastrugi height (anisotropic, elongated across ``wind_azimuth_deg``) whose
  slopes perturb the shading normal.

Lookups are trilinear in a mip pyramid; the level follows the pixel footprint on the ground,
which removes the far-field aliasing that otherwise invents features.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from terrain.errors import bad_input

__all__ = ["AlbedoParams", "GlacierAlbedo", "MipAtlas", "pyramid", "sample_pyramid"]


@dataclass(frozen=True)
class AlbedoParams:
    """Surface appearance of a scene (albedo in [0, 1], lengths in m)."""

    snow_fraction: float = 0.9  # share of the site under snow; the rest firn / bare ice
    snow_albedo: float = 0.85
    firn_albedo: float = 0.65
    ice_albedo: float = 0.42
    grain_contrast: float = 0.02  # relative std of the fine grain albedo on snow (flat light)
    ice_grain_contrast: float = 0.25  # relative std on bare ice (dirt in the ice)
    dirt_cones_per_100m2: float = 1.0  # dark debris cones, radius 0.3-1.5 m
    rocks_per_m2: float = 0.05  # dark stones, radius 3-15 cm
    sastrugi_height_m: float = 0.015  # std of the wind-ridge micro-relief
    sastrugi_wavelength_m: float = 0.6  # dominant across-ridge wavelength
    wind_azimuth_deg: float = 60.0  # ridges run along this azimuth (clockwise from north)
    base_cell_m: float = 0.25

    def __post_init__(self) -> None:
        for name in ("snow_fraction", "snow_albedo", "firn_albedo", "ice_albedo"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise bad_input(f"albedo.{name}", v, "a value in [0, 1]", "")
        for name in ("grain_contrast", "ice_grain_contrast", "dirt_cones_per_100m2"):
            if not getattr(self, name) >= 0:
                raise bad_input(f"albedo.{name}", getattr(self, name), "a value >= 0", "")
        if not (self.base_cell_m > 0 and self.sastrugi_wavelength_m > 0):
            raise bad_input("albedo.base_cell_m", self.base_cell_m, "a length > 0 (m)", "")


def pyramid(img: np.ndarray, periodic: bool, min_size: int = 2) -> list[np.ndarray]:
    """Mip pyramid (list of float32 arrays): each level the 2 x 2 mean of the previous."""
    levels = [np.asarray(img, np.float32)]
    while min(levels[-1].shape[:2]) >= 2 * min_size:
        a = levels[-1]
        h, w = a.shape[0] // 2 * 2, a.shape[1] // 2 * 2
        if not periodic and (h != a.shape[0] or w != a.shape[1]):
            a = a[:h, :w]
        a = a[:h, :w]
        levels.append(0.25 * (a[0::2, 0::2] + a[1::2, 0::2] + a[0::2, 1::2] + a[1::2, 1::2]))
    return levels


def _bilinear(a: np.ndarray, x: np.ndarray, y: np.ndarray, periodic: bool) -> np.ndarray:
    """``a`` (h, w[, c]) at fractional texel coordinates (x along columns, y along rows, texel
    centres at integers); wrapped when ``periodic``, clamped otherwise. OpenCV ``remap``
    (bilinear; OpenCV 5 interpolates at the float32 coordinate, no 1/32-texel table)."""
    h, w = a.shape[:2]
    if periodic:  # keep float32 coordinates small; remap wraps the last texel
        x, y = np.mod(x, w), np.mod(y, h)
    import cv2

    return _remap(a, x, y, cv2.BORDER_WRAP if periodic else cv2.BORDER_REPLICATE)


def _remap(a: np.ndarray, x: np.ndarray, y: np.ndarray, border: int) -> np.ndarray:
    """``cv2.remap`` (bilinear) of ``a`` (h, w[, c]) at the flat coordinates ``x, y`` (n,):
    (n,) or (n, c) float32. The points are laid out 1024 to a row (remap's maps must stay
    under 32767 a side)."""
    import cv2

    n = np.size(x)
    if n == 0:
        return np.zeros((0,) + a.shape[2:], np.float32)
    cols = 1024
    rows = -(-n // cols)
    mx = np.zeros(rows * cols, np.float32)
    my = np.zeros(rows * cols, np.float32)
    mx[:n], my[:n] = np.ravel(x), np.ravel(y)
    out = cv2.remap(
        a, mx.reshape(rows, cols), my.reshape(rows, cols), cv2.INTER_LINEAR, borderMode=border
    )
    return out.reshape((rows * cols,) + a.shape[2:])[:n]


class MipAtlas:
    """Mip pyramids (lists of (h, w[, c]) float32 levels, :func:`pyramid`) packed into one
    array, so that a trilinear lookup of every pyramid at every level is one ``cv2.remap``.

    Layout per pyramid (a block of rows): level 0 at the left, levels 1... stacked in a
    column to its right, every level framed by ``PAD`` texels: copies of the opposite edge
    (``periodic``) or of the nearest edge (clamped), so that a bilinear lookup never reads
    a neighbouring level. Lookup coordinates are wrapped (periodic) or clamped at level 0,
    once per point; each level's coordinate is then ``x * 2^-j + offset_j``. All pyramids
    must have the same level shapes and channels.
    """

    PAD = 2  # odd sizes lose a texel per level (pyramid() crops): 2 covers the drift

    def __init__(self, pyramids: list[list[np.ndarray]], periodic: bool):
        self.periodic = periodic
        self.flat = pyramids[0][0].ndim == 2
        pyramids = [[a[..., None] if self.flat else a for a in lev] for lev in pyramids]
        shapes = [[a.shape[:2] for a in lev] for lev in pyramids]
        if any(sh != shapes[0] for sh in shapes):
            raise bad_input("pyramids", "level shapes differ", "pyramids of one shape", "")
        P = self.PAD
        hs = np.array([h for h, _ in shapes[0]], np.int64) + 2 * P  # framed sizes
        ws = np.array([w for _, w in shapes[0]], np.int64) + 2 * P
        n = len(hs)
        col = np.where(np.arange(n) == 0, 0, ws[0])
        row = np.concatenate([[0, 0], np.cumsum(hs[1:])[:-1]])[:n]
        block = max(int(hs[0]), int(row[-1] + hs[-1]))
        width = int(ws[0] + (ws[1] if n > 1 else 0))
        self.atlas = np.zeros((block * len(pyramids), width, pyramids[0][0].shape[2]), np.float32)
        mode = "wrap" if periodic else "edge"
        for t, levels in enumerate(pyramids):
            for j, a in enumerate(levels):
                a = np.pad(a, ((P, P), (P, P), (0, 0)), mode=mode)
                r0 = t * block + row[j]
                self.atlas[r0 : r0 + a.shape[0], col[j] : col[j] + a.shape[1]] = a
        self.n_levels, self.block = n, block
        self.w0, self.h0 = float(shapes[0][0][1]), float(shapes[0][0][0])
        scale = np.ldexp(1.0, -np.arange(n))
        self.scale = scale.astype(np.float32)
        # level-j coordinate = (x + 0.5) 2^-j - 0.5 + frame + level origin in the atlas
        self.off_x = (0.5 * scale - 0.5 + P + col).astype(np.float32)
        self.off_y = [
            (0.5 * scale - 0.5 + P + row + t * block).astype(np.float32)
            for t in range(len(pyramids))
        ]
        # per pyramid, per level j: scale, x and y offsets of levels j and j + 1
        nxt = np.minimum(np.arange(n) + 1, n - 1)
        self._levels = [
            np.column_stack(
                [self.scale, self.off_x, oy, self.scale[nxt], self.off_x[nxt], oy[nxt]]
            ).astype(np.float32)
            for oy in self.off_y
        ]

    def sample(self, lookups) -> list[np.ndarray]:
        """Trilinear lookups: ``lookups`` holds per pyramid ``(x, y, lod)``, texel coordinates
        at level 0 (n,) and level of detail (log2 of the footprint in texels, >= 0). Returns
        per pyramid (n,) or (n, c) float32.

        Coordinates are wrapped (periodic) or clamped in their own precision (float64, or
        float32 when given float32: the renderer's camera-relative coordinates, ~1e-4 texel
        within 18 m of the camera), then looked up in float32."""
        import cv2

        cols = 1024  # remap's maps must stay under 32767 a side
        # every (pyramid, level) block starts on a row of the maps: the blend below is one
        # compiled pass over two equal-shaped images per pyramid (cv2.blendLinear)
        nrows = [-(-np.size(x) // cols) for x, _, _ in lookups]
        rows = max(2 * sum(nrows), 1)
        mx = np.zeros((rows, cols), np.float32)
        my = np.zeros((rows, cols), np.float32)
        flat_x, flat_y = mx.reshape(-1), my.reshape(-1)
        weights, r0 = [], 0
        for t, (x, y, lod) in enumerate(lookups):
            x, y = np.asarray(x), np.asarray(y)
            dt = np.float32 if x.dtype == np.float32 and y.dtype == np.float32 else np.float64
            x, y = x.astype(dt, copy=False).ravel(), y.astype(dt, copy=False).ravel()
            if self.periodic:  # x - floor(x / w) w: np.mod, 6x faster
                x = x - np.floor(x * dt(1.0 / self.w0)) * dt(self.w0)
                y = y - np.floor(y * dt(1.0 / self.h0)) * dt(self.h0)
            else:  # clamped at level 0 = the edge texel of every level (the frame)
                x, y = np.clip(x, 0.0, self.w0 - 1.0), np.clip(y, 0.0, self.h0 - 1.0)
            x, y = x.astype(np.float32, copy=False), y.astype(np.float32, copy=False)
            lod = np.clip(np.asarray(lod, np.float32).ravel(), 0.0, self.n_levels - 1.001)
            l0 = lod.astype(np.int32)  # floor: lod >= 0
            n, nr = x.size, nrows[t]
            f = np.zeros(nr * cols, np.float32)
            np.subtract(lod, l0, out=f[:n])
            weights.append(f.reshape(nr, cols))
            tab = np.take(self._levels[t], l0, axis=0)  # (n, 6): one gather per lookup
            for c in (0, 3):  # levels l0 and l0 + 1: x 2^-j + offset_j
                sl = slice(r0 * cols, r0 * cols + n)
                np.multiply(x, tab[:, c], out=flat_x[sl])
                flat_x[sl] += tab[:, c + 1]
                np.multiply(y, tab[:, c], out=flat_y[sl])
                flat_y[sl] += tab[:, c + 2]
                r0 += nr
        v = cv2.remap(self.atlas, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        out, r0 = [], 0
        for (x, _, _), f, nr in zip(lookups, weights, nrows, strict=True):
            n = np.size(x)
            v0, v1 = v[r0 : r0 + nr], v[r0 + nr : r0 + 2 * nr]
            res = v1 - v0  # v0 (1 - f) + v1 f
            res *= f[..., None] if res.ndim == 3 else f
            res += v0
            res = res.reshape(nr * cols, -1)[:n]
            out.append(res[:, 0] if self.flat else res)
            r0 += 2 * nr
        return out


def sample_pyramid(
    levels: list[np.ndarray], x: np.ndarray, y: np.ndarray, lod: np.ndarray, periodic: bool
) -> np.ndarray:
    """Trilinear lookup: texel coordinates ``x, y`` (level 0) at level of detail ``lod``
    (log2 of the footprint in texels, >= 0). Returns (n,) or (n, c). (One pyramid through
    :class:`MipAtlas`; build the atlas once to look up many times.)"""
    return MipAtlas([levels], periodic).sample([(x, y, lod)])[0]


def _periodic_noise(rng, n, texel, lam_lo, lam_hi, aniso=1.0, azimuth_deg=0.0, beta=2.0):
    """Band-limited periodic noise tile (n, n), std 1, and its slopes (n, n, 2) per metre.

    Power spectrum ``k^-beta`` between wavelengths ``lam_lo`` and ``lam_hi`` (m), the
    along-ridge wavenumber stretched by ``aniso`` (ridges longer than wide)."""
    k = np.fft.fftfreq(n, d=texel)  # cycles / m
    kx, ky = np.meshgrid(k, k)
    a = math.radians(azimuth_deg)  # ridge direction (east, north) = (sin a, cos a)
    along = kx * math.sin(a) + ky * math.cos(a)
    across = kx * math.cos(a) - ky * math.sin(a)
    keff = np.hypot(along * aniso, across)
    band = (keff >= 1.0 / lam_hi) & (keff <= 1.0 / lam_lo)
    amp = np.where(band, np.maximum(keff, 1e-9) ** (-beta / 2), 0.0)
    spec = amp * (rng.normal(size=(n, n)) + 1j * rng.normal(size=(n, n)))
    f = np.fft.ifft2(spec).real
    sd = f.std() or 1.0
    # texel (row, col) = (y, x): rows run north here, unlike a north-up DEM
    gx = np.fft.ifft2(spec * 2j * np.pi * kx).real / sd
    gy = np.fft.ifft2(spec * 2j * np.pi * ky).real / sd
    return (f / sd).astype(np.float32), np.stack([gx, gy], -1).astype(np.float32)


class GlacierAlbedo:
    """Seeded glacier appearance over the local rectangle ``bounds`` (west, south, east, north
    in m, log frame). ``sample(x, y, footprint)`` gives albedo (n,) and micro-relief slopes
    (n, 2) (dz/dx, dz/dy) at ground points, filtered to ``footprint`` (m per pixel)."""

    TILE = 512

    def __init__(self, bounds, params: AlbedoParams | None = None, rng=None):
        self.params = p = params or AlbedoParams()
        rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
        w, s, e, n = (float(v) for v in bounds)
        if not (e > w and n > s):
            raise bad_input("albedo bounds", bounds, "west < east, south < north", "")
        cell = max(p.base_cell_m, max(e - w, n - s) / 4096.0)  # at most 4096 cells a side
        self.cell, self.x0, self.y0 = cell, w, s
        nx, ny = int(math.ceil((e - w) / cell)) + 1, int(math.ceil((n - s) / cell)) + 1
        self.base = MipAtlas([pyramid(self._base(rng, nx, ny, cell), periodic=False)], False)
        self.tiles, tile_levels = [], []
        for texel, rot in ((0.015, 0.0), (0.061, 37.0)):
            grain, _ = _periodic_noise(rng, self.TILE, texel, 2 * texel, 40 * texel, beta=1.0)
            h, slope = _periodic_noise(
                rng,
                self.TILE,
                texel,
                p.sastrugi_wavelength_m / 4,
                p.sastrugi_wavelength_m * 3,
                aniso=4.0,
                azimuth_deg=p.wind_azimuth_deg - rot,
            )
            amp = p.sastrugi_height_m / math.sqrt(2.0)
            # slopes rotated from the tile frame to east / north once here (filtering and
            # lookups are linear): the lookup of both tiles is then one sum
            r = math.radians(rot)
            se = math.cos(r) * slope[..., 0] - math.sin(r) * slope[..., 1]
            sn = math.sin(r) * slope[..., 0] + math.cos(r) * slope[..., 1]
            c = np.stack([grain, se * amp, sn * amp], axis=-1).astype(np.float32)
            self.tiles.append((texel, math.radians(rot)))
            tile_levels.append(pyramid(c, periodic=True))
        # both tiles in one atlas: one remap for every level of both (docs/vision.md)
        self.tile_atlas = MipAtlas(tile_levels, periodic=True)

    def _base(self, rng, nx, ny, cell) -> np.ndarray:
        """Zones (snow / firn / ice), dirt cones and rocks on the site raster (ny, nx, 2):
        albedo and "bare" (0 on snow, 1 on ice: where the fine grain is strong)."""
        p = self.params
        from scipy.ndimage import gaussian_filter, map_coordinates

        coarse = 4.0  # zones vary over ~40 m: draw them on a 4 m raster, then upsample
        cy_, cx_ = int(ny * cell / coarse) + 2, int(nx * cell / coarse) + 2
        zone = gaussian_filter(rng.normal(size=(cy_, cx_)), 10.0, mode="wrap")
        zone = map_coordinates(
            zone, np.mgrid[0:ny, 0:nx] * (cell / coarse), order=1, mode="nearest"
        )
        zone = (zone - zone.mean()) / (zone.std() or 1.0)
        snow_t = float(np.quantile(zone, 1 - p.snow_fraction))
        ice_t = snow_t - 0.8
        # smooth transitions over ~0.3 sd: snow above snow_t, firn between, ice below ice_t
        w_snow = np.clip((zone - snow_t) / 0.3 + 0.5, 0, 1)
        w_ice = np.clip((ice_t - zone) / 0.3 + 0.5, 0, 1)
        albedo = w_snow * p.snow_albedo + w_ice * p.ice_albedo
        albedo += (1 - w_snow - w_ice).clip(0, 1) * p.firn_albedo
        bare = 1.0 - w_snow
        area = nx * ny * cell * cell
        for count, rmin, rmax, dark in (
            (rng.poisson(p.dirt_cones_per_100m2 * area / 100.0), 0.3, 1.5, 0.18),
            (rng.poisson(p.rocks_per_m2 * area), 0.03, 0.15, 0.12),
        ):
            cx, cy = rng.uniform(0, nx, count), rng.uniform(0, ny, count)
            r = rng.uniform(rmin, rmax, count) / cell
            for i in range(count):  # coverage of each disc, anti-aliased over one cell
                x0, x1 = int(cx[i] - r[i] - 1), int(cx[i] + r[i] + 2)
                y0, y1 = int(cy[i] - r[i] - 1), int(cy[i] + r[i] + 2)
                x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, nx), min(y1, ny)
                if x1 <= x0 or y1 <= y0:
                    continue
                d = np.hypot(np.arange(x0, x1)[None, :] - cx[i], np.arange(y0, y1)[:, None] - cy[i])
                cover = np.clip(r[i] + 0.5 - d, 0, 1) * (0.3 if r[i] < 0.5 else 1.0)
                albedo[y0:y1, x0:x1] += cover * (dark - albedo[y0:y1, x0:x1])
                bare[y0:y1, x0:x1] = np.maximum(bare[y0:y1, x0:x1], cover)
        return np.stack([albedo, bare], -1)

    def sample(self, x: np.ndarray, y: np.ndarray, footprint: np.ndarray):
        """Albedo (n,) and micro-relief slopes (n, 2) at local ground points ``x, y`` (m),
        each filtered over ``footprint`` (m, the pixel's size on the ground)."""
        x, y = np.asarray(x, float).ravel(), np.asarray(y, float).ravel()
        o = (float(np.mean(x)), float(np.mean(y))) if x.size else (0.0, 0.0)
        dx, dy = (x - o[0]).astype(np.float32), (y - o[1]).astype(np.float32)
        albedo, sx, sy = self.sample_near(dx, dy, o, np.asarray(footprint, np.float32))
        return albedo, np.column_stack([sx, sy])

    def sample_near(self, dx: np.ndarray, dy: np.ndarray, origin, footprint: np.ndarray):
        """:meth:`sample` at ``origin + (dx, dy)``: ``origin`` (east, north) in m (float64,
        e.g. the camera centre), ``dx, dy`` (n,) float32 offsets (m) and ``footprint`` (n,)
        float32 (m). Returns float32 albedo (n,) and slopes dz/dx, dz/dy (n,) each.

        The tile phase of ``origin`` is reduced in float64, the offsets in float32: texel
        coordinates keep ~1e-4 texel within 18 m of the origin."""
        p = self.params
        f32 = np.float32
        ox, oy = float(origin[0]), float(origin[1])
        log_fp = np.log2(np.maximum(footprint, f32(1e-6)))  # lod = log2(footprint / texel)
        inv = f32(1.0 / self.cell)
        (base,) = self.base.sample(
            [
                (
                    dx * inv + f32((ox - self.x0) / self.cell),
                    dy * inv + f32((oy - self.y0) / self.cell),
                    np.maximum(log_fp - f32(math.log2(self.cell)), f32(0.0)),
                )
            ]
        )
        lookups = []
        tile = float(self.TILE)
        for texel, rot in self.tiles:
            c, s = math.cos(rot), math.sin(rot)
            px = math.fmod((c * ox + s * oy) / texel, tile)  # the origin's phase, float64
            py = math.fmod((-s * ox + c * oy) / texel, tile)
            if rot == 0.0:
                tx, ty = dx * f32(1.0 / texel), dy * f32(1.0 / texel)
            else:
                tx = dx * f32(c / texel) + dy * f32(s / texel)
                ty = dy * f32(c / texel) - dx * f32(s / texel)
            tx += f32(px)
            ty += f32(py)
            lookups.append((tx, ty, np.maximum(log_fp - f32(math.log2(texel)), f32(0.0))))
        v1, v2 = self.tile_atlas.sample(lookups)
        v1 += v2  # grain, slope east, slope north (slopes rotated when the tiles were built)
        bare = base[:, 1]
        contrast = bare * f32(p.ice_grain_contrast - p.grain_contrast) + f32(p.grain_contrast)
        albedo = base[:, 0] * (1.0 + contrast * v1[:, 0] * f32(0.7071))
        smooth = 1.0 - f32(0.8) * bare  # bare ice is smoother than wind-packed snow
        return np.clip(albedo, 0.02, 1.0), v1[:, 1] * smooth, v1[:, 2] * smooth
