"""Survey points from GIS layers and point clouds, for ``glacimap reconstruct`` and ``certify``.

- **GIS layers** (GeoPackage, Shapefile, GeoJSON, FlatGeobuf, KML, GML... anything GDAL
  reads, through pyogrio): points, multipoints, or lines (digitised contours: every vertex
  is a sample). The height is the geometry's Z or an attribute named as a checkpoint
  column is (``z``, ``elevation``, ``elev``, ``height``...; :data:`toolkit.certify_io.
  COLUMN_ALIASES`), a 1-sigma attribute likewise (``z_std``, ``sigma``...); the position is
  the geometry's, in the CRS the layer declares. Polygons are refused (their vertices are
  not survey points).
- **Point clouds** (LAS / LAZ) are recognised here (:func:`point_format`) and read in chunks
  by :mod:`toolkit.point_clouds`.

A layer or cloud in feet (US lidar often is) is refused with the command that converts it:
the map's distances, kernels and heights are metres.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from pyproj import CRS

from terrain.errors import bad_input

__all__ = [
    "HDF5_SUFFIXES",
    "LAS_SUFFIXES",
    "RASTER_SUFFIXES",
    "VECTOR_SUFFIXES",
    "VectorPoints",
    "check_metres",
    "is_controller_csv",
    "point_classes_option",
    "point_format",
    "read_control_layer",
    "read_raster_points",
    "read_vector_points",
]

#: Suffixes read as GIS layers through GDAL (``.gpx`` is a GNSS log: toolkit.gnss_samples).
VECTOR_SUFFIXES = (".gpkg", ".shp", ".geojson", ".fgb", ".kml", ".gml", ".sqlite", ".gdb")
LAS_SUFFIXES = (".las", ".laz")
#: HDF5: an ICESat-2 ATL06 granule (toolkit.icesat2).
HDF5_SUFFIXES = (".h5", ".hdf5", ".he5")
#: Rasters read as their cells (a drone DSM with voids to fill, :func:`read_raster_points`).
RASTER_SUFFIXES = (".tif", ".tiff", ".vrt", ".img", ".asc")
#: A raster's valid cells read at most (a larger one: coarsen it first).
MAX_RASTER_CELLS = 25_000_000

_GEOMETRY_WORDS = {0: "point", 1: "line", 2: "line", 3: "polygon", 4: "point", 5: "line"}


def point_format(path: str | Path) -> str | None:
    """``"vector"``, ``"las"``, ``"atl06"``, ``"raster"`` or None (a CSV, Parquet or GNSS
    log), by the file's suffix."""
    suffix = Path(path).suffix.lower()
    if suffix in LAS_SUFFIXES:
        return "las"
    if suffix in HDF5_SUFFIXES:
        return "atl06"
    if suffix in RASTER_SUFFIXES:
        return "raster"
    return "vector" if suffix in VECTOR_SUFFIXES else None


def is_controller_csv(path: str | Path) -> bool:
    """Whether the file ``path`` is a controller export's CSV (a GNSS log, cloud, layer or
    Parquet table is not; a table the reader refuses is said where it is read)."""
    import csv

    from factorgraph.field.controller_csv import is_controller_export
    from factorgraph.field.table import csv_dialect

    from .gnss_samples import gnss_format

    path = Path(path)
    if point_format(path) or gnss_format(path) or path.suffix.lower() == ".parquet":
        return False
    try:  # the header line only: the table itself is read (once) by the samples' reader
        dialect = csv_dialect(path)
        with open(path, encoding=dialect["encoding"], errors="replace") as fh:
            line = next((ln for ln in fh if ln.strip() and not ln.lstrip().startswith("#")), "")
    except OSError:
        return False
    return is_controller_export(next(csv.reader([line], delimiter=dialect["sep"]), []))


def point_classes_option(text: str | None) -> tuple[int, ...] | None:
    """``--point-classes 2,9``: ASPRS class codes (0-255), or None for the default rule.

    Raises
    ------
    InputError
        A code that is not an integer in 0-255.
    """
    if text is None or not str(text).strip():
        return None
    try:
        codes = tuple(sorted({int(c) for c in str(text).split(",") if c.strip()}))
    except ValueError:
        codes = (-1,)
    if not codes or min(codes) < 0 or max(codes) > 255:
        raise bad_input(
            "--point-classes",
            text,
            "ASPRS class codes 0-255, comma-separated",
            "e.g. --point-classes 2 (ground) or 2,9 (ground and water)",
        )
    return codes


