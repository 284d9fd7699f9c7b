"""Checkpoint tables, the accuracy certificate's independent points (:mod:`toolkit.certify`).

- :func:`read_checkpoints` — CSV / Parquet / GIS-layer checkpoints with x, y, z[, z_std,
  crs] (metres), header aliases in :data:`COLUMN_ALIASES`, coordinates in any CRS pyproj knows;
  :func:`as_checkpoints` also takes a mapping / DataFrame of those columns.
- :func:`reproject_checkpoints` — checkpoint coordinates in the DEM's CRS (pyproj).

The DEMs they are checked against are read by :mod:`toolkit.dem_io`.
"""

from __future__ import annotations

import difflib
import math
import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from pyproj import CRS

from factorgraph.field.table import header_key, read_text_table, sidecar_crs
from terrain.errors import bad_input
from terrain.grid import check_same_crs

from .provenance import file_sha256

__all__ = [
    "COLUMN_ALIASES",
    "Checkpoints",
    "as_checkpoints",
    "layer_columns",
    "read_checkpoints",
    "read_layer_table",
    "read_point_table",
    "reproject_checkpoints",
]

_COLUMNS = ("x", "y", "z")
#: Header names read as each column (case-insensitive; a unit suffix ``_m``, `` (m)`` or
#: ``[m]`` is ignored). ``x`` is always the east coordinate: longitude in a geographic CRS.
COLUMN_ALIASES: dict[str, tuple[str, ...]] = {
    "x": ("x", "easting", "east", "e", "lon", "long", "longitude"),
    "y": ("y", "northing", "north", "n", "lat", "latitude"),
    "z": ("z", "elevation", "elev", "height", "h", "altitude", "alt"),
    "z_std": (
        "z_std",
        "sigma_z",
        "z_sigma",
        "std_z",
        "sd_z",
        "z_sd",
        "sigma",
        "std",
        "sd",
        "elevation_std",  # the name of glacimap's own 1-sigma band and variable
    ),
    "crs": ("crs", "srs"),
}
_ALIAS = {a: c for c, names in COLUMN_ALIASES.items() for a in names}
_ALIAS_TEXT = "; ".join(f"{c}: {'/'.join(names)}" for c, names in COLUMN_ALIASES.items())


# --------------------------------------------------------------------------- checkpoints
@dataclass(frozen=True)
class Checkpoints:
    """Independent check points, every row as read (NaN rows kept, counted by ``certify``).

    Attributes
    ----------
    xy : ndarray of shape (n, 2)
        Easting/northing in ``crs``, metres.
    z : ndarray of shape (n,)
        Surveyed elevation, metres.
    z_std : ndarray of shape (n,) or None
        1-sigma of each surveyed elevation, metres, when the file has a ``z_std`` column.
    crs : pyproj.CRS or None
        CRS of ``xy``, projected or geographic (anything pyproj understands is converted;
        :func:`toolkit.certify.certify` reprojects to the DEM's); None when the file, a
        sidecar and the caller name none.
    source : str
        File name (or ``"arrays"``); ``sha256`` of the file's bytes when read from one.
    columns : dict of str
        Which header became which column (``{"x": "easting", ...}``) when read from a table.
    ignored_columns : tuple of str
        Headers that are none of :data:`COLUMN_ALIASES` (ids, notes): kept out, listed.
    note : str
        How a GIS layer was read (its layers, lines' vertices, attributes left out); "" for
        a table.
    height_datum : str or None
        The datum the file states for its heights (an Emlid export's ellipsoidal heights:
        ``"ellipsoidal"``); ``None`` when only a CRS could say.
    """

    xy: np.ndarray
    z: np.ndarray
    z_std: np.ndarray | None = None
    crs: CRS | None = None
    source: str = "arrays"
    sha256: str | None = None
    columns: dict[str, str] = field(default_factory=dict)
    ignored_columns: tuple[str, ...] = ()
    note: str = ""
    height_datum: str | None = None

    def __post_init__(self) -> None:
        xy = np.asarray(self.xy, dtype=float)
        z = np.asarray(self.z, dtype=float).reshape(-1)
        if xy.ndim != 2 or xy.shape != (z.size, 2):
            raise bad_input("checkpoints.xy", xy.shape, f"shape ({z.size}, 2) like z", "")
        z_std = None if self.z_std is None else np.asarray(self.z_std, dtype=float).reshape(-1)
        if z_std is not None and z_std.shape != z.shape:
            raise bad_input("checkpoints.z_std", z_std.shape, f"shape {z.shape} like z", "")
        if z_std is not None and np.nanmin(z_std, initial=0.0) < 0:
            raise bad_input("z_std", float(np.nanmin(z_std)), "1-sigma >= 0 (m)", "fix it")
        object.__setattr__(self, "xy", xy)
        object.__setattr__(self, "z", z)
        object.__setattr__(self, "z_std", z_std)
        if self.crs is not None:
            object.__setattr__(self, "crs", any_crs(self.crs, "checkpoints.crs"))

    @property
    def n(self) -> int:
        """Number of rows."""
        return int(self.z.shape[0])

    def nan_rows(self) -> np.ndarray:
        """Boolean mask, shape (n,): rows with a NaN in x, y, z (or z_std when present)."""
        cols = [self.xy[:, 0], self.xy[:, 1], self.z]
        if self.z_std is not None:
            cols.append(self.z_std)
        return ~np.logical_and.reduce([np.isfinite(c) for c in cols])


