"""Breaklines from a file: lines a surveyor knows the ground steps across (an ice cliff, a
calving front, a moraine's edge), for ``terrain.BreaklineMean``.

Any vector file GDAL reads (GeoPackage, GeoJSON, Shapefile...) of LineStrings or
MultiLineStrings, reprojected to the map's CRS from the CRS it declares, or a WKT file (one
geometry per line, or a GEOMETRYCOLLECTION) in the map's CRS (:mod:`toolkit.vector_io`).
A line that stops inside the survey has its step die out towards that end (its taper;
terrain/breakline.py).

The same lines come from a ``glacimap run`` / ``process`` scenario's ``[reconstruct]``
``breaklines``, ``breakline_width`` and ``breakline_taper`` (:func:`scenario_breaklines`);
errors then name those keys.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

import numpy as np

from terrain.dem_reading import dem_lacks
from terrain.errors import bad_input

from .vector_io import read_geometries

__all__ = [
    "breakline_taper",
    "breakline_width",
    "check_breakline_options",
    "is_search",
    "read_breaklines",
    "scenario_breaklines",
    "scenario_lines",
    "step_notes",
    "with_breaklines",
]

FIELD = "--breaklines"
#: ``--breaklines auto``: lines found in the samples (``terrain.find_breaklines``).
AUTO = "auto"
#: Said after the lines the search dropped: a step seen on few tracks is not confirmed
#: (a rover's four swaths across a 4 m scarp: 3.03 +- 0.93 m), and a user who knows where
#: it runs maps it best by drawing it (docs/terrain.md "The search on a rover's own survey").
DROPPED_HINT = (
    "a dropped line may still be a step the samples cannot confirm (seen on few tracks): "
    "if you know where it runs, draw it in a vector file (--breaklines FILE, or the "
    "scenario's [reconstruct] breaklines)"
)


def read_breaklines(
    path: Path, crs: Any = None, notes: list[str] | None = None, field: str = FIELD
) -> list[np.ndarray]:
    """The lines of ``path`` as vertex arrays, each of shape (k, 2), in file order, in
    ``crs`` when given (reprojected from the CRS the file declares:
    :func:`toolkit.vector_io.read_geometries`); ``notes``, when given, gains a sentence on
    how they were read (for the console).

    Raises an ``InputError`` naming ``field`` (``--breaklines``, or the scenario key
    ``reconstruct.breaklines``) when the file is missing or unreadable,
    holds no line, holds another geometry (a polygon's outline is not a step), or holds
    longitude / latitude for a projected ``crs`` without declaring it.
    """
    geoms, note = read_geometries(Path(path), field, crs)
    if "empty geometries" in note:  # counted, never silently dropped
        warnings.warn(note, stacklevel=2)
    lines: list[np.ndarray] = []
    for g in geoms:
        for part in getattr(g, "geoms", [g]):
            if part.geom_type != "LineString":
                raise bad_input(
                    field,
                    f"a {part.geom_type} in {Path(path).name}",
                    "LineStrings (or MultiLineStrings) only",
                    "draw each breakline as a line along the step",
                )
            lines.append(np.asarray(part.coords, dtype=float)[:, :2])
    if not lines:
        raise bad_input(field, Path(path).name, "at least one line", f"or leave {field} out")
    if notes is not None:
        notes.append(f"{len(lines)} line(s) from {Path(path).name}; {note.split(': ', 1)[1]}")
    return lines


def is_search(lines: Any) -> bool:
    """Whether ``--breaklines`` asks for the lines to be found in the samples (``auto``)."""
    return isinstance(lines, str | Path) and str(lines).strip().lower() == AUTO


def with_breaklines(
    mean: Any,
    lines: Any,
    width: float | str = "auto",
    taper: float | str = "auto",
    crs: Any = None,
    notes: list[str] | None = None,
    samples: Any = None,
) -> Any:
    """``mean`` with a step across each breakline (``terrain.BreaklineMean``), or ``mean``
    itself when ``lines`` is None. ``lines``: a vector file (:func:`read_breaklines`, read
    in ``crs``: the map's, its reading said in ``notes``), vertex arrays already in it, or
    ``"auto"``: found in ``samples`` (``terrain.find_breaklines``; what was found, and what
    was dropped and why, said in ``notes``; ``mean`` itself when none is);
    ``width``, ``taper``: ``"auto"`` or metres (:func:`breakline_width`,
    :func:`breakline_taper`)."""
    if lines is None:
        return mean
    from terrain import BreaklineMean

    if is_search(lines):
        from terrain import find_breaklines

        if samples is None:
            raise bad_input(FIELD, AUTO, "the samples to search", "pass samples=")
        search = find_breaklines(samples)
        if notes is not None:
            notes.append(search.summary())
            notes.extend(f"dropped: {why}" for why in search.dropped)
            if search.dropped:  # e.g. a scarp seen on few swaths: not confirmed, maybe real
                notes.append(DROPPED_HINT)
        if not search.lines:
            return mean
        lines = search.lines
    elif isinstance(lines, str | Path):
        lines = read_breaklines(Path(lines), crs, notes)
    return BreaklineMean(
        lines, base=mean, width=breakline_width(width), taper=breakline_taper(taper)
    )


def _metres_or_auto(value: Any, option: str, what: str, example: str) -> float | str:
    if isinstance(value, str) and value.strip().lower() == "auto":
        return "auto"
    try:  # TOML true / false is not a length
        metres = float("nan") if isinstance(value, bool) else float(value)
    except (TypeError, ValueError):
        metres = float("nan")
    if not 0 < metres < float("inf"):
        raise bad_input(option, value, f'"auto" or a positive {what} in m', example)
    return metres


def breakline_width(value: Any, field: str = "--breakline-width") -> float | str:
    """``--breakline-width``: ``"auto"`` (each line's own, chosen by fit) or a positive
    number of metres; anything else an ``InputError`` naming ``field``."""
    return _metres_or_auto(value, field, "width", "e.g. auto or 1.5")


def breakline_taper(value: Any, field: str = "--breakline-taper") -> float | str:
    """``--breakline-taper``: ``"auto"`` or the positive length (m) a step dies out over
    before an end inside the survey; anything else an ``InputError`` naming ``field``."""
    return _metres_or_auto(value, field, "length", "e.g. auto or 40")


def scenario_breaklines(reconstruct: dict[str, Any], base: Path) -> dict[str, Any]:
    """A scenario's ``[reconstruct]`` table with its breakline keys checked before any
    work: ``breaklines`` ``""`` (none), ``"auto"`` (found in the selected landmarks) or a
    vector file, a relative path resolved against ``base`` (the scenario file's folder) and
    made absolute, the file read once; ``breakline_width`` / ``breakline_taper`` ``"auto"``
    or positive metres. Errors name the key (``reconstruct.breaklines``...)."""
    out = dict(reconstruct)
    raw = str(out.get("breaklines", "")).strip()
    if is_search(raw):
        out["breaklines"] = AUTO
    elif raw:
        path = Path(raw).expanduser()
        path = path if path.is_absolute() else (base / path)
        read_breaklines(path, field="reconstruct.breaklines")
        out["breaklines"] = str(path.resolve())
    out["breakline_width"] = breakline_width(
        out.get("breakline_width", "auto"), "reconstruct.breakline_width"
    )
    out["breakline_taper"] = breakline_taper(
        out.get("breakline_taper", "auto"), "reconstruct.breakline_taper"
    )
    return out


def scenario_lines(settings: dict[str, Any]) -> tuple[Any, float | str, float | str]:
    """``(lines, width, taper)`` of loaded settings' ``[reconstruct]`` table, as
    :func:`with_breaklines` takes them: lines None when ``breaklines`` is ``""`` (or absent:
    settings from before 0.39.0)."""
    rc = settings.get("reconstruct", {})
    lines = str(rc.get("breaklines", "")).strip() or None
    return lines, rc.get("breakline_width", "auto"), rc.get("breakline_taper", "auto")


def check_breakline_options(
    path: Path, width: Any, taper: Any = "auto"
) -> tuple[float | str, float | str]:
    """``--breaklines``, ``--breakline-width`` and ``--breakline-taper`` checked before any
    work (the file parses and holds lines; width and taper are valid): ``(width, taper)``
    as :func:`breakline_width` and :func:`breakline_taper` give them. The lines themselves
    are read again in the map's CRS when it is known (:func:`with_breaklines`)."""
    if not is_search(path):
        read_breaklines(Path(path))
    return breakline_width(width), breakline_taper(taper)


def step_notes(mean: Any) -> list[str]:
    """One sentence per breakline of a fitted ``terrain.BreaklineMean`` (for the console):
    its step's height with its 1-sigma, its width, and where it stops inside the survey the
    length its step dies out over; ``[]`` for another mean."""
    coef, cov = getattr(mean, "coef_", None), getattr(mean, "coef_cov_", None)
    if type(mean).__name__ != "BreaklineMean" or coef is None:
        return []
    out = []
    lacks = dem_lacks(mean)
    for j in range(len(mean.lines)):
        k = mean.coef_names.index(f"step{j + 1}_m")
        sds = getattr(mean, "widths_sd_", None)  # a width chosen by the map's evidence
        width = f"{mean.widths_[j]:g}" + ("" if sds is None else f" +- {sds[j]:.2f}")
        text = (
            f"line {j + 1}: step {coef[k]:.2f} +- {np.sqrt(cov[k, k]):.2f} m up to its left, "
            f"{width} m wide"
        )
        if lacks:  # the prior DEM's share of it (terrain.dem_reading)
            text += (
                f"; the prior DEM lacks {lacks[j][0]:.2f} +- {lacks[j][1]:.2f} m of it "
                "(about 0 when the DEM holds the step, about the step when it predates it)"
            )
        inside = zip(("first", "last"), mean.open_ends_[j], strict=True)
        ends = [name for name, open_end in inside if open_end]
        if ends:
            text += (
                f"; its {' and '.join(ends)} vertex inside the survey: the step dies out over "
                f"the {mean.tapers_[j]:g} m before it"
            )
        out.append(text)
    return out
