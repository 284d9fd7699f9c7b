"""Heights above a national vertical datum, carried to the ellipsoid by PROJ's own operation.

EGM96 and EGM2008 (:data:`terrain.vertical_datum.GEOIDS`) are world geoids whose grids
glacimap looks for itself. A national DEM or a surveyor's checkpoints are often in a
national height system instead: NN2000 (Norway, EPSG:5941), LN02 / LHN95 (Switzerland,
EPSG:5728 / 5729), NAVD88 (USA, EPSG:5703), CGVD2013 (Canada, EPSG:6647), NZVD2016 (EPSG:7839),
ISH2004 (Iceland, EPSG:8089)... PROJ's database knows, for each, the geoid model that relates
it to an ellipsoidal height and the grid file that holds it
(``no_kv_HREF2018B_NN2000_EUREF89.tif``, ``us_noaa_g2018u0.tif``...). Such a datum is named
here by its vertical CRS, ``"EPSG:5941"``, and its undulation ``N`` (``h = H + N``) is what
PROJ's best operation from the compound CRS *WGS 84 + that height* to WGS 84's 3-D CRS
(EPSG:4979) gives at ``H = 0``.

PROJ quietly falls back to a "ballpark" operation (``h = H``, no geoid) when the grid is not
on the machine; that would put the geoid's undulation (tens of metres) into every height.
Here the operation is PROJ's most accurate one, over the positions' area, whose grid is on
the machine, never a ballpark: with none, an :class:`InputError` names the grids that would
do and how to get one (``projsync --file NAME``, or the file from https://cdn.proj.org into
``~/.local/share/proj`` or ``$PROJ_DATA``); a datum PROJ relates to the ellipsoid only by a
ballpark is refused. The ellipsoidal frame of a national geoid (ETRS89, NAD83(2011),
NZGD2000) is taken as WGS 84's: they differ by centimetres to a metre horizontally and
centimetres in height, far below a rover's survey error and the geoid model's own.

Reference values: a geoid grid written under PROJ's file name with a known linear field,
read back bilinearly by PROJ to rounding (``tests/test_vertical_crs.py``).
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np

from .errors import bad_input

__all__ = [
    "is_vertical_crs_key",
    "undulation_of",
    "vertical_crs_key",
    "vertical_crs_name",
    "vertical_undulation",
]

#: How to get a grid PROJ names (the fix of a missing-grid error).
_GRID_FIX = (
    "projsync --file {name} (it writes to ~/.local/share/proj), or put {name} from "
    "https://cdn.proj.org into $PROJ_DATA or ~/.local/share/proj"
)


def is_vertical_crs_key(text: Any) -> bool:
    """Whether ``text`` looks like an ``AUTHORITY:CODE`` CRS name (not checked against PROJ)."""
    head, sep, tail = str(text).strip().partition(":")
    return bool(sep) and head.isalpha() and tail.strip() != ""


def vertical_crs_key(value: Any, field: str) -> str:
    """``value`` (``"EPSG:5941"``, a ``pyproj.CRS``) as a vertical CRS's ``"AUTH:CODE"``.

    Raises
    ------
    InputError
        Not a CRS pyproj knows, not a vertical CRS (a compound CRS gives its vertical part;
        a horizontal CRS states no heights), heights not in metres, or a CRS without an
        authority code.
    """
    from pyproj import CRS
    from pyproj.exceptions import CRSError

    try:
        crs = value if isinstance(value, CRS) else CRS.from_user_input(str(value).strip())
    except CRSError as exc:
        raise bad_input(
            field, value, "ellipsoidal / egm96 / egm2008 or a vertical CRS (e.g. EPSG:5941)", ""
        ) from exc
    if crs.is_compound:
        crs = crs.sub_crs_list[-1]
    if not crs.is_vertical:
        raise bad_input(
            field,
            value,
            "a vertical CRS (heights), e.g. EPSG:5941 for NN2000 or EPSG:5703 for NAVD88",
            f"{crs.name} is not one: name the heights' datum, not the map's projection",
        )
    unit = crs.axis_info[0].unit_name if crs.axis_info else "metre"
    if unit not in ("metre", "meter"):
        raise bad_input(
            field,
            f"{crs.name} ({unit})",
            "heights in metres",
            "convert the heights to metres and name the metre version of the datum "
            "(e.g. EPSG:5703 for NAVD88 height in metres)",
        )
    code = crs.to_authority(min_confidence=100)
    if code is None:
        raise bad_input(
            field,
            crs.name,
            "a vertical CRS with an authority code (e.g. EPSG:5941)",
            "name the datum by its EPSG code",
        )
    return f"{code[0]}:{code[1]}"


def vertical_crs_name(key: str) -> str:
    """``"NN2000 height (EPSG:5941)"``: the vertical CRS's name and key, in words."""
    from pyproj import CRS

    return f"{CRS.from_user_input(key).name} ({key})"


