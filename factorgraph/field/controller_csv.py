"""Survey points as a GNSS controller app exports them (Emlid Flow / ReachView 3), read as
what they are: samples and checkpoints (``toolkit.certify_io``), ground control
(:mod:`factorgraph.control_io`: ``Name`` and ``Easting / Northing RMS`` too).

Emlid's Reach receivers are the low-cost RTK rovers glaciologists carry, and their app's
CSV export holds each point twice: projected (``Easting, Northing, Elevation`` in the
project's coordinate system, named in ``CS name``; ``Elevation`` above that system's vertical
datum when it has one) and global (``Longitude, Latitude, Ellipsoidal height``), with the
receiver's ``Easting / Northing / Elevation RMS`` and a ``Solution status`` (FIX, FLOAT,
SINGLE...). Read as a plain table it names ``x`` twice (``Easting`` and ``Longitude``) and
``z`` twice; here it is read as:

* **heights**: ``Ellipsoidal height``, the map's datum (WGS 84 ellipsoidal heights, as the
  rover's GNSS logs), so no geoid is needed, and the table states it (``height_datum``);
* **position**: ``Easting, Northing`` in the ``CS name`` system (pyproj reads the name) when
  that system is projected and in metres; otherwise ``Longitude, Latitude`` (EPSG:4326);
* **units**: the export writes heights and RMS in the system's unit (US survey feet on a
  state plane in ftUS): they are converted to metres by the system's axis unit; a ``CS name``
  pyproj does not know, so an unknown unit, is refused;
* **1-sigma**: ``Elevation RMS`` (same unit), each point's own;
* **solution status**: counted and said, every point kept with its own RMS (a FLOAT point's
  is decimetres where a FIX's is centimetres).

The antenna height is already applied to the exported coordinates (they are the pole tip's).
``Longitude / Latitude`` are in the corrections' frame (ETRS89, NAD83(2011), WGS 84); reading
them as WGS 84 moves a point by up to a metre, which is why the projected pair comes first.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from terrain.errors import bad_input

__all__ = ["EMLID_COLUMNS", "ControllerTable", "controller_table", "is_controller_export"]

#: The headers that mark an Emlid Flow / ReachView 3 survey export (lower case).
EMLID_COLUMNS = ("easting", "northing", "longitude", "latitude", "ellipsoidal height")
_READ = (*EMLID_COLUMNS, "elevation", "elevation rms", "solution status", "cs name")


@dataclass(frozen=True)
class ControllerTable:
    """A controller export's columns as glacimap reads them.

    Attributes
    ----------
    columns : dict
        ``x, y, z`` (m) and ``z_std`` (m, when the export has ``Elevation RMS``), then every
        column not read, under its own header.
    crs : pyproj.CRS
        The CRS of ``x, y`` (horizontal).
    how : str
        Where the CRS came from, in words.
    note : str
        What was read, converted and counted.
    used : dict
        Which header became ``x, y, z, z_std``.
    height_datum : str
        ``"ellipsoidal"``: what the heights are above.
    point : dict
        What a control point needs besides: ``id`` (``Name``), ``sigma_x``, ``sigma_y``
        (``Easting RMS``, ``Northing RMS``, m) where the export has them.
    """

    columns: dict[str, Any]
    crs: Any
    how: str
    note: str
    used: dict[str, str] = field(default_factory=dict)
    height_datum: str = "ellipsoidal"
    point: dict[str, Any] = field(default_factory=dict)


def is_controller_export(headers: Any) -> bool:
    """Whether ``headers`` are an Emlid Flow / ReachView 3 export's (case-insensitive)."""
    keys = {str(h).strip().lower() for h in headers}
    return all(c in keys for c in EMLID_COLUMNS)


def _cells(cols: dict[str, Any], key: str) -> tuple[str, list[Any]] | None:
    for header, values in cols.items():
        if str(header).strip().lower() == key:
            return str(header), list(values)
    return None


def _numbers(values: list[Any], header: str, name: str) -> np.ndarray:
    out = np.empty(len(values))
    for i, v in enumerate(values):
        text = "" if v is None else str(v).strip()
        try:
            out[i] = float(text) if text else np.nan
        except ValueError as exc:
            raise bad_input(
                f"{name} column {header!r} row {i + 1}", v, "a number", "fix the cell"
            ) from exc
    return out