def check_metres(crs: CRS, field: str, name: str) -> None:
    """Refuse a horizontal CRS whose axes are not in metres, naming the conversion (for
    layers here and clouds, :mod:`toolkit.point_clouds`)."""
    horizontal = crs.sub_crs_list[0] if crs.is_compound else crs
    units = {a.unit_name for a in horizontal.axis_info} if horizontal.is_projected else set()
    if crs.is_compound:  # heights in feet too (NAVD88 ftUS)
        units |= {a.unit_name for a in crs.sub_crs_list[-1].axis_info}
    if units and units != {"metre"}:
        raise bad_input(
            field,
            f"{name} in {horizontal.name} ({', '.join(sorted(units))})",
            "coordinates and heights in metres (the map's distances, kernels and heights are)",
            "reproject to a CRS in metres, e.g. ogr2ogr -t_srs EPSG:326zz out.gpkg in.gpkg, or "
            "pdal translate in.laz out.laz reprojection --filters.reprojection.out_srs=EPSG:326zz "
            "(heights in feet also need scaling: pdal's filters.assign)",
        )


# --------------------------------------------------------------------------- GIS layers
def _layer(path: Path, field: str) -> tuple[str | None, str]:
    """The layer to read (the only one, or the first of several, said in the note)."""
    import pyogrio

    try:
        layers = pyogrio.list_layers(path)
    except Exception as exc:  # pyogrio's DataSourceError
        raise bad_input(field, path.name, "a vector file GDAL reads", str(exc)) from exc
    if len(layers) <= 1:
        return None, ""
    names = [str(n) for n in layers[:, 0]]
    return names[0], f"{path.name} has {len(names)} layers ({', '.join(names)}): read {names[0]!r}"


class VectorPoints:
    """A GIS layer's vertices (:func:`read_vector_points`).

    Attributes
    ----------
    xy : ndarray of shape (m, 2)
        Each vertex's x, y in ``crs``.
    z : ndarray of shape (m,) or None
        The geometry's Z (None: 2-D, or a Z of 0 everywhere: a 2-D layer saved as 3-D).
    fields : dict of str to ndarray of shape (m,)
        Every attribute, each vertex its feature's.
    crs : pyproj.CRS or None
        The CRS the layer declares (None when it declares none, or a GeoJSON's RFC 7946
        WGS 84 that its coordinates cannot be).
    note : str
        What was read, exploded, or left out.
    """

    def __init__(self, xy, z, fields, crs, note):  # noqa: ANN001 -- plain record
        self.xy, self.z, self.fields, self.crs, self.note = xy, z, fields, crs, note


def read_vector_points(path: str | Path, field: str) -> VectorPoints:
    """A GIS layer's survey points: every vertex of its point, multipoint or line features.

    Raises
    ------
    InputError
        A file GDAL cannot read; polygons; no features; a CRS not in metres.
    """
    import pyogrio
    import shapely

    path = Path(path)
    layer, note = _layer(path, field)
    try:
        meta, _, wkb, data = pyogrio.raw.read(path, layer=layer)
    except Exception as exc:  # DataSourceError, ...
        raise bad_input(field, path.name, "a vector file GDAL reads", str(exc)) from exc
    geoms = shapely.from_wkb(wkb) if wkb is not None and len(wkb) else np.array([])
    empty = np.array([g is None or g.is_empty for g in geoms], dtype=bool)
    if not geoms.size or empty.all():
        raise bad_input(field, path.name, "a layer with point or line features", "check it")
    kinds = {_GEOMETRY_WORDS.get(int(t), "other") for t in shapely.get_type_id(geoms[~empty])}
    if kinds - {"point", "line"}:
        raise bad_input(
            field,
            f"{path.name} ({', '.join(sorted(kinds))} features)",
            "points (spot heights, a GNSS survey) or lines (digitised contours)",
            "save the survey points as a point layer (ogr2ogr -nlt POINT for vertices)",
        )
    notes = [note] if note else []
    if empty.any():
        notes.append(f"{int(empty.sum())} features without a geometry left out")
    kept = geoms[~empty]
    coords, owner = shapely.get_coordinates(kept, include_z=True, return_index=True)
    feature = np.flatnonzero(~empty)[owner]
    if "line" in kinds:
        notes.append(f"{kept.size} features' {coords.shape[0]} vertices read as samples")
    elif coords.shape[0] != kept.size:
        notes.append(f"{kept.size} features exploded to {coords.shape[0]} points")
    z = coords[:, 2] if np.isfinite(coords[:, 2]).any() and np.any(coords[:, 2] != 0) else None
    fields = {
        str(name): np.asarray(values)[feature]
        for name, values in zip(meta["fields"], data, strict=True)
    }
    crs = CRS.from_user_input(meta["crs"]) if meta.get("crs") else None
    if crs is not None and crs.is_geographic:
        lonlat = (np.abs(coords[:, 0]) <= 180).all() and (np.abs(coords[:, 1]) <= 90).all()
        if not lonlat:  # GeoJSON's RFC 7946 default, not the file's coordinates
            crs = None
            notes.append(f"{path.name} declares {meta['crs']} but its x, y are not degrees")
    if crs is not None:
        check_metres(crs, field, path.name)
        if crs.is_compound:  # the position's CRS; the heights' datum is named
            notes.append(f"heights as stored ({crs.sub_crs_list[-1].name})")
            crs = crs.sub_crs_list[0]
    return VectorPoints(coords[:, :2], z, fields, crs, "; ".join(notes))