def any_crs(value: Any, field_name: str) -> CRS:
    """A CRS from anything pyproj understands, projected or geographic."""
    try:
        return CRS.from_user_input(value)
    except Exception as exc:  # pyproj's CRSError
        raise bad_input(field_name, value, "a CRS pyproj understands", "e.g. EPSG:4326") from exc


def _header_key(name: str) -> str:
    return header_key(name, _ALIAS)


def _canonical(cols: dict[str, Any], name: str) -> tuple[dict[str, Any], dict[str, str], list]:
    """Rename the headers of ``cols`` by :data:`COLUMN_ALIASES`; unknown ones are returned
    apart; a column named twice (``z`` and ``elevation``) is an error; a missing x, y or z
    names the closest unknown header (difflib) as the fix."""
    out: dict[str, Any] = {}
    used: dict[str, str] = {}
    unknown = []
    for header, values in cols.items():
        canon = _ALIAS.get(_header_key(header))
        if canon is None:
            unknown.append(header)
        elif canon in out:
            raise bad_input(
                f"{name} columns",
                [used[canon], header],
                f"one column for {canon}",
                f"drop or rename one of {used[canon]!r}, {header!r}",
            )
        else:
            out[canon], used[canon] = values, header
    missing = [c for c in _COLUMNS if c not in out]
    numbers = sum(_all_numbers([c]) for c in cols)
    if missing and (_all_numbers(list(cols)) or numbers >= 3):  # the first line is data
        raise bad_input(
            f"{name} header",
            list(cols),
            f"a header row naming the columns (the first line holds {numbers} numbers of "
            f"{len(cols)} cells: data, so the file has none; a controller's PNEZD / PENZD "
            "export has no header)",
            "add a first line naming the columns in the file's order, e.g. x,y,z, or "
            "name,northing,easting,elevation,code for PNEZD (name and code are kept out)",
        )
    if missing:
        hints = []
        for header in unknown:
            close = difflib.get_close_matches(_header_key(header), list(_ALIAS), n=1, cutoff=0.6)
            if close:
                hints.append(f"{header!r} -> did you mean {close[0]!r} ({_ALIAS[close[0]]})?")
        raise bad_input(
            f"{name} columns",
            list(cols),
            f"columns x, y, z[, z_std, crs]; missing {', '.join(missing)} (headers read as "
            f"{_ALIAS_TEXT})",
            "; ".join(hints) or "rename the header (x, y: easting/northing; z: elevation, m)",
        )
    return out, used, unknown


def _all_numbers(cells: list[Any]) -> bool:
    """True when every cell reads as a finite number (a data row taken for a header)."""
    try:
        return bool(cells) and all(math.isfinite(float(str(c))) for c in cells)
    except ValueError:
        return False


def _float(text: Any, where: str) -> float:
    if text is None or (isinstance(text, str) and not text.strip()):
        return math.nan
    try:
        return float(text)
    except (TypeError, ValueError) as exc:
        raise bad_input(where, text, "a number (m)", "fix the cell or leave it empty") from exc


def _table(path: Path, field: str = "CHECKPOINTS") -> dict[str, list[Any]]:
    """Columns of a CSV or Parquet file by lower-cased name (values as read)."""
    if path.suffix.lower() == ".parquet":
        import pyarrow.parquet as pq

        try:
            table = pq.read_table(path)
        except Exception as exc:  # pyarrow raises ArrowInvalid / OSError subclasses
            raise bad_input(field, path.name, "a Parquet table", str(exc)) from exc
        return {n.strip(): table.column(n).to_pylist() for n in table.column_names}
    return read_text_table(path, field).columns()


def _file_crs(path: Path | None, cols: dict[str, Any]) -> tuple[Any, str] | None:
    """CRS named by a ``crs`` column (one value) or a sidecar ``<stem>.crs`` / ``<stem>.prj``."""
    if "crs" in cols:
        raw = [cols["crs"]] if isinstance(cols["crs"], str) else list(cols["crs"])
        values = sorted({str(v).strip() for v in raw if v is not None and str(v).strip()})
        values = [v for v in values if v.lower() != "nan"]
        if len(values) > 1:
            raise bad_input("crs column", values, "one CRS for every row", "reproject the rows")
        if values:
            return values[0], "crs column"
    return None if path is None else sidecar_crs(path)