def _system(cols: dict[str, Any], name: str) -> tuple[Any, float, str]:
    """The export's ``CS name`` as ``(horizontal CRS or None, metres per unit, words)``."""
    from pyproj import CRS
    from pyproj.exceptions import CRSError

    found = _cells(cols, "cs name")
    if found is None:
        return None, 1.0, "no CS name column: heights taken in metres"
    header, values = found
    names = sorted({str(v).strip() for v in values if v is not None and str(v).strip()})
    if len(names) > 1:
        raise bad_input(
            f"{name} column {header!r}", names, "one coordinate system for every point",
            "export each coordinate system's points to their own file",
        )  # fmt: skip
    if not names:
        return None, 1.0, "CS name empty: heights taken in metres"
    try:
        crs = CRS.from_user_input(names[0])
    except CRSError as exc:
        raise bad_input(
            f"{name} column {header!r}",
            names[0],
            "a coordinate system pyproj knows by name (its unit sets the heights' unit)",
            "export the points in a metric system such as 'WGS 84 / UTM zone 33N', or rename "
            "the columns to x, y, z and add a crs column",
        ) from exc
    horizontal = crs.sub_crs_list[0] if crs.is_compound else crs
    axis = horizontal.axis_info[0] if horizontal.axis_info else None
    factor = float(axis.unit_conversion_factor) if axis and horizontal.is_projected else 1.0
    return horizontal, factor, f"CS name {names[0]!r}"


def controller_table(cols: dict[str, Any], name: str) -> ControllerTable | None:
    """``cols`` (``{header: cells}``) read as a controller export, or ``None`` when they are
    not one (:func:`is_controller_export`).

    Raises
    ------
    InputError
        Two coordinate systems in ``CS name``, one pyproj does not know, a cell that is not a
        number.
    """
    if not is_controller_export(cols):
        return None
    from pyproj import CRS

    system, factor, words = _system(cols, name)
    metric = system is not None and system.is_projected and factor == 1.0
    pair = ("easting", "northing") if metric else ("longitude", "latitude")
    crs = system if metric else CRS("EPSG:4326")
    out: dict[str, Any] = {}
    used: dict[str, str] = {}
    for canon, key in zip(("x", "y"), pair, strict=True):
        header, values = _cells(cols, key)  # type: ignore[misc]
        out[canon], used[canon] = _numbers(values, header, name), header
    header, values = _cells(cols, "ellipsoidal height")  # type: ignore[misc]
    out["z"], used["z"] = _numbers(values, header, name) * factor, header
    rms = _cells(cols, "elevation rms")
    if rms is not None:
        out["z_std"], used["z_std"] = _numbers(rms[1], rms[0], name) * factor, rms[0]
    point: dict[str, Any] = {}
    name_col = _cells(cols, "name")
    if name_col is not None:
        point["id"] = [str(v).strip() for v in name_col[1]]
    for key, axis in (("easting rms", "sigma_x"), ("northing rms", "sigma_y")):
        found = _cells(cols, key)
        if found is not None:
            point[axis] = _numbers(found[1], found[0], name) * factor
    status = _cells(cols, "solution status")
    counts = Counter(str(v).strip().upper() or "(none)" for v in (status[1] if status else []))
    for header, values in cols.items():  # the rest, under their own names
        if str(header).strip().lower() not in _READ:
            out[str(header)] = values
    parts = [
        f"Emlid Flow export: {used['x']}, {used['y']}"
        + (f" in {system.name}" if metric else " as WGS 84 longitude, latitude")
        + f" ({words}), {used['z']} as WGS 84 ellipsoidal heights",
    ]
    if factor != 1.0:
        parts.append(f"heights and RMS in {system.axis_info[0].unit_name} converted to metres")
    if "z_std" in used:
        parts.append(f"{used['z_std']} as each point's 1-sigma")
    if counts:
        parts.append(
            "solution status "
            + ", ".join(f"{n} {k}" for k, n in sorted(counts.items(), key=lambda kv: -kv[1]))
            + " (all kept, each with its own RMS)"
        )
    how = f"Emlid export's {'CS name' if metric else 'Longitude, Latitude'}"
    return ControllerTable(out, crs, how, "; ".join(parts), used, point=point)
