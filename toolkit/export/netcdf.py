"""The terrain product as CF-1.8 netCDF (``product.nc``): the variables named as CF names them,
so that GDAL, QGIS, Panoply and cf-python know what the numbers are.

The product Dataset (:func:`terrain.product.terrain_dataset`) already carries ``units`` and
``long_name`` per variable and a ``grid_mapping`` CRS. This writer adds what CF readers use
to identify the quantity (CF-1.8 sec. 3.3 standard names, sec. 3.4 ancillary data):

* ``elevation``: ``standard_name`` from the product's ``vertical_datum`` —
  ``height_above_reference_ellipsoid`` for ellipsoidal (GPS) heights, ``height_above_geoid``
  for orthometric heights on a geoid; none when the datum is not stated (never guessed) —
  and ``ancillary_variables = "elevation_std elevation_std_relative"``;
* ``elevation_std``: ``standard_name = "<that name> standard_error"`` (the CF modifier for a
  1-sigma of the same quantity);
* ``elevation_std_relative`` keeps its ``long_name`` only: it is one part of the error (the
  survey's shared offset left out), not the standard error of the elevation.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from terrain.atomic import atomic_path
from terrain.errors import bad_input

__all__ = ["cf_standard_name", "write_netcdf"]


def cf_standard_name(vertical_datum: str | None) -> str | None:
    """The CF standard name of heights on ``vertical_datum`` (the product's words), or None.

    ``"ellipsoidal height above the WGS 84 ellipsoid (GPS); no geoid applied"`` ->
    ``"height_above_reference_ellipsoid"``; a text naming a geoid or orthometric heights
    (without "no geoid") -> ``"height_above_geoid"``; anything else -> None.
    """
    text = (vertical_datum or "").lower()
    if "ellipsoid" in text and ("no geoid" in text or "geoid" not in text):
        return "height_above_reference_ellipsoid"
    if ("geoid" in text and "no geoid" not in text) or "orthometric" in text:
        return "height_above_geoid"
    return None


def write_netcdf(product: Any, path: str | os.PathLike) -> Path:
    """Write a terrain product Dataset as CF-1.8 netCDF (atomically; scipy engine, netCDF3).

    Parameters
    ----------
    product : xarray.Dataset
        ``elevation`` and ``elevation_std`` (m) on (y, x), optionally
        ``elevation_std_relative`` (m), with the product's attributes
        (:func:`terrain.product.terrain_dataset`).
    path : path-like
        Output ``.nc`` file in an existing folder.

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    InputError
        ``product`` lacks ``elevation`` or ``elevation_std``.
    """
    have = getattr(product, "data_vars", {})
    missing = [v for v in ("elevation", "elevation_std") if v not in have]
    if missing:
        raise bad_input(
            "product", f"variables missing: {missing}", "a terrain product Dataset",
            "pass the Dataset TerrainGP.predict_grid returns",
        )  # fmt: skip
    ds = product.copy(deep=False)  # the caller's Dataset keeps its attributes
    name = cf_standard_name(product.attrs.get("vertical_datum"))
    ds["elevation"] = ds["elevation"].copy(deep=False)
    ds["elevation_std"] = ds["elevation_std"].copy(deep=False)
    ancillary = [v for v in ("elevation_std", "elevation_std_relative") if v in ds.data_vars]
    ds["elevation"].attrs["ancillary_variables"] = " ".join(ancillary)
    if name is not None:
        ds["elevation"].attrs["standard_name"] = name
        ds["elevation_std"].attrs["standard_name"] = f"{name} standard_error"
    target = Path(path)
    with atomic_path(target) as tmp:
        ds.to_netcdf(tmp, engine="scipy")
    return target
