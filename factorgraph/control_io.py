"""Control-point files: a CSV (or a GIS layer's rows, ``toolkit.point_files``) read into
:class:`factorgraph.control.ControlPoints`: header aliases (:data:`ALIASES`), per-axis
1-sigmas, the file's CRS (a ``crs`` column or a ``.crs`` / ``.prj`` sidecar), free-text notes.
"""

from __future__ import annotations

import difflib
import math
from pathlib import Path
from typing import Any

import numpy as np

from terrain.errors import bad_input

from .control import ControlPoints
from .field.controller_csv import controller_table, is_controller_export
from .field.table import header_key, read_text_table, sidecar_crs

__all__ = ["ALIASES", "NOTE_COLUMNS", "control_from_rows", "read_control"]

#: Column aliases of a control file (lower-cased header -> canonical name).
ALIASES: dict[str, tuple[str, ...]] = {
    "id": ("id", "name", "point", "point_id", "gcp", "gcp_id", "label", "station"),
    "x": ("x", "easting", "east", "e", "x_m", "lon", "longitude", "long"),
    "y": ("y", "northing", "north", "n", "y_m", "lat", "latitude"),
    "z": ("z", "elevation", "elev", "height", "h", "alt", "altitude", "z_m"),
    "sigma_x": ("sigma_x", "std_x", "sx", "sigma_e", "x_std"),
    "sigma_y": ("sigma_y", "std_y", "sy", "sigma_n", "y_std"),
    "sigma_z": ("sigma_z", "std_z", "sz", "sigma_u", "z_std", "sigma_h_z"),
    "sigma_h": ("sigma_h", "sigma_xy", "std_h", "sigma_horizontal"),
    "sigma": ("sigma", "std", "sigma_m", "accuracy"),
    "target_id": ("target_id", "target", "landmark_id", "marker_id"),
    "crs": ("crs", "epsg", "srs"),
}
#: Free-text columns kept as notes (anything else unknown is an error with a did-you-mean).
NOTE_COLUMNS = ("description", "note", "notes", "comment", "comments", "code", "remarks")
_LOOKUP = {alias: name for name, aliases in ALIASES.items() for alias in aliases}


def _canonical(header: list[str], path: Path) -> dict[str, int]:
    """Header -> {canonical column: index}; unknown columns raise with a did-you-mean."""
    cols: dict[str, int] = {}
    for i, raw in enumerate(header):
        h = header_key(raw, _LOOKUP)
        name = _LOOKUP.get(h)
        if name is None and h not in NOTE_COLUMNS:
            near = difflib.get_close_matches(h, [*_LOOKUP, *NOTE_COLUMNS], n=1)
            hint = f"did you mean {near[0]!r}? " if near else ""
            raise bad_input(
                f"{path.name} column {raw!r}",
                header,
                "known control columns (id, x, y, z, sigma_x, sigma_y, sigma_z, ... or aliases)",
                f"{hint}rename it; aliases are listed in factorgraph.control_io.ALIASES",
            )
        if name is not None:
            if name in cols:
                raise bad_input(
                    f"{path.name} column {raw!r}", header, f"one {name!r} column", "drop one"
                )
            cols[name] = i
    return cols


def read_control(
    path: str | Path,
    crs: Any = None,
    sigma_m: float | tuple[float, float, float] | None = None,
    centring_sigma_m: float = 0.02,
) -> ControlPoints:
    """Read a control-point CSV.

    Parameters
    ----------
    path : path
        An Emlid Flow export (``Name``, its projected pair, ``Ellipsoidal height``, the RMS
        columns as the 1-sigmas: :mod:`.field.controller_csv`), or a CSV with a header: ``id,
        x, y, z`` and the 1-sigma columns ``sigma_x, sigma_y,
        sigma_z`` (or ``sigma_h`` for both horizontal axes, or one ``sigma`` for all);
        aliases such as ``name, easting, northing, elevation, lat, lon`` (:data:`ALIASES`);
        optional ``target_id`` (track id of a marked target) and ``crs``; free-text
        ``description``/``notes``/``code`` columns are kept.
    crs : optional
        CRS of the file when it has no ``crs`` column (any pyproj input, e.g. "EPSG:4326":
        then x is longitude, y latitude, degrees).
    sigma_m : float or 3 floats, optional
        1-sigma (m) for points whose file gives none. Without it, a missing sigma is an error.
    centring_sigma_m : float
        See :class:`ControlPoints`.

    Returns
    -------
    ControlPoints
        In the file's CRS; :meth:`ControlPoints.to_crs` reprojects to the map's.
    """
    path = Path(path)
    if not path.is_file():
        raise bad_input("control file", str(path), "an existing CSV file", "check the path")
    table = read_text_table(path, "control file")
    if is_controller_export(table.header):  # an Emlid Flow export: its own columns and CRS
        return _from_export(table.columns(), path, crs, sigma_m, centring_sigma_m)
    return control_from_rows([table.header, *table.rows], path, crs, sigma_m, centring_sigma_m)


