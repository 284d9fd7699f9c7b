"""The terrain product as the exporters see it: validated arrays on a Grid, plus provenance."""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

import numpy as np

from terrain import Grid
from terrain.errors import bad_input
from terrain.grid import north_up

__all__ = ["Product", "bilinear", "provenance_strings", "read_product"]

#: Attributes that describe georeferencing, not provenance (stored natively by each format).
GEOREF_ATTRS = frozenset({"crs", "crs_wkt", "transform", "resolution", "Conventions"})
VARIABLES = ("elevation", "elevation_std")


@dataclass(frozen=True)
class Product:
    """A checked terrain product.

    Attributes
    ----------
    grid : terrain.Grid
        Where the map lives (north-up, cell centres, projected CRS in metres).
    elevation, elevation_std : ndarray of shape grid.shape
        Posterior mean and 1-sigma, metres, float64; NaN where there is no value.
    elevation_std_relative : ndarray of shape grid.shape or None
        The map's own 1-sigma without the survey's shared offset (m), when the product has it.
    attrs : dict
        The product's attributes (CRS and provenance: seed, method, ...).
    """

    grid: Grid
    elevation: np.ndarray
    elevation_std: np.ndarray
    attrs: dict[str, Any]
    elevation_std_relative: np.ndarray | None = None

    @property
    def provenance(self) -> dict[str, str]:
        """Provenance attributes (everything but georeferencing) as strings, always with
        ``vertical_datum`` (:attr:`vertical_datum`)."""
        return {**provenance_strings(self.attrs), "vertical_datum": self.vertical_datum}

    @property
    def vertical_datum(self) -> str:
        """What the heights are (``attrs["vertical_datum"]``, set by
        :func:`terrain.product.terrain_dataset`), or that the product does not say."""
        return str(self.attrs.get("vertical_datum") or "not stated by the product")


def read_product(ds: Any) -> Product:
    """Validate a terrain product Dataset (docs/architecture.md §3) and load its arrays.

    Parameters
    ----------
    ds : xarray.Dataset
        Variables ``elevation`` and ``elevation_std`` (m) on dims ``(y, x)``, stored in
        either row or column order (sorted north-up here), the CRS in ``attrs["crs_wkt"]``
        or ``attrs["crs"]``. Dask-backed variables are computed.

    Raises
    ------
    terrain.errors.InputError
        Not a Dataset, a variable missing, wrong dims, no or unusable CRS, no finite
        elevation, or a negative 1-sigma.
    """
    import xarray as xr

    if not isinstance(ds, xr.Dataset):
        raise bad_input(
            "product",
            type(ds).__name__,
            "an xarray.Dataset with elevation and elevation_std",
            "use terrain.product.terrain_dataset or xarray.open_dataset(reconstruction.nc)",
        )
    for name in VARIABLES:
        if name not in ds.data_vars:
            raise bad_input(
                f"product['{name}']",
                sorted(str(v) for v in ds.data_vars),
                f"a variable named '{name}' (metres)",
                "export a terrain product made by TerrainGP.predict_grid or glacimap reconstruct",
            )
        if tuple(ds[name].dims) != ("y", "x"):
            raise bad_input(
                f"product['{name}'].dims",
                tuple(ds[name].dims),
                "('y', 'x')",
                "rename the dims to y, x and use ds.transpose('y', 'x')",
            )
    if not (ds.attrs.get("crs_wkt") or ds.attrs.get("crs")):
        raise bad_input(
            "product.attrs['crs']",
            None,
            "the CRS of the map (WKT or 'EPSG:...')",
            "set ds.attrs['crs'] = 'EPSG:32608' (or the map's projected CRS)",
        )
    try:
        ds = north_up(ds)  # rows north first, as the grid's
        grid = Grid.from_dataarray(ds)
    except (KeyError, IndexError) as exc:
        raise bad_input(
            "product coordinates",
            dict(ds.sizes),
            "x and y cell-centre coordinates (at least 2 each, or attrs['resolution'])",
            "build the product on a terrain.Grid",
        ) from exc
    elevation = np.asarray(ds["elevation"].values, dtype=float)
    std = np.asarray(ds["elevation_std"].values, dtype=float)
    elevation[~np.isfinite(elevation)] = np.nan
    std[~np.isfinite(std)] = np.nan
    if not np.isfinite(elevation).any():
        raise bad_input("product['elevation']", "all NaN", "some finite elevations", "")
    if np.nanmin(std, initial=0.0) < 0:
        raise bad_input(
            "product['elevation_std']",
            float(np.nanmin(std)),
            "non-negative 1-sigma values (m)",
            "pass standard deviations, not signed errors",
        )
    rel = None
    if "elevation_std_relative" in ds.data_vars:
        rel = np.asarray(ds["elevation_std_relative"].transpose("y", "x").values, dtype=float)
    return Product(grid, elevation, std, dict(ds.attrs), rel)


def provenance_strings(attrs: dict[str, Any]) -> dict[str, str]:
    """Non-georeferencing attributes as ``{name: str}`` (lists and arrays as JSON)."""
    out = {}
    for key, value in attrs.items():
        if key in GEOREF_ATTRS:
            continue
        if isinstance(value, str):
            out[str(key)] = value
        else:
            value = value.tolist() if isinstance(value, np.ndarray | np.generic) else value
            out[str(key)] = json.dumps(value, default=str)
    return out


def bilinear(grid: Grid, values: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Bilinear interpolation of a raster at points, ignoring NaN neighbours.

    Parameters
    ----------
    grid : terrain.Grid
        The raster's grid; values are taken at cell centres.
    values : ndarray of shape grid.shape
        The raster (row 0 north), NaN where missing.
    xy : ndarray of shape (n, 2)
        Easting/northing in the grid's CRS, metres; clamped to the cell-centre hull.

    Returns
    -------
    ndarray of shape (n,)
        The weighted mean of the (up to four) finite neighbours with bilinear weights; NaN
        where all weighted neighbours are NaN.
    """
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    dx, dy = grid.resolution
    # Fractional (col, row) of the point in cell-centre index space.
    col = np.clip((xy[:, 0] - grid.x[0]) / dx, 0, grid.nx - 1)
    row = np.clip((grid.y[0] - xy[:, 1]) / dy, 0, grid.ny - 1)
    c0 = np.minimum(np.floor(col).astype(int), max(grid.nx - 2, 0))
    r0 = np.minimum(np.floor(row).astype(int), max(grid.ny - 2, 0))
    fc, fr = col - c0, row - r0
    num = np.zeros(len(xy))
    den = np.zeros(len(xy))
    for dr, wr in ((0, 1 - fr), (1, fr)):
        for dc, wc in ((0, 1 - fc), (1, fc)):
            v = values[np.minimum(r0 + dr, grid.ny - 1), np.minimum(c0 + dc, grid.nx - 1)]
            w = np.where(np.isfinite(v), wr * wc, 0.0)
            num += w * np.nan_to_num(v)
            den += w
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 1e-12, num / den, np.nan)
