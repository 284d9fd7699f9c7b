"""A second epoch of a site: the same glacier after a known, seeded surface change.

``surface_change`` is the truth of a change experiment: inside a glacier outline the surface
thins with elevation (``max_thinning_m`` at the lowest glacier cell to ``min_thinning_m`` at
the highest -- ablation is strongest at the terminus), plus small-scale ablation features
(melt pools and widened crevasses: Gaussian depressions of 0.2-1 m, 5-20 m wide, seeded),
tapered to zero over ``taper_m`` inside the outline so that stable ground stays exactly
unchanged. ``second_epoch`` adds it to a truth DEM.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .coregister import as_polygons
from .errors import bad_input
from .grid import Grid, north_up

__all__ = ["default_outline", "second_epoch", "surface_change"]


def default_outline(bounds: tuple[float, float, float, float], margin: float = 0.2) -> Any:
    """A glacier-tongue polygon inside ``bounds`` (west, south, east, north), leaving a
    ``margin`` fraction of the site as stable ground on every side (shapely Polygon)."""
    from shapely.geometry import Polygon

    w, s, e, n = (float(b) for b in bounds)
    if not 0 < margin < 0.5:
        raise bad_input("margin", margin, "0 < margin < 0.5", "e.g. 0.2")
    t = np.linspace(0, 2 * np.pi, 73)[:-1]
    cx, cy = (w + e) / 2, (s + n) / 2
    rx, ry = (0.5 - margin) * (e - w), (0.5 - margin) * (n - s)
    # a lobed ellipse: the tongue is wider down-glacier (south-west)
    r = 1.0 + 0.08 * np.cos(2 * t + 0.7) - 0.05 * np.sin(3 * t)
    r = r / r.max()
    return Polygon(np.column_stack([cx + rx * r * np.cos(t), cy + ry * r * np.sin(t)]))


def surface_change(
    truth: Any,
    outline: Any,
    seed: int = 0,
    min_thinning_m: float = 0.5,
    max_thinning_m: float = 3.0,
    n_features: int = 12,
    taper_m: float = 20.0,
):
    """The true elevation change (m, negative = thinning) on the grid of ``truth``.

    Parameters
    ----------
    truth : xarray.DataArray
        The first epoch's true DEM (north-up or not), with a CRS.
    outline : shapely polygon(s)
        The glacier; change is zero outside.
    seed : int
        Seed of the one generator (feature positions, sizes, depths).
    min_thinning_m, max_thinning_m : float
        Thinning at the highest and the lowest glacier cell, m (0 < min <= max).
    n_features : int
        Small-scale ablation features (Gaussian depressions).
    taper_m : float
        Width of the smooth ramp inside the outline's edge, m.

    Returns
    -------
    xarray.DataArray
        ``dh`` on the truth's grid (north-up), attrs with the seed and settings.
    """
    from rasterio.features import geometry_mask
    from scipy.ndimage import distance_transform_edt

    if not 0 < min_thinning_m <= max_thinning_m:
        raise bad_input(
            "min_thinning_m/max_thinning_m",
            (min_thinning_m, max_thinning_m),
            "0 < min <= max (m)",
            "e.g. 0.5 and 3.0",
        )
    da = north_up(truth)
    g = Grid.from_dataarray(da)
    z = np.asarray(da.values, float)
    inside = ~geometry_mask(as_polygons(outline, "outline"), g.shape, g.transform)
    if not inside.any():
        raise bad_input("outline", "no cell inside", "an outline over the DEM", "")
    rng = np.random.default_rng(seed)
    zi = z[inside]
    frac = (z - zi.min()) / max(np.ptp(zi), 1e-9)  # 0 lowest .. 1 highest
    thin = -(max_thinning_m - (max_thinning_m - min_thinning_m) * np.clip(frac, 0, 1))
    xx, yy = np.meshgrid(g.x, g.y)
    feat = np.zeros(g.shape)
    cells = np.flatnonzero(inside)
    for k in rng.choice(cells, size=min(int(n_features), cells.size), replace=False):
        depth, width = rng.uniform(0.2, 1.0), rng.uniform(5.0, 20.0)
        cx, cy = xx.ravel()[k], yy.ravel()[k]
        feat -= depth * np.exp(-0.5 * ((xx - cx) ** 2 + (yy - cy) ** 2) / width**2)
    dist = distance_transform_edt(inside, sampling=(g.resolution[1], g.resolution[0]))
    ramp = np.clip(dist / float(taper_m), 0, 1) if taper_m > 0 else inside.astype(float)
    w = ramp * ramp * (3 - 2 * ramp)  # smoothstep: zero at the edge, one 'taper_m' inside
    dh = np.where(inside, w * (thin + feat), 0.0)
    return g.data_array(
        dh,
        "dh",
        seed=int(seed),
        surface_change=f"thinning {min_thinning_m:g}-{max_thinning_m:g} m with elevation, "
        f"{n_features} ablation features, taper {taper_m:g} m",
    )


def second_epoch(truth: Any, outline: Any, seed: int = 0, **kwargs: Any):
    """``truth + surface_change(truth, outline, seed, **kwargs)``: the later epoch's DEM."""
    dh = surface_change(truth, outline, seed, **kwargs)
    da = north_up(truth)
    out = da.copy(data=np.asarray(da.values, float) + dh.values)
    out.attrs.update(
        {
            "epoch": "after",
            "change_seed": int(seed),
            **{"surface_change": dh.attrs["surface_change"]},
        }
    )
    return out
