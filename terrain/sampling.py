"""Sample a true DEM the way a rover's camera does: landmarks beside a driven path.

This stands in for the localization stage until real landmark selection feeds the terrain
stage (docs/architecture.md §1 step 4): most landmarks lie close to the path, none closer than the
paper's 5 m first-seen distance (Section II-E), each with an elevation variance that grows
with range — what Eq 7 gives a monocular landmark.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import RegularGridInterpolator

from .errors import bad_input
from .grid import Grid, north_up
from .samples import ElevationSamples

__all__ = ["LandmarkNoise", "sample_along_path", "sample_dem"]


def sample_dem(truth, xy: np.ndarray) -> np.ndarray:
    """Bilinear interpolation of a DEM ``DataArray`` at points ``xy`` (n, 2), metres.

    Points outside the cell-centre hull of the DEM are an error (never silently NaN). The
    DEM's rows may run north to south or south to north.
    """
    grid = Grid.from_dataarray(truth)
    truth = north_up(truth)
    xy = np.asarray(xy, dtype=float)
    x, y = grid.x, grid.y
    outside = (xy[:, 0] < x[0]) | (xy[:, 0] > x[-1]) | (xy[:, 1] < y[-1]) | (xy[:, 1] > y[0])
    if outside.any():
        raise bad_input(
            "xy",
            f"{int(outside.sum())} points outside the DEM",
            "points inside the DEM's cell centres",
            "clip the points to the DEM extent first",
        )
    # RegularGridInterpolator needs increasing axes: flip y (north-up rows).
    interp = RegularGridInterpolator((y[::-1], x), np.asarray(truth.values)[::-1], method="linear")
    return interp(xy[:, ::-1])


@dataclass(frozen=True)
class LandmarkNoise:
    """Where landmarks fall relative to the path and how noisy their elevations are.

    Parameters
    ----------
    min_range : float
        Nearest landmark distance from the path, m (the paper's 5 m first-seen rule).
    max_range : float
        Farthest landmark distance, m (camera range limit).
    range_scale : float
        Mean of the exponential excess range beyond ``min_range``, m: most landmarks are
        near the path, as in the paper's Fig. 12.
    sigma0, sigma_per_m : float
        Elevation 1-sigma = ``sigma0 + sigma_per_m * range`` (m, m/m).
    sigma_max : float
        Cap on the elevation 1-sigma, m (the paper's 0.5 m selection rule).
    """

    min_range: float = 5.0
    max_range: float = 60.0
    range_scale: float = 12.0
    sigma0: float = 0.08
    sigma_per_m: float = 0.006
    sigma_max: float = 0.5

    def sigma(self, rng_m: np.ndarray) -> np.ndarray:
        return np.minimum(self.sigma0 + self.sigma_per_m * rng_m, self.sigma_max)


def sample_along_path(
    truth,
    path: np.ndarray,
    n: int,
    noise: LandmarkNoise | None = None,
    seed: int | np.random.Generator | None = 0,
) -> tuple[ElevationSamples, int]:
    """``n`` noisy landmark elevations scattered beside a driven polyline.

    Parameters
    ----------
    truth : xarray.DataArray
        True DEM (dims y, x) with CRS attributes.
    path : ndarray of shape (k, 2)
        Waypoints of the driven path, easting/northing in m, k >= 2.
    n : int
        Number of landmarks wanted inside the DEM.
    noise : LandmarkNoise, optional
        Range and noise model.
    seed : int or Generator
        Randomness for positions and noise.

    Returns
    -------
    samples : ElevationSamples
        ``extra`` holds ``range_m`` (distance from the path, m) and ``true_z`` (m).
    n_rejected : int
        Candidate landmarks that fell outside the DEM and were redrawn (counted, not hidden).
    """
    noise = noise or LandmarkNoise()
    rng = np.random.default_rng(seed)
    path = np.asarray(path, dtype=float)
    if path.ndim != 2 or path.shape[0] < 2 or path.shape[1] != 2:
        raise bad_input("path", path.shape, "waypoints of shape (k >= 2, 2)", "")
    if int(n) < 1:
        raise bad_input("n", n, "at least one landmark", "")
    seg = np.diff(path, axis=0)
    seg_len = np.hypot(seg[:, 0], seg[:, 1])
    if seg_len.sum() <= 0:
        raise bad_input("path", "zero length", "a path that moves", "")
    cum = np.concatenate([[0.0], np.cumsum(seg_len)])
    grid = Grid.from_dataarray(truth)
    x, y = grid.x, grid.y
    kept_xy, kept_r, rejected = [], [], 0
    while sum(len(k) for k in kept_xy) < n:
        m = 2 * int(n)
        s = rng.uniform(0.0, cum[-1], m)
        i = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, seg.shape[0] - 1)
        t = ((s - cum[i]) / np.where(seg_len[i] > 0, seg_len[i], 1.0))[:, None]
        base = path[i] + t * seg[i]
        normal = np.column_stack([-seg[i, 1], seg[i, 0]]) / np.maximum(seg_len[i], 1e-12)[:, None]
        excess = rng.exponential(noise.range_scale, m)
        r = np.minimum(noise.min_range + excess, noise.max_range)
        side = rng.choice([-1.0, 1.0], m)
        pts = base + (side * r)[:, None] * normal
        inside = (
            (pts[:, 0] >= x[0]) & (pts[:, 0] <= x[-1]) & (pts[:, 1] >= y[-1]) & (pts[:, 1] <= y[0])
        )
        rejected += int((~inside).sum())
        kept_xy.append(pts[inside])
        kept_r.append(r[inside])
    xy = np.concatenate(kept_xy)[:n]
    r = np.concatenate(kept_r)[:n]
    true_z = sample_dem(truth, xy)
    sigma = noise.sigma(r)
    z = true_z + rng.normal(0.0, 1.0, n) * sigma
    return ElevationSamples(
        xy,
        z,
        sigma**2,
        crs=grid.crs,
        extra={"range_m": r, "true_z": true_z},
        duplicates="average",
    ), rejected