def _operation(key: str, field: str, lon: np.ndarray, lat: np.ndarray) -> Any:
    """PROJ's best usable operation, over the positions' area, from WGS 84 + ``key``
    heights to WGS 84's 3-D CRS (a ballpark never)."""
    from pyproj import CRS
    from pyproj.crs import CompoundCRS
    from pyproj.transformer import AreaOfInterest, TransformerGroup

    vertical = CRS.from_user_input(key)
    source = CompoundCRS(f"WGS 84 + {vertical.name}", [CRS("EPSG:4326"), vertical])
    ok = np.isfinite(lon) & np.isfinite(lat)
    area = (
        AreaOfInterest(lon[ok].min(), lat[ok].min(), lon[ok].max(), lat[ok].max())
        if ok.any()
        else None
    )
    with warnings.catch_warnings():  # pyproj warns of a missing grid: said below instead
        warnings.simplefilter("ignore", UserWarning)
        group = TransformerGroup(source, CRS("EPSG:4979"), always_xy=True, area_of_interest=area)
    usable = [t for t in group.transformers if "ballpark" not in t.description.lower()]
    if usable:  # PROJ's order: the most accurate of the operations whose grids are here
        return usable[0]
    options = []  # the grids of PROJ's best operations, any one of which would do
    for op in group.unavailable_operations:
        names = " and ".join(g.short_name for g in op.grids if not g.available)
        if names and names not in options:
            options.append(names)
    use = vertical.area_of_use
    if not options and use is not None and area is not None and not _inside(area, use):
        raise bad_input(
            field,
            f"{vertical_crs_name(key)} at lon {area.west_lon_degree:.4f} to "
            f"{area.east_lon_degree:.4f}, lat {area.south_lat_degree:.4f} to "
            f"{area.north_lat_degree:.4f}",
            f"positions inside its area of use ({use.name})",
            "check that the datum is the one of the site's country",
        )
    if not options:
        raise bad_input(
            field,
            vertical_crs_name(key),
            "a height datum PROJ relates to the WGS 84 ellipsoid by a geoid model",
            "convert the heights to ellipsoidal (or EGM96 / EGM2008) heights with the "
            "national agency's tool and name that datum",
        )
    first = options[0].split(" and ")
    raise bad_input(
        field,
        vertical_crs_name(key),
        f"PROJ's geoid grid for {vertical.name} here on this machine (any of: "
        + "; ".join(options[:3])
        + ")",
        "; ".join(_GRID_FIX.format(name=n) for n in first)
        + "; or set PROJ_NETWORK=ON to let PROJ fetch it",
    )


def _inside(area: Any, use: Any) -> bool:
    """Whether the positions' box overlaps a CRS's area of use (degrees; an area across the
    antimeridian has its west bound east of its east bound)."""
    if area.north_lat_degree < use.south or area.south_lat_degree > use.north:
        return False
    west, east = area.west_lon_degree, area.east_lon_degree
    if use.west <= use.east:
        return not (east < use.west or west > use.east)
    return east >= use.west or west <= use.east


def vertical_undulation(lon_deg: Any, lat_deg: Any, key: str, field: str) -> np.ndarray:
    """``N`` (m) of the datum ``key`` at WGS 84 longitude, latitude: ``h = H + N``.

    Parameters
    ----------
    lon_deg, lat_deg : array_like, shape (n,)
        WGS 84 longitude and latitude, degrees.
    key : str
        A vertical CRS, ``"AUTH:CODE"`` (:func:`vertical_crs_key`).
    field : str
        The option or setting that named the datum (for errors).

    Returns
    -------
    ndarray of shape (n,)
        The ellipsoidal height of ``H = 0`` there, metres.

    Raises
    ------
    InputError
        The grid is missing, PROJ knows no geoid model for the datum, or a position lies
        outside the grid.
    """
    lon = np.atleast_1d(np.asarray(lon_deg, float))
    lat = np.atleast_1d(np.asarray(lat_deg, float))
    op = _operation(key, field, lon, lat)
    return undulation_of(
        op, lon, lat, field, vertical_crs_name(key), "check that the datum is the site's country's"
    )


def undulation_of(op: Any, lon: np.ndarray, lat: np.ndarray, field: str, what: str, fix: str):
    """The ellipsoidal height of ``H = 0`` by the PROJ operation ``op`` (WGS 84 + heights
    -> 3-D) at ``lon, lat`` (degrees); a position outside its grid (PROJ gives inf) is an
    :class:`InputError` naming ``what`` there and ``fix``."""
    _, _, n = op.transform(lon, lat, np.zeros_like(lon), errcheck=False)
    n = np.asarray(n, float)
    bad = ~np.isfinite(n) | (np.abs(n) > 200.0)  # outside the grid: PROJ gives inf
    if bad.any():
        i = int(np.argmax(bad))
        raise bad_input(
            field,
            f"{what} at lon {lon[i]:.6f}, lat {lat[i]:.6f}",
            "a position the geoid grid covers",
            fix,
        )
    return n
