"""Voids of an elevation change filled by elevation band: the mean-hypsometric method.

Satellite DEM pairs leave voids on a glacier (clouds, shadow, saturated snow, radar
layover), most in the accumulation area or on the tongue, and a glacier's thinning depends
on elevation (strongest low down). Filling every void with the glacier's mean ``dh`` then
biases the volume: a void on the tongue gets the glacier's mean thinning instead of the
tongue's. McNabb, Nuth, Kääb & Girod (2019, The Cryosphere 13, 895-910: "Sensitivity of
glacier volume change estimation to DEM void interpolation") compared the methods on
thousands of glaciers; the hypsometric ones were the least biased. Here (their "mean
hypsometric"):

1. the glacier's cells with ``dh`` are binned by the earlier surface's elevation
   (``elevation_before``; ``elevation_after`` where that is a void too) into
   :data:`N_BANDS` bands of equal height over the glacier's range;
2. each band's area-weighted mean ``dh`` fills the band's voids; a band without data takes
   the value interpolated linearly in elevation between the nearest bands with data (the
   end bands' values beyond them); a void without any elevation takes the glacier's mean;
3. the fill's 1-sigma: a filled cell's ``dh`` is unknown within its band's spread of ``dh``
   (the weighted standard deviation about the band's mean; the glacier's spread for an
   interpolated band or a cell without elevation), fully correlated inside a band (voids
   are contiguous) and independent between bands; the band's mean is itself uncertain by
   the same spread over its data's effective number of independent patches, taken as
   their area over the void's (a correlation as wide as the void), so its volume term is
   ``sqrt(sum_b (sd_b * A_filled,b)^2 * (1 + A_filled,b / A_data,b))`` (1 + 1 for an
   interpolated band). Measured on eleven real sites (``benchmarks/void_fill.py``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["N_BANDS", "hypsometric_fill"]

#: Elevation bands over the glacier's range (McNabb et al. 2019 used 50 m bins on glaciers
#: a few hundred metres to kilometres high: about ten).
N_BANDS = 10


def _weighted_sd(v: np.ndarray, w: np.ndarray) -> float:
    m = float(np.sum(w * v) / np.sum(w))
    return float(np.sqrt(np.sum(w * (v - m) ** 2) / np.sum(w)))


def hypsometric_fill(
    dh: np.ndarray, z: np.ndarray, weights: np.ndarray, inside: np.ndarray
) -> tuple[np.ndarray, dict[str, Any]]:
    """``dh`` with the voids inside the glacier filled by elevation band, and the record.

    Parameters
    ----------
    dh : ndarray (ny, nx)
        Elevation change, m; NaN for voids.
    z : ndarray (ny, nx)
        The elevation the bands are of, m (NaN where unknown).
    weights : ndarray (ny, nx)
        Each cell's area inside the glacier, m^2.
    inside : ndarray of bool (ny, nx)
        The glacier's cells; at least one with a finite ``dh``.

    Returns
    -------
    (filled, record)
        ``filled``: ``dh`` with every void inside the glacier filled (outside unchanged).
        ``record``: ``method``, ``n_filled``, ``n_filled_without_elevation``, ``bands``
        (``z_lo, z_hi, mean_dh, sd_dh, n_cells, n_filled, interpolated``) and
        ``fill_std_m3``, the fill's volume 1-sigma.
    """
    dh = np.asarray(dh, float)
    z = np.asarray(z, float)
    w = np.asarray(weights, float)
    valid = inside & np.isfinite(dh)
    void = inside & ~np.isfinite(dh)
    filled = dh.copy()
    overall = float(np.sum(w[valid] * dh[valid]) / np.sum(w[valid]))
    overall_sd = _weighted_sd(dh[valid], w[valid])
    record: dict[str, Any] = {
        "method": "mean hypsometric (McNabb et al. 2019): each void the mean dh of its "
        f"elevation band ({N_BANDS} bands of the earlier surface over the glacier)",
        "n_filled": int(void.sum()),
        "n_filled_without_elevation": 0,
        "bands": [],
        "fill_std_m3": 0.0,
    }
    if not void.any():
        return filled, record
    known = valid & np.isfinite(z)
    if not known.any():  # no elevation anywhere: the glacier's mean, its spread
        filled[void] = overall
        record["n_filled_without_elevation"] = int(void.sum())
        record["fill_std_m3"] = overall_sd * float(w[void].sum())
        return filled, record
    lo, hi = float(z[known].min()), float(z[known].max())
    edges = np.linspace(lo, hi, N_BANDS + 1) if hi > lo else np.array([lo, lo + 1.0])
    band = np.clip(np.searchsorted(edges, z, side="right") - 1, 0, edges.size - 2)
    centre = 0.5 * (edges[:-1] + edges[1:])
    means = np.full(centre.size, np.nan)
    sds = np.full(centre.size, np.nan)
    for b in range(centre.size):
        m = known & (band == b)
        if m.any():
            means[b] = float(np.sum(w[m] * dh[m]) / np.sum(w[m]))
            sds[b] = _weighted_sd(dh[m], w[m]) if m.sum() > 1 else overall_sd
    have = np.isfinite(means)
    interpolated = ~have
    means[~have] = np.interp(centre[~have], centre[have], means[have])
    sds[~have] = overall_sd
    with_z = void & np.isfinite(z)
    filled[with_z] = means[band[with_z]]
    no_z = void & ~np.isfinite(z)
    filled[no_z] = overall
    var = float(overall_sd * w[no_z].sum()) ** 2
    for b in range(centre.size):
        area_b = float(w[with_z & (band == b)].sum())
        data_b = float(w[known & (band == b)].sum())
        # the band's mean is itself uncertain where its data are few against its voids
        share = area_b / data_b if data_b > 0 else 1.0
        var += (sds[b] * area_b) ** 2 * (1.0 + share)
        record["bands"].append(
            {
                "z_lo": float(edges[b]),
                "z_hi": float(edges[b + 1]),
                "mean_dh": float(means[b]),
                "sd_dh": float(sds[b]),
                "n_cells": int((known & (band == b)).sum()),
                "n_filled": int((with_z & (band == b)).sum()),
                "interpolated": bool(interpolated[b]),
            }
        )
    record["n_filled_without_elevation"] = int(no_z.sum())
    record["fill_std_m3"] = float(np.sqrt(var))
    return filled, record
