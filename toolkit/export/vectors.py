"""Named vector layers (points or lines with attribute columns) to GeoPackage and GeoJSON.

Used for contour lines, the rover trajectory (estimated and true LineStrings) and the selected
landmarks (Points with x, y, z, z_std, ...). Files are written with pyogrio (GDAL) — no
geopandas — and atomically.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import shapely
from pyproj import CRS, Transformer

from terrain.errors import bad_input

from ._files import atomic_file, check_target

__all__ = ["GPKG_VERSION", "VectorLayer", "write_geojson", "write_vector_layers"]

#: GeoPackage version written. 1.3 (not GDAL 3.10's default 1.4) so GDAL < 3.7 readers and
#: validators accept the R-tree triggers (1.4 renamed ``update1``/``update3``).
GPKG_VERSION = "1.3"
_TYPES = {0: "Point", 1: "LineString"}  # shapely type id -> OGR geometry type
_RESERVED = {"fid", "geom", "geometry"}


@dataclass(frozen=True)
class VectorLayer:
    """One layer: features of one geometry type with attribute columns.

    Parameters
    ----------
    geometry : sequence of shapely.Point or shapely.LineString, length n
        All of one type, all 2-D or all 3-D (x, y[, z] in the layer's CRS, metres).
    fields : mapping of str to array-like of shape (n,)
        Attribute columns: numbers, booleans or strings.
    geometry_type : str, optional
        OGR type (``"Point"``, ``"LineString"``, ``"Point Z"``, ``"LineString Z"``); inferred
        from the geometries, required for an empty layer.
    """

    geometry: Any
    fields: Mapping[str, Any] = field(default_factory=dict)
    geometry_type: str | None = None

    def __post_init__(self) -> None:
        geoms = np.asarray(self.geometry, dtype=object).reshape(-1)
        if not all(isinstance(g, shapely.Geometry) for g in geoms):
            raise bad_input("geometry", self.geometry, "shapely geometries", "")
        kinds = set(shapely.get_type_id(geoms).tolist())
        if not kinds <= set(_TYPES) or len(kinds) > 1:
            raise bad_input(
                "geometry",
                sorted(shapely.get_type_id(geoms).tolist()),
                "all Points or all LineStrings",
                "write each geometry type to its own layer",
            )
        if geoms.size and (shapely.is_empty(geoms).any() or not shapely.is_valid(geoms).all()):
            raise bad_input("geometry", "empty or invalid", "valid, non-empty geometries", "")
        has_z = shapely.has_z(geoms)
        if has_z.any() and not has_z.all():
            raise bad_input("geometry", "mixed 2-D/3-D", "all 2-D or all 3-D", "")
        if not np.isfinite(shapely.get_coordinates(geoms, include_z=bool(has_z.any()))).all():
            raise bad_input("geometry coordinates", "NaN/inf", "finite coordinates", "")
        gtype = self.geometry_type
        if gtype is None:
            if not geoms.size:
                raise bad_input("geometry_type", None, "a type for an empty layer", "")
            gtype = _TYPES[kinds.pop()] + (" Z" if has_z.any() else "")
        columns = {}
        for name, values in dict(self.fields).items():
            if not isinstance(name, str) or not name or name.lower() in _RESERVED:
                raise bad_input("field name", name, f"a non-empty name, not {_RESERVED}", "")
            arr = np.asarray(values)
            if arr.shape != (geoms.size,):
                raise bad_input(f"field '{name}'", arr.shape, f"shape ({geoms.size},)", "")
            if arr.dtype.kind in "US":
                arr = arr.astype(str).astype(object)
            elif arr.dtype.kind not in "biuf" and not (arr.dtype == object and arr.size == 0):
                raise bad_input(f"field '{name}'", arr.dtype, "numbers, booleans or str", "")
            columns[name] = arr
        object.__setattr__(self, "geometry", geoms)
        object.__setattr__(self, "fields", columns)
        object.__setattr__(self, "geometry_type", gtype)

    def __len__(self) -> int:
        return int(self.geometry.size)

    @classmethod
    def points(cls, xyz: Any, **fields: Any) -> VectorLayer:
        """Points from coordinates ``xyz`` of shape (n, 2) or (n, 3) (metres)."""
        xyz = np.asarray(xyz, dtype=float)
        if xyz.ndim != 2 or xyz.shape[1] not in (2, 3):
            raise bad_input("xyz", xyz.shape, "shape (n, 2) or (n, 3)", "")
        gtype = "Point Z" if xyz.shape[1] == 3 else "Point"
        return cls(shapely.points(xyz), fields, gtype)

    @classmethod
    def lines(cls, paths: Sequence[Any], **fields: Any) -> VectorLayer:
        """LineStrings from a sequence of vertex arrays of shape (k_i, 2) or (k_i, 3), k_i >= 2;
        no paths make an empty 2-D ``LineString`` layer (e.g. no contour crosses the map)."""
        arrays = [np.asarray(p, dtype=float) for p in paths]
        if any(a.ndim != 2 or a.shape[0] < 2 or a.shape[1] not in (2, 3) for a in arrays):
            raise bad_input("paths", [a.shape for a in arrays], "(k >= 2, 2 or 3) arrays", "")
        gtype = None if arrays else "LineString"
        return cls([shapely.linestrings(a) for a in arrays], fields, gtype)


def _crs(crs: Any) -> CRS:
    if crs is None:
        raise bad_input("crs", None, "the CRS of the coordinates", 'pass e.g. "EPSG:32608"')
    try:
        return CRS.from_user_input(crs)
    except Exception as exc:  # pyproj's CRSError
        raise bad_input("crs", crs, "a CRS pyproj understands", 'e.g. "EPSG:32608"') from exc


def _crs_text(crs: CRS) -> str:
    """Authority code where there is one (so GeoPackage records srs_id = EPSG code)."""
    auth = crs.to_authority()
    return f"{auth[0]}:{auth[1]}" if auth else crs.to_wkt()


def _as_layer(name: str, layer: Any) -> VectorLayer:
    if isinstance(layer, VectorLayer):
        return layer
    try:
        geometry, fields = layer
    except (TypeError, ValueError) as exc:
        raise bad_input(
            f"layers['{name}']", layer, "a VectorLayer or (geometry, fields)", ""
        ) from exc
    return VectorLayer(geometry, fields)


def _write(path: Path, layer: VectorLayer, name: str, crs: str, driver: str, **options) -> None:
    from pyogrio import get_gdal_config_option, set_gdal_config_options
    from pyogrio.raw import write

    from ..provenance import gpkg_last_change

    # GDAL stamps gpkg_contents.last_change with the wall clock unless OGR_CURRENT_DATE is
    # set: a fixed stamp keeps the file's bytes a function of its content (same seed, same
    # bytes); restored afterwards, as it is a process-wide GDAL setting
    before = get_gdal_config_option("OGR_CURRENT_DATE")
    if driver == "GPKG":
        set_gdal_config_options({"OGR_CURRENT_DATE": gpkg_last_change()})
    try:
        _write_layer(write, path, layer, name, crs, driver, **options)
    finally:
        if driver == "GPKG":
            set_gdal_config_options({"OGR_CURRENT_DATE": before})


def _write_layer(write, path, layer, name, crs, driver, **options) -> None:
    write(
        str(path),
        shapely.to_wkb(layer.geometry) if len(layer) else np.array([], dtype=object),
        list(layer.fields.values()),
        list(layer.fields),
        layer=name,
        driver=driver,
        geometry_type=layer.geometry_type,
        crs=crs,
        **options,
    )


def write_vector_layers(
    gpkg_path: str | os.PathLike,
    layers: Mapping[str, VectorLayer | tuple[Any, Mapping[str, Any]]],
    crs: Any,
    *,
    metadata: Mapping[str, str] | None = None,
) -> Path:
    """Write several named layers into one GeoPackage (replacing the file as a whole).

    Parameters
    ----------
    gpkg_path : path-like
        Output ``.gpkg`` in an existing folder; written atomically.
    layers : mapping of str to VectorLayer or (geometry, fields)
        Layer name -> features, e.g. ``{"trajectory": VectorLayer.lines([est, true],
        kind=["estimated", "true"]), "landmarks": VectorLayer.points(xyz, z_std=s)}``.
    crs : pyproj.CRS, str or int
        CRS of every layer's coordinates (e.g. ``"EPSG:32608"``).
    metadata : mapping of str to str, optional
        Provenance (seed, method, ...) stored as each layer's GDAL metadata.

    Returns
    -------
    pathlib.Path
        ``gpkg_path``.
    """
    target = check_target(gpkg_path, (".gpkg",), "gpkg_path")
    if not isinstance(layers, Mapping) or not layers:
        raise bad_input("layers", layers, "a non-empty mapping name -> layer", "")
    checked = {}
    for name, layer in layers.items():
        if not isinstance(name, str) or not name or name.lower().startswith(("gpkg_", "rtree_")):
            raise bad_input("layer name", name, "a non-empty name not starting gpkg_/rtree_", "")
        checked[name] = _as_layer(name, layer)
    crs_text = _crs_text(_crs(crs))
    meta = {str(k): str(v) for k, v in (metadata or {}).items()}
    with atomic_file(target) as tmp:
        for i, (name, layer) in enumerate(checked.items()):
            _write(
                tmp,
                layer,
                name,
                crs_text,
                "GPKG",
                dataset_options={"VERSION": GPKG_VERSION} if i == 0 else None,
                layer_metadata=meta or None,
            )
    return target


def write_geojson(
    path: str | os.PathLike,
    layer: VectorLayer,
    crs: Any,
    *,
    name: str = "features",
    precision: int = 7,
    description: str | None = None,
) -> Path:
    """Write one layer as RFC 7946 GeoJSON: reprojected to WGS 84 longitude/latitude.

    Parameters
    ----------
    path : path-like
        Output ``.geojson``/``.json``; written atomically.
    layer : VectorLayer
        Features in ``crs``.
    crs : pyproj.CRS, str or int
        CRS of ``layer``'s coordinates; they are transformed to OGC:CRS84 (EPSG:4326 with
        longitude first, as RFC 7946 requires) with pyproj, heights unchanged.
    name : str
        Name of the FeatureCollection.
    precision : int
        Decimal digits of the coordinates (7 -> ~1 cm).
    description : str, optional
        The FeatureCollection's ``description`` member (e.g. the vertical datum of heights).
    """
    target = check_target(path, (".geojson", ".json"), "path")
    layer = _as_layer(name, layer)
    to_lonlat = Transformer.from_crs(_crs(crs), CRS("OGC:CRS84"), always_xy=True)
    has_z = "Z" in layer.geometry_type

    def project(coords: np.ndarray) -> np.ndarray:
        return np.column_stack(to_lonlat.transform(*coords.T))

    geoms = shapely.transform(layer.geometry, project, include_z=has_z)
    lonlat = VectorLayer(geoms, layer.fields, layer.geometry_type)
    with atomic_file(target) as tmp:
        _write(
            tmp,
            lonlat,
            name,
            "EPSG:4326",
            "GeoJSON",
            layer_options={
                "RFC7946": "YES",
                "COORDINATE_PRECISION": str(precision),
                **({"DESCRIPTION": description} if description else {}),
            },
        )
    return target