def _from_export(
    cols: dict[str, list[str]], path: Path, crs: Any, sigma_m: Any, centring_sigma_m: float
) -> ControlPoints:
    """Control points from a controller export (:mod:`.field.controller_csv`): ``Name`` the
    id, the export's position and ellipsoidal height, ``Easting / Northing / Elevation RMS``
    the per-axis 1-sigma (``sigma_m`` where a cell is empty)."""
    from pyproj import CRS

    export = controller_table(cols, path.name)
    if "id" not in export.point:
        raise bad_input(f"{path.name} header", list(cols), "a Name column too", "export it")
    if crs is not None and not CRS.from_user_input(crs).equals(export.crs):
        raise bad_input(
            "control crs", crs, f"the export's own ({export.crs.name}, {export.how})",
            "drop crs=; the export states its coordinate system",
        )  # fmt: skip
    c = export.columns
    n = len(export.point["id"])
    sigma = np.column_stack(
        [export.point.get(k, np.full(n, np.nan)) for k in ("sigma_x", "sigma_y")]
        + [c.get("z_std", np.full(n, np.nan))]
    )
    if sigma_m is not None:
        sigma = np.where(
            np.isfinite(sigma), sigma, np.broadcast_to(np.asarray(sigma_m, float), (n, 3))
        )
    if not np.isfinite(sigma).all():
        i = int(np.argmax(~np.isfinite(sigma).all(1)))
        raise bad_input(
            f"{path.name} line {i + 2} RMS", sigma[i].tolist(),
            "the export's Easting / Northing / Elevation RMS", "pass sigma_m=",
        )  # fmt: skip
    notes = {
        k: v for k, v in ((h.strip().lower(), v) for h, v in cols.items()) if k in NOTE_COLUMNS
    }
    return ControlPoints(
        np.array(export.point["id"]), np.column_stack([c["x"], c["y"], c["z"]]), sigma,
        export.crs.to_string(), np.full(n, -1, int), centring_sigma_m, source=path.name,
        notes=notes,
    )  # fmt: skip


def control_from_rows(
    rows: list[list[str]],
    path: Path,
    crs: Any = None,
    sigma_m: float | tuple[float, float, float] | None = None,
    centring_sigma_m: float = 0.02,
) -> ControlPoints:
    """:func:`read_control` of rows already read as text (a header, then one row per point):
    a CSV's, or a GIS layer's (``toolkit.point_files``); ``path`` names the file in errors
    and finds a ``.crs`` / ``.prj`` sidecar."""
    if len(rows) < 2:
        raise bad_input("control file", str(path), "a header and >= 1 point", "add points")
    cols = _canonical(rows[0], path)
    missing = [c for c in ("id", "x", "y", "z") if c not in cols]
    if missing:  # id: the point's name, which stops.csv, targets and the report use
        raise bad_input(f"{path.name} header", rows[0], f"columns {missing} too", "see ALIASES")
    body = rows[1:]

    def col(name: str) -> np.ndarray | None:
        if name not in cols:
            return None
        j, out = cols[name], []
        for i, r in enumerate(body):
            cell = r[j].strip()
            try:
                out.append(float(cell) if cell else math.nan)
            except ValueError as exc:
                raise bad_input(f"{path.name} line {i + 2} {name}", cell, "a number", "") from exc
        return np.array(out)

    ids = np.array([r[cols["id"]].strip() for r in body])
    xyz = np.column_stack([col("x"), col("y"), col("z")])
    sigma = _sigmas(col, len(body), sigma_m, path)
    tid = col("target_id")
    tid = np.full(len(body), -1, int) if tid is None else np.nan_to_num(tid, nan=-1).astype(int)
    file_crs = {r[cols["crs"]].strip() for r in body} - {""} if "crs" in cols else set()
    if len(file_crs) > 1:
        raise bad_input(f"{path.name} crs", sorted(file_crs), "one CRS per file", "reproject")
    file_crs = file_crs or {side[0] for side in [sidecar_crs(path)] if side}
    if not file_crs and crs is None:
        want = f"a crs column, a {path.stem}.crs sidecar or crs="
        raise bad_input("control crs", path.name, want, 'e.g. "EPSG:4326"')
    use = crs if crs is not None else file_crs.pop()
    if use.isdigit() if isinstance(use, str) else False:
        use = f"EPSG:{use}"
    notes = {h.strip().lower(): [r[i] for r in body] for i, h in enumerate(rows[0])}
    notes = {k: v for k, v in notes.items() if k in NOTE_COLUMNS}
    return ControlPoints(ids, xyz, sigma, use, tid, centring_sigma_m, source=path.name, notes=notes)


def _sigmas(col, n: int, sigma_m, path: Path) -> np.ndarray:
    """Per-axis 1-sigma (n, 3) from sigma_x/y/z, sigma_h, sigma, or the ``sigma_m`` default."""
    out = np.full((n, 3), np.nan)
    one, h = col("sigma"), col("sigma_h")
    if one is not None:
        out[:] = one[:, None]
    if h is not None:
        out[:, :2] = np.where(np.isfinite(h), h, out[:, 0])[:, None]
    for i, a in enumerate("xyz"):
        c = col(f"sigma_{a}")
        if c is not None:
            out[:, i] = np.where(np.isfinite(c), c, out[:, i])
    if sigma_m is not None:
        out = np.where(np.isfinite(out), out, np.broadcast_to(np.asarray(sigma_m, float), (n, 3)))
    if not np.isfinite(out).all():
        i = int(np.argmax(~np.isfinite(out).all(1)))
        raise bad_input(
            f"{path.name} line {i + 2} sigma",
            out[i].tolist(),
            "a 1-sigma per axis (sigma_x, sigma_y, sigma_z, sigma_h or sigma columns)",
            "add the survey's stated accuracy, or pass sigma_m=",
        )
    return out
