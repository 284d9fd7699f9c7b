"""Breaklines from a file: lines a surveyor knows the ground steps across (an ice cliff, a
calving front, a moraine's edge), for ``terrain.BreaklineMean``.

A GeoJSON file (a FeatureCollection, a Feature or a bare geometry) or a WKT file (one
geometry per line, or a GEOMETRYCOLLECTION) of LineStrings or MultiLineStrings, coordinates
in the map's CRS, metres. Each line must cross the survey (terrain/breakline.py).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from terrain.errors import bad_input

__all__ = ["breakline_width", "read_breaklines", "with_breaklines"]

FIELD = "--breaklines"


def read_breaklines(path: Path) -> list[np.ndarray]:
    """The lines of ``path`` as vertex arrays, each of shape (k, 2), in file order.

    Raises an ``InputError`` naming ``--breaklines`` when the file is missing or unreadable,
    holds no line, or holds another geometry (a polygon's outline is not a step).
    """
    import shapely

    path = Path(path)
    if not path.is_file():
        raise bad_input(FIELD, str(path), "an existing GeoJSON or WKT file", "check the path")
    text = path.read_text(encoding="utf-8").strip()
    try:
        if text.startswith("{"):
            geoms = _geojson(json.loads(text))
        else:
            geoms = [shapely.from_wkt(t) for t in text.splitlines() if t.strip()]
    except (ValueError, shapely.errors.GEOSException, KeyError, TypeError) as exc:
        raise bad_input(
            FIELD, path.name, "GeoJSON or WKT lines", f"the file does not parse: {exc}"
        ) from exc
    lines: list[np.ndarray] = []
    for g in geoms:
        parts = getattr(g, "geoms", [g])
        for part in parts:
            if part.geom_type != "LineString":
                raise bad_input(
                    FIELD,
                    f"a {part.geom_type} in {path.name}",
                    "LineStrings (or MultiLineStrings) only",
                    "draw each breakline as a line across the survey",
                )
            lines.append(np.asarray(part.coords, dtype=float)[:, :2])
    if not lines:
        raise bad_input(FIELD, path.name, "at least one line", "or leave --breaklines out")
    return lines


def with_breaklines(mean: Any, lines: Any, width: float | str = "auto") -> Any:
    """``mean`` with a step across each breakline (``terrain.BreaklineMean``), or ``mean``
    itself when ``lines`` is None. ``lines``: a GeoJSON/WKT path (:func:`read_breaklines`) or
    vertex arrays already read; ``width``: ``"auto"`` or metres (:func:`breakline_width`)."""
    if lines is None:
        return mean
    from terrain import BreaklineMean

    if isinstance(lines, str | Path):
        lines = read_breaklines(Path(lines))
    return BreaklineMean(lines, base=mean, width=breakline_width(width))


def breakline_width(value: Any) -> float | str:
    """``--breakline-width``: ``"auto"`` (each line's own, chosen by fit) or a positive
    number of metres; anything else an ``InputError`` naming the option."""
    if isinstance(value, str) and value.strip().lower() == "auto":
        return "auto"
    try:
        width = float(value)
    except (TypeError, ValueError):
        width = float("nan")
    if not width > 0:
        raise bad_input(
            "--breakline-width", value, '"auto" or a positive width in m', "e.g. auto or 1.5"
        )
    return width


def _geojson(obj: dict) -> list:
    import shapely

    kind = obj.get("type")
    if kind == "FeatureCollection":
        return [shapely.geometry.shape(f["geometry"]) for f in obj["features"]]
    if kind == "Feature":
        return [shapely.geometry.shape(obj["geometry"])]
    return [shapely.geometry.shape(obj)]
