"""Cloud-Optimized GeoTIFF of a terrain product: elevation and its 1-sigma as two bands."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from terrain.errors import bad_input

from ._files import atomic_file, check_target
from ._product import read_product

__all__ = ["BANDS", "RELATIVE_BAND", "write_cog"]

#: Band order of the GeoTIFF: (description, long name); both in metres.
BANDS = (
    ("elevation", "posterior mean elevation"),
    ("elevation_std", "posterior 1-sigma of elevation"),
)
#: Third band, when the product has it: the map's own 1-sigma, the shared offset left out.
RELATIVE_BAND = ("elevation_std_relative", "relative 1-sigma (shared survey offset excluded)")


def overview_factors(shape: tuple[int, int], min_size: int = 8) -> list[int]:
    """Decimation factors 2, 4, 8, ... while the overview's short side stays >= ``min_size``."""
    factors = []
    f = 2
    while min(shape) / f >= min_size:
        factors.append(f)
        f *= 2
    return factors


def write_cog(
    ds: Any,
    path: str | os.PathLike,
    *,
    bands: Sequence[tuple[str, str]] | None = None,
    blocksize: int = 512,
    overview_min_size: int = 8,
    compress_level: int = 6,
) -> Path:
    """Write a terrain product as a Cloud-Optimized GeoTIFF (GDAL's ``COG`` driver).

    Parameters
    ----------
    ds : xarray.Dataset
        Terrain product: ``elevation`` and ``elevation_std`` (m) on dims ``(y, x)`` with the
        CRS in its attributes (:func:`terrain.product.terrain_dataset`).
    path : path-like
        Output ``.tif``/``.tiff`` file, in an existing folder; written atomically.
    bands : sequence of (str, str), optional
        ``(variable, long name)`` pairs: write these variables of ``ds`` (metres, dims
        ``(y, x)``, each of the grid's shape) as the bands, in this order, instead of the
        terrain product's ``elevation`` / ``elevation_std`` [/ ``elevation_std_relative``].
        ``ds`` then needs only those variables and a CRS, e.g. ``dh`` and ``dh_std`` of
        :func:`terrain.difference`; its attributes (georeferencing left out) become tags.
    blocksize : int
        Tile size in pixels (a multiple of 16; COG default 512).
    overview_min_size : int
        Internal overviews halve the raster (factors 2, 4, 8, ...) while the overview's short
        side is at least this many pixels; they are averages that skip nodata.
    compress_level : int
        DEFLATE level 1-9 (horizontal floating-point predictor).

    Returns
    -------
    pathlib.Path
        ``path``.

    Notes
    -----
    Two float32 bands, descriptions ``elevation`` and ``elevation_std`` (a third,
    ``elevation_std_relative``, when the product has the map's own 1-sigma), unit ``m``, nodata
    NaN (non-finite cells of the product become nodata); the CRS and the affine transform of
    the product's Grid (pixel-is-area, north-up). The product's provenance attributes (seed,
    method, hyperparameters, ...) and ``vertical_datum`` (what the heights are: ellipsoidal
    GPS heights unless the product says otherwise) are dataset tags; JSON-encoded where not
    strings.

    With ``bands=`` the bands are those variables (unit ``m``, nodata NaN) and the tags the
    dataset's attributes.

    Raises
    ------
    terrain.errors.InputError
        Bad product (see ``read_product``), a wrong extension or an unwritable folder, a bad
        block size; with ``bands=``, a variable that is missing or not on ``(y, x)``, no CRS.
    """
    from rasterio.enums import Resampling
    from rasterio.io import MemoryFile
    from rasterio.shutil import copy as gdal_copy

    target = check_target(path, (".tif", ".tiff"), "path")
    if blocksize < 16 or blocksize % 16:
        raise bad_input("blocksize", blocksize, "a positive multiple of 16", "e.g. 512")
    if not 1 <= compress_level <= 9:
        raise bad_input("compress_level", compress_level, "an integer 1-9", "e.g. 6")
    if bands is None:
        product = read_product(ds)
        grid, tags = product.grid, product.provenance
        names = BANDS if product.elevation_std_relative is None else (*BANDS, RELATIVE_BAND)
        layers = [product.elevation, product.elevation_std, product.elevation_std_relative]
        data = np.stack(layers[: len(names)]).astype(np.float32)
    else:
        grid, names, data, tags = _named_bands(ds, bands)
    profile = {
        "driver": "GTiff",
        "width": grid.nx,
        "height": grid.ny,
        "count": len(names),
        "dtype": "float32",
        "crs": grid.crs.to_wkt(),
        "transform": grid.transform,
        "nodata": np.nan,
    }
    with MemoryFile() as mem:
        # Build the bands, metadata and overviews on an in-memory GeoTIFF, then let GDAL's COG
        # driver lay it out (IFDs first, overviews before the full resolution, tiles).
        with mem.open(**profile) as dst:
            dst.write(data)
            for i, (name, long_name) in enumerate(names, start=1):
                dst.set_band_description(i, name)
                dst.set_band_unit(i, "m")
                dst.update_tags(i, long_name=long_name, units="m")
            dst.update_tags(AREA_OR_POINT="Area", **tags)
            factors = overview_factors(grid.shape, overview_min_size)
            if factors:
                dst.build_overviews(factors, Resampling.average)
        with mem.open() as src, atomic_file(target) as tmp:
            gdal_copy(
                src,
                str(tmp),
                driver="COG",
                COMPRESS="DEFLATE",
                LEVEL=compress_level,
                PREDICTOR="YES",
                BLOCKSIZE=blocksize,
                OVERVIEWS="FORCE_USE_EXISTING" if factors else "NONE",
            )
    return target


def _named_bands(ds: Any, bands: Sequence[tuple[str, str]]):
    """(grid, band names, float32 stack (k, ny, nx), tags) of the variables ``bands`` of
    ``ds``, north-up."""
    import xarray as xr

    from terrain.grid import Grid, north_up

    from ._product import provenance_strings

    if not isinstance(ds, xr.Dataset):
        raise bad_input("ds", type(ds).__name__, "an xarray.Dataset", "pass the dataset")
    try:
        pairs = [(str(v), str(long)) for v, long in bands]
    except (TypeError, ValueError) as exc:
        raise bad_input(
            "bands", bands, "(variable, long name) pairs", "e.g. [('dh', 'dh')]"
        ) from exc
    if not pairs:
        raise bad_input("bands", bands, "at least one (variable, long name) pair", "")
    for name, _ in pairs:
        if name not in ds.data_vars or set(ds[name].dims) != {"y", "x"}:
            raise bad_input(
                f"bands '{name}'",
                sorted(str(v) for v in ds.data_vars),
                "a variable of ds on dims (y, x)",
                "name variables that the dataset has",
            )
    if not (ds.attrs.get("crs_wkt") or ds.attrs.get("crs")):
        raise bad_input("ds.attrs['crs_wkt']", None, "the CRS of the raster", "set it")
    ds = north_up(ds)
    grid = Grid.from_dataarray(ds)
    data = np.stack([ds[n].transpose("y", "x").values for n, _ in pairs]).astype(np.float32)
    data[~np.isfinite(data)] = np.nan
    return grid, pairs, data, provenance_strings(dict(ds.attrs))
