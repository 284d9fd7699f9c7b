"""Heights on a geoid and on the WGS 84 ellipsoid: the geoid's undulation ``N`` from PROJ's grids.

A GNSS receiver measures ellipsoidal heights ``h``; topographic maps, SRTM / NASADEM / ASTER
(EGM96) and Copernicus GLO-30 (EGM2008) give orthometric heights ``H`` above a geoid, and
consumer receivers write such heights into GPX ``ele`` and NMEA's altitude. They differ by
the geoid's undulation, ``h = H + N`` (tens of metres: -107 to +85 m on Earth), which varies
slowly (centimetres per kilometre). glacimap's maps are in the rover's ellipsoidal heights
(:data:`terrain.product.VERTICAL_DATUM`); a height stated above a geoid is carried to the
ellipsoid here, never silently.

``N`` is read from the geoid's grid through PROJ's ``vgridshift`` (bilinear interpolation).
The grids are not in pyproj's wheel; they are looked for, under PROJ's CDN name and the older
``.gtx`` name, in ``$PROJ_DATA`` / ``$PROJ_LIB``, pyproj's data and user folders and the
system's PROJ folders (Debian's ``proj-data``, which GDAL's packages pull in, ships
``egm96_15.gtx``). A geoid whose grid is not found is an :class:`~terrain.errors.InputError`
naming the file and where to put it.

Reference values: NGA's EGM96 test points (``N`` from the 15' grid, e.g. 38.6281550 N,
269.7791550 E: -31.628 m); PROJ's bilinear interpolation agrees within 6 cm
(``tests/test_vertical_datum.py``).
"""

from __future__ import annotations

import os
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from .errors import bad_input
from .vertical_crs import (
    is_vertical_crs_key,
    undulation_of,
    vertical_crs_key,
    vertical_crs_name,
    vertical_undulation,
)

__all__ = [
    "GEOIDS",
    "HEIGHT_DATUMS",
    "datum_words",
    "dem_height_datum",
    "ellipsoidal_height",
    "geoid_grid",
    "geoid_height",
    "height_datum_option",
    "height_words",
    "lattice_geoid_height",
    "product_in_datum",
    "split_vertical",
    "stated_or_given",
]

#: Geoid models glacimap can apply: their grid files (PROJ CDN name first) and the vertical
#: CRS of heights above them.
GEOIDS: dict[str, dict[str, Any]] = {
    "egm96": {
        "grids": ("us_nga_egm96_15.tif", "egm96_15.gtx"),
        "crs": "EPSG:5773",
        "name": "EGM96 (SRTM, NASADEM, ASTER GDEM; most GPS receivers' sea level)",
        "fix": "install Debian's proj-data package (it ships egm96_15.gtx), or put "
        "us_nga_egm96_15.tif from https://cdn.proj.org into $PROJ_DATA",
    },
    "egm2008": {
        "grids": ("us_nga_egm08_25.tif", "egm08_25.gtx"),
        "crs": "EPSG:3855",
        "name": "EGM2008 (Copernicus GLO-30 / GLO-90)",
        "fix": "put us_nga_egm08_25.tif from https://cdn.proj.org (or projsync --file "
        "us_nga_egm08_25.tif) into $PROJ_DATA or ~/.local/share/proj",
    },
}

#: What a height can be stated as: above the WGS 84 ellipsoid or above one of :data:`GEOIDS`.
HEIGHT_DATUMS = ("ellipsoidal", *GEOIDS)

_SYSTEM_DIRS = ("/usr/share/proj", "/usr/local/share/proj", "/opt/homebrew/share/proj")


def _search_dirs() -> list[Path]:
    import pyproj.datadir

    dirs: list[str] = []
    for var in ("PROJ_DATA", "PROJ_LIB"):
        dirs += [d for d in os.environ.get(var, "").split(os.pathsep) if d]
    for get in (pyproj.datadir.get_data_dir, pyproj.datadir.get_user_data_dir):
        try:
            dirs += get().split(os.pathsep)
        except Exception:  # pragma: no cover - pyproj without a data folder
            pass
    dirs += list(_SYSTEM_DIRS)
    return [Path(d) for d in dict.fromkeys(dirs)]


def height_datum_option(value: Any, field: str, allow_auto: bool = False) -> str:
    """``value`` as one of :data:`HEIGHT_DATUMS` (case-insensitive; ``"auto"`` too when
    ``allow_auto``) or a national vertical CRS's ``"AUTH:CODE"``
    (:func:`terrain.vertical_crs.vertical_crs_key`; EPSG:5773 / 3855 are ``"egm96"`` /
    ``"egm2008"``), else an :class:`InputError` naming ``field``."""
    text = str(value).strip().lower()
    allowed = ("auto", *HEIGHT_DATUMS) if allow_auto else HEIGHT_DATUMS
    if text in allowed:
        return text
    if is_vertical_crs_key(text):
        return _datum_of_vertical(vertical_crs_key(value, field))
    raise bad_input(
        field,
        value,
        " / ".join(allowed) + " or a vertical CRS (e.g. EPSG:5941, NN2000)",
        f"e.g. {field} egm96",
    )


