"""Geometries of a vector file in the map's CRS: glacier outlines and stable ground
(``glacimap change``), breaklines (``reconstruct`` / ``process --breaklines``).

Any vector file GDAL reads (GeoPackage, GeoJSON, Shapefile, KML...) through pyogrio, and
reprojected with pyproj from the CRS it declares; a WKT text file (one geometry per line)
through shapely, taken to be in the map's CRS (WKT carries none). One trap is handled: a
GeoJSON file without a ``crs`` member is declared WGS 84 by GDAL (RFC 7946), whatever its
coordinates are. Coordinates that cannot be longitude / latitude are then read in the map's
CRS, and the note says so. The other way round, geometries whose every coordinate could be
longitude / latitude while the map's CRS is projected and the file declares nothing are
refused by name: they would lie thousands of kilometres off the map.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from terrain.errors import InputError, bad_input

__all__ = ["read_geometries"]

_WKT_TYPES = (b"POINT", b"LINESTRING", b"POLYGON", b"MULTI", b"GEOMETRYCOLLECTION")


def _is_wkt(path: Path) -> bool:
    """Text that starts with a WKT keyword (``LINESTRING (...``), whatever the suffix."""
    head = path.read_bytes()[:64].lstrip().upper()
    return head.startswith(_WKT_TYPES)


def _could_be_lonlat(geoms: list) -> bool:
    import shapely

    xy = np.vstack([shapely.get_coordinates(g) for g in geoms] or [np.zeros((0, 2))])
    return bool(xy.size) and bool(
        np.all(np.abs(xy[:, 0]) <= 180) and np.all(np.abs(xy[:, 1]) <= 90)
    )


def _where(path: Path, field: str, where: str, info: dict) -> tuple[list, str]:
    """The geometries of the features ``where`` selects and the selection in words."""
    import pyogrio
    import shapely

    names = ", ".join(map(str, info.get("fields", []))) or "(none)"
    try:
        wkb = pyogrio.raw.read(path, where=where)[2]
    except Exception as exc:  # pyogrio's FieldError / DataLayerError: the clause
        raise bad_input(
            f"{field}-where", where, "an OGR SQL WHERE clause on the file's attributes",
            f"{path.name}'s attributes: {names} (e.g. \"RGIId = 'RGI60-07.01482'\"); {exc}",
        ) from exc  # fmt: skip
    if not len(wkb):
        raise bad_input(
            f"{field}-where", where, f"a clause that selects features of {path.name}",
            f"{path.name}'s attributes: {names}; it has {info['features']} features",
        )  # fmt: skip
    return list(shapely.from_wkb(wkb)), f"{len(wkb)} of {info['features']} features: {where}"


def read_geometries(
    path: Path, field: str, crs: Any = None, where: str | None = None
) -> tuple[list, str]:
    """The geometries of ``path`` (shapely, file order), in ``crs`` when given, and a note
    on how they were read (``"<field>: same CRS"``, ``"... reprojected from EPSG:4326"``,
    ``"... no CRS declared: read in the map's CRS"``), which counts the empty or missing
    geometries left out.

    ``where`` (an OGR SQL WHERE clause, as ``ogr2ogr -where``) keeps the features it selects:
    one glacier of an inventory (RGI, GLIMS) by its ID.

    Raises an ``InputError`` naming ``field`` when the file is missing or does not parse,
    when ``where`` does not parse or selects nothing (the message lists the attributes), or
    when its coordinates look like longitude / latitude for a projected ``crs`` and it
    declares no CRS.
    """
    import shapely
    from pyproj import CRS, Transformer

    path = Path(path)
    if not path.is_file():
        raise bad_input(field, str(path), "an existing vector file (GeoJSON, GeoPackage, "
                        "Shapefile, WKT...)", "check the path")  # fmt: skip
    declared = None
    selected = ""
    try:
        if _is_wkt(path):
            if where:
                raise bad_input(f"{field}-where", where, "a vector file with attributes",
                                f"{path.name} is WKT lines: select the lines by hand")  # fmt: skip
            text = path.read_text(encoding="utf-8")
            geoms = [shapely.from_wkt(t) for t in text.splitlines() if t.strip()]
        else:
            import pyogrio

            info = pyogrio.read_info(path)
            if where:
                geoms, selected = _where(path, field, where, info)
            else:
                wkb = pyogrio.raw.read(path)[2] if info["features"] else []
                geoms = list(shapely.from_wkb(wkb)) if len(wkb) else []
            declared = CRS.from_user_input(info["crs"]) if info.get("crs") else None
    except InputError:
        raise
    except Exception as exc:  # shapely's GEOSException, pyogrio's DataSourceError, ...
        raise bad_input(field, path.name, "a vector file GDAL reads, or WKT lines",
                        f"the file does not parse: {exc}") from exc  # fmt: skip
    field = f"{field} ({selected})" if selected else field
    kept = [g for g in geoms if g is not None and not g.is_empty]
    left = (
        f" ({len(geoms) - len(kept)} empty geometries left out)" if len(kept) < len(geoms) else ""
    )
    geoms = kept
    if crs is None or not geoms:
        return geoms, f"{field}: read as is{left}"
    target = CRS.from_user_input(crs)
    lonlat = _could_be_lonlat(geoms)
    if declared is not None and declared.is_geographic and not lonlat:
        declared = None  # GeoJSON's RFC 7946 default, not the file's coordinates
    if declared is None:
        if target.is_projected and lonlat:
            raise bad_input(
                field,
                f"{path.name}: every coordinate within longitude / latitude bounds",
                f"coordinates in the map's CRS ({target.to_string()}), or a file that "
                "declares its CRS",
                "reproject it (e.g. ogr2ogr -t_srs <map CRS>) or save it as a GeoPackage",
            )
        return geoms, f"{field}: no CRS declared: read in the map's CRS{left}"
    if declared.equals(target, ignore_axis_order=True):
        return geoms, f"{field}: same CRS{left}"
    t = Transformer.from_crs(declared, target, always_xy=True)
    geoms = [shapely.transform(g, t.transform, interleaved=False) for g in geoms]
    return geoms, f"{field}: reprojected from {declared.to_string()}{left}"