def read_control_layer(path: str | Path, crs: Any = None) -> Any:
    """Ground control points from a GIS layer (a surveyor's GeoPackage or Shapefile): the
    geometry's x, y (and Z), the attributes :data:`factorgraph.control_io.ALIASES` names (id,
    height, 1-sigmas, target id) and free-text notes, the layer's CRS; other attributes are
    left out. Read as a control CSV would be (:func:`factorgraph.control_io.control_from_rows`).

    Returns
    -------
    factorgraph.control.ControlPoints
    """
    from factorgraph.control_io import ALIASES, NOTE_COLUMNS, control_from_rows
    from factorgraph.field.table import header_key

    path = Path(path)
    layer = read_vector_points(path, "control file")
    lookup = {a: name for name, names in ALIASES.items() for a in names}
    header, cols = ["x", "y"], [layer.xy[:, 0], layer.xy[:, 1]]
    if layer.z is not None:
        header.append("z")
        cols.append(layer.z)
    for name, values in layer.fields.items():
        canon = lookup.get(header_key(name, lookup))
        keep = canon not in (None, "x", "y", "crs") and not (canon == "z" and layer.z is not None)
        if keep or name.strip().lower() in NOTE_COLUMNS:
            header.append(name)
            cols.append(values)
    if layer.crs is not None:
        header.append("crs")
        cols.append(np.full(layer.xy.shape[0], layer.crs.to_wkt()))
    rows = [[_text(c[i]) for c in cols] for i in range(layer.xy.shape[0])]
    return control_from_rows([header, *rows], path, crs)


def _text(value: Any) -> str:
    """A layer's cell as a control table's text (repr for floats: no digits lost)."""
    if isinstance(value, float | np.floating):
        return "" if not np.isfinite(value) else repr(float(value))
    return "" if value is None else str(value)


def read_raster_points(
    path: str | Path, crs: Any = None
) -> tuple[np.ndarray, np.ndarray, CRS, str]:
    """A raster DEM's valid cells as points (a drone DSM or a DEM with voids, mapped with a
    1-sigma where it has none): each cell's centre and height in metres (a band scale,
    offset or heights in feet applied, :func:`terrain.raster_source.open_source`).

    Returns
    -------
    (xy, z, crs, note)
        Centres (n, 2) in the raster's horizontal CRS, heights (n,) m, that CRS, and what
        was read and left to fill.

    Raises
    ------
    InputError
        A raster GDAL cannot read, with no CRS and no ``crs`` (or one that disagrees), rotated,
        without a valid cell, or with more than :data:`MAX_RASTER_CELLS` valid cells.
    """
    from terrain.raster_source import open_source

    path = Path(path)
    src = open_source(path, crs)
    h, w = src.shape
    if h * w > 4 * MAX_RASTER_CELLS:  # checked before reading: a national DEM is not a survey
        raise bad_input(
            "SAMPLES",
            f"{path.name} ({h:,} x {w:,} cells)",
            f"a raster of at most {MAX_RASTER_CELLS:,} valid cells",
            "coarsen or clip it first (gdalwarp -tr 10 10 -te W S E N in.tif out.tif)",
        )
    values, t = src.read(src.bounds, pad=0)
    valid = np.isfinite(values)
    n = int(valid.sum())
    if not n or n > MAX_RASTER_CELLS:
        raise bad_input(
            "SAMPLES",
            f"{path.name} ({n:,} valid cells)",
            f"a raster with 1 to {MAX_RASTER_CELLS:,} valid cells",
            "coarsen or clip it first (gdalwarp -tr 10 10 -te W S E N in.tif out.tif)",
        )
    rows, cols = np.nonzero(valid)
    xy = np.column_stack([t.c + t.a * (cols + 0.5), t.f + t.e * (rows + 0.5)])
    out = src.crs.sub_crs_list[0] if src.crs.is_compound else src.crs
    res = f"{abs(t.a):g} x {abs(t.e):g}"
    note = (
        f"{path.name}: {n:,} cells of {res} read as samples at their centres "
        f"({values.size - n:,} voids, nodata, left to the map); heights {src.vertical}; "
        "a raster states no per-cell noise"
    )
    return xy, values[valid], out, note