def _datum_of_vertical(key: str) -> str:
    """A vertical CRS's key as glacimap's datum: a key of :data:`GEOIDS` for EGM96 / EGM2008
    (their grids found by glacimap), else the key itself (PROJ's operation)."""
    return next((k for k, g in GEOIDS.items() if g["crs"] == key.upper()), key.upper())


def geoid_grid(geoid: str, field: str = "geoid") -> Path:
    """The grid file of ``geoid`` (a key of :data:`GEOIDS`) on this machine.

    Raises
    ------
    InputError
        An unknown geoid, or none of its grid files in PROJ's folders (the message names the
        file, the folders searched and the fix).
    """
    geoid = height_datum_option(geoid, field)
    if geoid == "ellipsoidal":
        raise bad_input(field, geoid, "a geoid (" + " / ".join(GEOIDS) + ")", "")
    names = GEOIDS[geoid]["grids"]
    dirs = _search_dirs()
    for d in dirs:
        for name in names:
            if (d / name).is_file():
                return d / name
    raise bad_input(
        field,
        geoid,
        f"the {geoid.upper()} grid ({' or '.join(names)}) in one of PROJ's folders "
        f"({', '.join(str(d) for d in dirs)})",
        GEOIDS[geoid]["fix"],
    )


@lru_cache(maxsize=4)
def _undulation(grid: str):
    from pyproj import Transformer

    # Z_target = Z_source + multiplier x grid value: from Z = 0, the grid's N itself
    return Transformer.from_pipeline(
        "+proj=pipeline +step +proj=unitconvert +xy_in=deg +xy_out=rad "
        f"+step +proj=vgridshift +grids={grid} +multiplier=1 "
        "+step +proj=unitconvert +xy_in=rad +xy_out=deg"
    )


def geoid_height(
    lon_deg: Any, lat_deg: Any, geoid: str = "egm96", field: str = "geoid"
) -> np.ndarray:
    """The geoid's undulation ``N`` above the WGS 84 ellipsoid at WGS 84 longitude, latitude.

    Parameters
    ----------
    lon_deg, lat_deg : array_like, shape (n,)
        WGS 84 longitude and latitude, degrees.
    geoid : str
        A key of :data:`GEOIDS`, or a national vertical CRS's ``"AUTH:CODE"``
        (:mod:`terrain.vertical_crs`: PROJ's own operation and grid).
    field : str
        The option or setting that named the geoid (for errors).

    Returns
    -------
    ndarray of shape (n,)
        ``N``, metres (``h = H + N``).
    """
    lon = np.atleast_1d(np.asarray(lon_deg, float))
    lat = np.atleast_1d(np.asarray(lat_deg, float))
    if is_vertical_crs_key(geoid):  # a national datum (or EGM96 / EGM2008 by EPSG code)
        geoid = height_datum_option(geoid, field)
        if geoid not in GEOIDS:
            return vertical_undulation(lon, lat, geoid, field)
    grid = geoid_grid(geoid, field)
    return undulation_of(_undulation(str(grid)), lon, lat, field, geoid, f"check the grid {grid}")


def ellipsoidal_height(
    height_m: Any,
    lon_deg: Any,
    lat_deg: Any,
    datum: str,
    field: str = "heights",
) -> np.ndarray:
    """Heights stated on ``datum`` (``"ellipsoidal"`` or a geoid) as WGS 84 ellipsoidal
    heights, metres: ``h = H + N``."""
    datum = height_datum_option(datum, field)
    h = np.asarray(height_m, float)
    if datum == "ellipsoidal":
        return h.copy()
    return h + geoid_height(lon_deg, lat_deg, datum, field).reshape(h.shape)


def split_vertical(crs: Any) -> tuple[Any, str | None]:
    """``(horizontal CRS, height datum)`` of a raster's CRS: a compound CRS with a geoid's
    height (e.g. ``EPSG:32632+5773``) gives that geoid's key of :data:`GEOIDS`, one with a
    national height (``EPSG:25833+5941``: NN2000) the vertical CRS's ``"EPSG:5941"``
    (:mod:`terrain.vertical_crs`), a 3-D geographic CRS (EPSG:4979) ``"ellipsoidal"``,
    anything else ``None`` (not stated).

    Raises
    ------
    InputError
        A compound CRS whose heights are not in metres or whose vertical CRS has no
        authority code.
    """
    from pyproj import CRS

    crs = CRS.from_user_input(crs)
    if not crs.is_compound:
        return crs, ("ellipsoidal" if crs.is_geographic and len(crs.axis_info) == 3 else None)
    horizontal, vertical = crs.sub_crs_list[0], crs.sub_crs_list[-1]
    return horizontal, _datum_of_vertical(vertical_crs_key(vertical, "vertical CRS"))


