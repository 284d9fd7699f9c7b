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

__all__ = ["read_features", "read_geometries"]

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


def _where(
    path: Path, field: str, where: str | None, info: dict, attribute: str | None
) -> tuple[list, list | None, str]:
    """The geometries of the features ``where`` selects (all without it), their
    ``attribute`` values, and the selection in words."""
    import pyogrio
    import shapely

    names = ", ".join(map(str, info.get("fields", []))) or "(none)"
    if attribute is not None and attribute not in list(info.get("fields", [])):
        raise bad_input(f"{field} attribute", attribute, f"one of {path.name}'s attributes",
                        f"its attributes: {names}")  # fmt: skip
    if not info["features"]:
        return [], [] if attribute else None, ""
    try:
        got = pyogrio.raw.read(path, where=where, columns=[attribute] if attribute else [])
    except Exception as exc:  # pyogrio's FieldError / DataLayerError: the clause
        raise bad_input(
            f"{field}-where", where, "an OGR SQL WHERE clause on the file's attributes",
            f"{path.name}'s attributes: {names} (e.g. \"RGIId = 'RGI60-07.01482'\"); {exc}",
        ) from exc  # fmt: skip
    wkb = got[2]
    values = [str(v) for v in got[3][0]] if attribute else None
    if where and not len(wkb):
        raise bad_input(
            f"{field}-where", where, f"a clause that selects features of {path.name}",
            f"{path.name}'s attributes: {names}; it has {info['features']} features",
        )  # fmt: skip
    said = f"{len(wkb)} of {info['features']} features: {where}" if where else ""
    return list(shapely.from_wkb(wkb)) if len(wkb) else [], values, said


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
    geoms, _, note = read_features(path, field, crs, where)
    return geoms, note


def read_features(
    path: Path, field: str, crs: Any = None, where: str | None = None, attribute: str | None = None
) -> tuple[list, list | None, str]:
    """:func:`read_geometries` with each kept feature's ``attribute`` value (text; ``None``
    without one): an inventory's glacier IDs beside their outlines.

    Raises
    ------
    InputError
        As :func:`read_geometries`, and an ``attribute`` the file does not have (its
        attributes listed) or a WKT file asked for one.
    """
    import shapely
    from pyproj import CRS, Transformer

    path = Path(path)
    if not path.is_file():
        raise bad_input(field, str(path), "an existing vector file (GeoJSON, GeoPackage, "
                        "Shapefile, WKT...)", "check the path")  # fmt: skip
    declared = None
    selected = ""
    values = None
    try:
        if _is_wkt(path):
            if where or attribute:
                raise bad_input(
                    f"{field}-where",
                    where or attribute,
                    "a vector file with attributes",
                    f"{path.name} is WKT lines: select by hand",
                )
            text = path.read_text(encoding="utf-8")
            geoms = [shapely.from_wkt(t) for t in text.splitlines() if t.strip()]
        else:
            import pyogrio

            info = pyogrio.read_info(path)
            geoms, values, selected = _where(path, field, where, info, attribute)
            declared = CRS.from_user_input(info["crs"]) if info.get("crs") else None
    except InputError:
        raise
    except Exception as exc:  # shapely's GEOSException, pyogrio's DataSourceError, ...
        raise bad_input(field, path.name, "a vector file GDAL reads, or WKT lines",
                        f"the file does not parse: {exc}") from exc  # fmt: skip
    field = f"{field} ({selected})" if selected else field
    keep = [g is not None and not g.is_empty for g in geoms]
    left = f" ({keep.count(False)} empty geometries left out)" if not all(keep) else ""
    geoms = [g for g, k in zip(geoms, keep, strict=True) if k]
    values = None if values is None else [v for v, k in zip(values, keep, strict=True) if k]
    if crs is None or not geoms:
        return geoms, values, f"{field}: read as is{left}"
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
        return geoms, values, f"{field}: no CRS declared: read in the map's CRS{left}"
    if declared.equals(target, ignore_axis_order=True):
        return geoms, values, f"{field}: same CRS{left}"
    t = Transformer.from_crs(declared, target, always_xy=True)
    geoms = [shapely.transform(g, t.transform, interleaved=False) for g in geoms]
    return geoms, values, f"{field}: reprojected from {declared.to_string()}{left}"