def _column(values: Any, where: str) -> np.ndarray:
    try:
        return np.asarray(values, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        return np.array([_float(v, f"{where} row {i}") for i, v in enumerate(values)])


def _from_columns(
    cols: dict[str, Any],
    name: str,
    crs: Any,
    path: Path | None,
    sha256: str | None,
    declared: tuple[Any, str] | None = None,
    note: str = "",
) -> Checkpoints:
    from factorgraph.field.controller_csv import controller_table

    export = controller_table(cols, name)  # an Emlid Flow export: its own columns and CRS
    if export is not None:
        cols, declared = export.columns, (export.crs, export.how)
        note = "; ".join(t for t in (note, export.note) if t)
    cols, used, unknown = _canonical(cols, name)
    if export is not None:
        used = {**used, **export.used}
    arr = {
        c: _column(cols[c], f"{name} column {used[c]}") for c in (*_COLUMNS, "z_std") if c in cols
    }
    found = _file_crs(path, cols) if declared is None else declared
    resolved = None if crs is None else any_crs(crs, "crs")
    if found is not None:
        file_crs = any_crs(found[0], f"{name} {found[1]}")
        check_same_crs(resolved, file_crs, "crs argument", f"{name} ({found[1]})")
        resolved = file_crs
    n = {k: v.size for k, v in arr.items()}
    if len(set(n.values())) > 1:
        raise bad_input(f"{name} columns", n, "columns of one length", "check the table")
    xy = np.column_stack([arr["x"], arr["y"]]).reshape(-1, 2)
    return Checkpoints(
        xy, arr["z"], arr.get("z_std"), resolved, name, sha256, used, tuple(map(str, unknown)),
        note, None if export is None else export.height_datum,
    )  # fmt: skip


def layer_columns(path: Path, name: str) -> tuple[dict[str, Any], tuple[Any, str] | None, str]:
    """A GIS layer (:func:`toolkit.point_files.read_vector_points`) as table columns: ``x, y``
    its vertices, ``z`` the geometry's Z or the height attribute, every other attribute.

    Attributes naming a position (``easting``, ``lon``...) are left out (the geometry is the
    position; said); a height attribute must agree with a geometry Z to 1 mm.

    Returns
    -------
    (columns, declared, note)
        ``declared`` is ``(crs, "layer CRS")`` or None.
    """
    from .point_files import read_vector_points

    layer = read_vector_points(path, name)
    notes = [layer.note] if layer.note else []
    cols: dict[str, Any] = {}
    for header, values in layer.fields.items():
        canon = _ALIAS.get(_header_key(header))
        if canon in ("x", "y", "crs"):
            notes.append(f"attribute {header!r} not read: the geometry is the position")
        elif canon == "z" and layer.z is not None:
            height = _column(values, f"{name} attribute {header}")
            worst = np.nanmax(np.abs(height - layer.z), initial=0.0)
            if not worst <= 1e-3:
                raise bad_input(
                    f"{name} heights",
                    f"geometry Z and attribute {header!r} differ by up to {worst:.3g} m",
                    "one height per point: the geometry's Z, or an attribute",
                    f"drop the attribute {header!r} or the Z (ogr2ogr -dim XY)",
                )
            notes.append(f"attribute {header!r} agrees with the geometry's Z")
        else:
            cols[header] = values
    cols.update({"x": layer.xy[:, 0], "y": layer.xy[:, 1]})
    if layer.z is not None:
        cols["z"] = layer.z
    declared = None if layer.crs is None else (layer.crs, "layer CRS")
    return cols, declared, "; ".join(notes)


def read_checkpoints(path: str | os.PathLike, crs: Any = None) -> Checkpoints:
    """Read checkpoints from CSV (header row), Parquet (``.parquet``) or a GIS point layer
    (GeoPackage, Shapefile, GeoJSON...: :func:`layer_columns`; the height the geometry's Z
    or an attribute, the CRS the layer's).

    Parameters
    ----------
    path : path-like
        Columns ``x, y, z`` (east, north, elevation: metres in a projected CRS, or degrees of
        longitude, latitude and metres in a geographic one) and optionally ``z_std`` (1-sigma,
        m) and ``crs``; case-insensitive, with the aliases of :data:`COLUMN_ALIASES`
        (``easting, northing, elevation`` ...). Other columns (ids, notes) are listed in
        ``ignored_columns``. Empty cells become NaN: such rows are kept and reported as
        dropped by :func:`certify`.
    crs : str or pyproj.CRS, optional
        CRS of the coordinates, any that pyproj knows (EPSG:4326 included). Also read from a
        ``crs`` column or a sidecar file ``<stem>.crs`` (e.g. ``EPSG:32608``) or ``<stem>.prj``
        (WKT); all that are given must agree.

    Raises
    ------
    terrain.errors.InputError
        Missing file or columns (named, with a did-you-mean), a column given twice, a
        non-numeric cell, a negative ``z_std``, a CRS pyproj does not know.
    terrain.errors.CRSMismatchError
        The ``crs`` argument and the file's CRS differ.
    """
    from .point_files import point_format

    path = Path(path)
    if not path.is_file():
        raise bad_input(
            "CHECKPOINTS", str(path), "an existing CSV, Parquet or GIS point file", "check it"
        )
    digest = file_sha256(path)
    kind = point_format(path)
    if kind in ("las", "atl06", "raster"):
        raise bad_input(
            "CHECKPOINTS",
            path.name,
            "independent check points (a table or a GIS point layer), not a cloud, a granule "
            "or a raster",
            "certify DEM CHECKPOINTS takes the DEM first; survey checkpoints apart from it",
        )
    if kind == "vector":
        return read_layer_table(path, crs, digest)[0]
    return read_point_table(path, crs, digest)[0]


def read_point_table(
    path: Path, crs: Any = None, sha256: str | None = None, field: str = "CHECKPOINTS"
) -> tuple[Checkpoints, dict[str, Any]]:
    """A CSV or Parquet table as :class:`Checkpoints` and its columns as read (one parse:
    ``glacimap reconstruct`` reads its noise columns there); errors name ``field``."""
    cells = _table(path, field)
    digest = file_sha256(path) if sha256 is None else sha256
    return _from_columns(cells, path.name, crs, path, digest), cells


def read_layer_table(
    path: Path, crs: Any = None, sha256: str | None = None, field: str = "CHECKPOINTS"
) -> tuple[Checkpoints, dict[str, Any]]:
    """A GIS layer's points as :class:`Checkpoints` and the columns they were read from
    (:func:`layer_columns`; ``glacimap reconstruct`` reads its noise columns there); errors
    name ``field``."""
    cols, declared, note = layer_columns(path, field)
    digest = file_sha256(path) if sha256 is None else sha256
    return _from_columns(cols, path.name, crs, None, digest, declared, note), cols


def as_checkpoints(obj: Any, crs: Any = None) -> Checkpoints:
    """Checkpoints from a :class:`Checkpoints`, a file (:func:`read_checkpoints`), or a table:
    a mapping or DataFrame with columns ``x, y, z[, z_std, crs]`` (m). ``crs`` fills in a CRS
    the input does not name and must agree with one it names."""
    if isinstance(obj, Checkpoints):
        given = None if crs is None else any_crs(crs, "crs")
        check_same_crs(given, obj.crs, "crs argument", "checkpoints")
        return obj if obj.crs is not None or crs is None else replace(obj, crs=crs)
    if isinstance(obj, str | os.PathLike):
        return read_checkpoints(obj, crs)
    try:
        cols = {str(k).strip(): obj[k] for k in obj.keys()}
    except (AttributeError, TypeError, KeyError) as exc:
        expected = "Checkpoints, a CSV/Parquet path or a table with x, y, z"
        raise bad_input("checkpoints", type(obj).__name__, expected, "") from exc
    return _from_columns(cols, "checkpoints", crs, None, None)


def reproject_checkpoints(
    cps: Checkpoints, crs: CRS, nan: np.ndarray
) -> tuple[np.ndarray, dict[str, str] | None]:
    """Checkpoint x, y in ``crs`` (the DEM's), shape (n, 2), 0 on the ``nan`` rows (n,), and
    the record of the transformation (``None`` when already in it). pyproj, x = east
    (longitude) first; heights are not transformed (they must share the DEM's vertical
    datum); a point pyproj cannot transform comes back non-finite (counted by ``certify``)."""
    xy = np.where(nan[:, None], 0.0, cps.xy)
    if cps.crs is None or cps.crs.equals(crs, ignore_axis_order=True):
        return xy, None
    from pyproj import Transformer, __version__

    tr = Transformer.from_crs(cps.crs, crs, always_xy=True)
    ex, ny = tr.transform(xy[:, 0], xy[:, 1], errcheck=False)
    out = np.where(nan[:, None], 0.0, np.column_stack([ex, ny]))
    note = {
        "from": cps.crs.to_string(),
        "to": crs.to_string(),
        "how": f"pyproj {__version__} Transformer, x = east (longitude) first; heights as given",
        "operation": tr.description,
    }
    return out, note