def dem_height_datum(attrs: dict[str, Any]) -> str | None:
    """The height datum a DEM's attributes state: ``height_datum`` (set by a reader from a
    compound CRS), else a glacimap product's ``vertical_datum`` words; ``None`` if neither
    says."""
    if attrs.get("height_datum"):
        return str(attrs["height_datum"])
    text = str(attrs.get("vertical_datum") or "").lower()
    if "not stated" in text:  # e.g. a map of a CSV whose z's datum nobody gave
        return None
    if "ellipsoid" in text and ("no geoid" in text or "geoid" not in text):
        return "ellipsoidal"
    return next((k for k in GEOIDS if k in text.replace("-", "").replace(" ", "")), None)


def lattice_geoid_height(x: Any, y: Any, crs: Any, geoid: str, field: str = "geoid") -> np.ndarray:
    """The geoid's undulation ``N`` (m) at every cell centre of a lattice: ``x`` (nx,) and
    ``y`` (ny,) in ``crs`` (projected or geographic), shape ``(ny, nx)``."""
    from pyproj import CRS, Transformer

    xx, yy = np.meshgrid(np.asarray(x, float), np.asarray(y, float))
    to_ll = Transformer.from_crs(CRS.from_user_input(crs), "EPSG:4326", always_xy=True)
    lon, lat = to_ll.transform(xx.ravel(), yy.ravel())
    return geoid_height(lon, lat, geoid, field).reshape(xx.shape)


def product_in_datum(ds: Any, datum: str, field: str = "--heights") -> tuple[Any, str]:
    """A terrain product (``xarray.Dataset`` with ``elevation``) with its heights on
    ``datum``, and in words what was done.

    The product's own datum is :func:`dem_height_datum` of its attributes (a glacimap map:
    ellipsoidal). ``elevation`` gets ``N_own - N_datum`` at each cell; the 1-sigma bands are
    kept (the geoid model's own error, decimetres, is not in them: said in
    ``vertical_datum``); ``height_datum`` and ``vertical_datum`` say the new datum.

    Raises
    ------
    InputError
        An unknown ``datum``, or a product that does not state its own.
    """
    import xarray as xr

    from .grid import dataarray_crs

    datum = height_datum_option(datum, field)
    own = dem_height_datum(ds.attrs)
    if own is None:
        raise bad_input(
            field,
            datum,
            "a product that states its heights' datum (attrs vertical_datum / height_datum)",
            "set the product's height_datum attribute first",
        )
    if own == datum:
        return ds, f"heights already above {datum_words(datum)}"
    crs = dataarray_crs(ds)
    x, y = ds["x"].values, ds["y"].values

    def undulation(d: str) -> np.ndarray:
        if d == "ellipsoidal":
            return np.zeros((y.size, x.size))
        return lattice_geoid_height(x, y, crs, d, field)

    shift = undulation(own) - undulation(datum)  # h = H + N
    out = ds.copy()
    out["elevation"] = ds["elevation"] + xr.DataArray(shift, dims=("y", "x"))
    out["elevation"].attrs = dict(ds["elevation"].attrs)
    out.attrs = {
        **ds.attrs,
        "height_datum": datum,
        "vertical_datum": f"{height_words(datum)} (from the map's heights above "
        f"{datum_words(own)} with the geoid's undulation; the geoid model's own error is "
        "not in elevation_std)",
    }
    note = (
        f"heights carried from {datum_words(own)} to {datum_words(datum)}: "
        f"{float(np.mean(shift)):+.2f} m on average ({float(np.min(shift)):+.2f} to "
        f"{float(np.max(shift)):+.2f} m)"
    )
    return out, note


def datum_words(datum: str) -> str:
    """A datum (:func:`height_datum_option`) in words: "the WGS 84 ellipsoid", "EGM96",
    "NN2000 height (EPSG:5941)"..."""
    if datum == "ellipsoidal":
        return "the WGS 84 ellipsoid"
    return datum.upper() if datum in GEOIDS else vertical_crs_name(datum)


def height_words(datum: str) -> str:
    """What a height on ``datum`` is, in words: "ellipsoidal height above the WGS 84
    ellipsoid", "orthometric height above EGM96"..."""
    if datum == "ellipsoidal":
        return "ellipsoidal height above the WGS 84 ellipsoid"
    return f"orthometric height above {datum_words(datum)}"


def stated_or_given(stated: str | None, given: Any, field: str, what: str) -> str | None:
    """The height datum of ``what``: the option ``given`` (checked) where ``what`` does not
    state its own (``stated``), else the stated one; an option that contradicts it is an
    :class:`InputError` naming ``field``."""
    given = None if given is None else height_datum_option(given, field)
    if given is not None and stated is not None and given != stated:
        raise bad_input(field, given, f"the datum the {what} state ({stated})", "drop it")
    return given or stated
