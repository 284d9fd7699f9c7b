"""Baseline reconstructions the GP is judged against (paper Section II-E, Fig. 5)."""

from __future__ import annotations

import numpy as np
from scipy.interpolate import LinearNDInterpolator
from scipy.spatial import Delaunay, QhullError

from .errors import bad_input
from .grid import Grid, check_same_crs
from .samples import ElevationSamples

__all__ = ["delaunay_linear"]


def delaunay_linear(samples: ElevationSamples, grid: Grid):
    """The paper's triangular mesh: linear interpolation on the Delaunay triangulation.

    Each query inside a triangle gets the plane through its three vertices; queries outside
    the convex hull of the samples are NaN — the method covers only the hull (the paper's
    25.8 %). Measurement variance is ignored, as the paper notes it cannot be used.

    Parameters
    ----------
    samples : ElevationSamples
        At least 3 non-collinear samples.
    grid : Grid
        Cells to estimate; same CRS as the samples.

    Returns
    -------
    xarray.Dataset
        ``elevation`` (NaN outside the hull) on dims ``(y, x)``; ``attrs["covered_fraction"]``
        is the fraction of grid cells with an estimate.
    """
    import xarray as xr

    if samples.n < 3:
        raise bad_input("samples", samples.n, "at least 3 samples to triangulate", "")
    check_same_crs(samples.crs, grid.crs, "samples", "grid")
    offset = samples.xy.mean(axis=0)  # centred coordinates: Qhull precision
    try:
        # An explicit Delaunay object: LinearNDInterpolator(points) was measured 70x slower
        # to query (9.3 s vs 0.13 s for 90,000 cells and 3,730 samples, scipy 1.16).
        interp = LinearNDInterpolator(Delaunay(samples.xy - offset), samples.z)
    except QhullError as exc:
        raise bad_input(
            "samples.xy",
            f"{samples.n} points",
            "points that span an area (not collinear)",
            "collect samples off a single line",
        ) from exc
    z = interp(grid.xy() - offset).reshape(grid.shape)
    covered = float(np.isfinite(z).mean())
    return xr.Dataset(
        {"elevation": (("y", "x"), z, {"units": "m", "long_name": "Delaunay linear elevation"})},
        coords=grid.coords(),
        attrs={
            **grid.attrs(),
            "method": "Delaunay linear interpolation (scipy LinearNDInterpolator)",
            "n_samples": samples.n,
            "covered_fraction": covered,
        },
    )
