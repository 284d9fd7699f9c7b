"""The map grid of ``glacimap reconstruct --like RASTER``: the raster's own cells, and the
samples moved into its CRS when it is another projected one."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from pyproj import CRS, Transformer

from terrain import ElevationSamples
from terrain.errors import bad_input

from .samples_io import SampleTable

__all__ = ["grid_like"]


def grid_like(path: str | Path, table: SampleTable) -> tuple[Any, SampleTable, str]:
    """The map grid of ``--like RASTER`` and the samples in its CRS.

    A raster in another projected CRS than the samples: the samples' x, y are projected into
    the raster's CRS (heights unchanged), so the map lands on the raster's own cells (to
    difference it with that raster, say). A raster in a geographic CRS is refused: the GP's
    distances are in metres.

    Returns
    -------
    (terrain.Grid, SampleTable, str)
        The raster's grid, the samples in its CRS, and a note saying what was projected ("" when
        nothing was).

    Raises
    ------
    InputError
        No file, a raster GDAL cannot read or without a CRS, a geographic CRS, or a raster that
        holds none of the samples.
    """
    import rasterio
    from rasterio.errors import RasterioIOError

    from .dem_io import read_dem

    path = Path(path)
    if not path.is_file():
        raise bad_input("--like", str(path), "an existing raster file", "check the path")
    try:
        with rasterio.open(path) as src:
            crs = None if src.crs is None else CRS.from_wkt(src.crs.to_wkt())
    except RasterioIOError as exc:
        raise bad_input("--like", path.name, "a raster GDAL can read", str(exc)) from exc
    if crs is None:
        raise bad_input(
            "--like", path.name, "a raster with a CRS", "set it (gdal_edit.py -a_srs EPSG:...)"
        )
    target = table.samples.crs
    if crs.is_geographic:
        raise bad_input(
            "--like",
            f"{path.name} ({crs.name})",
            "a raster in a projected CRS in metres (the map's distances are metres)",
            f"reproject it first (gdalwarp -t_srs {target.to_string()} {path.name} OUT.tif) "
            "or pass --bounds W S E N and --resolution",
        )
    grid = read_dem(path).grid
    samples, note = table.samples, ""
    if not grid.crs.equals(target, ignore_axis_order=True):
        tr = Transformer.from_crs(target, grid.crs, always_xy=True)
        xy = np.column_stack(tr.transform(samples.xy[:, 0], samples.xy[:, 1]))
        samples = ElevationSamples(
            xy, samples.z, samples.z_var, crs=grid.crs, extra=dict(samples.extra)
        )
        note = (
            f"samples projected from {target.to_string()} to {path.name}'s CRS "
            f"{grid.crs.to_string()} ({grid.crs.name}); heights unchanged"
        )
    x, y = samples.xy[:, 0], samples.xy[:, 1]
    w, s, e, n = grid.bounds
    if not ((x >= w) & (x <= e) & (y >= s) & (y <= n)).any():
        raise bad_input(
            "--like",
            f"{path.name} (bounds {w:.1f}, {s:.1f}, {e:.1f}, {n:.1f}, {grid.crs.to_string()})",
            f"a raster whose extent holds some of the {samples.n} samples",
            "check that the samples' CRS (--crs) and the raster's are right",
        )
    out = SampleTable(samples, table.track_z_std, table.shared_z_std, table.note)
    out.derived = table.derived
    return grid, out, note
