"""The tests' DEMs as one-band float64 GeoTIFFs: a DataArray on a terrain.Grid, or an array
with its transform and CRS (a compound CRS too)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rasterio

from terrain import Grid


def write_geotiff(da, path: Path) -> Path:
    """``da`` (on a north-up :class:`terrain.Grid`, its CRS) as a GeoTIFF at ``path``."""
    g = Grid.from_dataarray(da)
    with rasterio.open(
        path, "w", driver="GTiff", height=g.ny, width=g.nx, count=1, dtype="float64",
        crs=g.crs, transform=g.transform,
    ) as dst:  # fmt: skip
        dst.write(np.asarray(da.values, float), 1)
    return Path(path)


def write_array(path: Path, values, transform, crs) -> Path:
    """``values`` (ny, nx) as a GeoTIFF at ``path`` with ``transform`` (rasterio's affine
    from the north-west corner) in ``crs`` (e.g. ``"EPSG:25833+5941"``)."""
    values = np.asarray(values, float)
    with rasterio.open(
        path, "w", driver="GTiff", height=values.shape[0], width=values.shape[1], count=1,
        dtype="float64", crs=crs, transform=transform,
    ) as dst:  # fmt: skip
        dst.write(values, 1)
    return Path(path)
