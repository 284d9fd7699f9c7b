"""A DataArray on a terrain.Grid written as a one-band float64 GeoTIFF (the tests' DEMs)."""

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
