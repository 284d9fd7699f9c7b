"""The ``--breaklines``, ``--breakline-width`` and ``--breakline-taper`` options
``reconstruct`` and ``process`` share (``toolkit.breaklines_io``; ``terrain.BreaklineMean``)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

Breaklines = Annotated[
    Path | None,
    typer.Option(
        "--breaklines",
        help="Lines the ground steps across (an ice cliff, a moraine's edge): a GeoPackage, "
        "GeoJSON, Shapefile... (reprojected from its CRS) or WKT (the map's CRS). Step "
        "heights fitted with their 1-sigma; a line that stops inside the survey has its "
        'step die out towards that end. "auto": lines found where the samples step '
        "(terrain.find_breaklines), each kept only where its step is told from zero.",
    ),
]
BreaklineWidth = Annotated[
    str,
    typer.Option(
        "--breakline-width",
        help="Scale of each step's logistic, m, or \"auto\": each line's own, by least "
        "squares beside it.",
    ),
]
BreaklineTaper = Annotated[
    str,
    typer.Option(
        "--breakline-taper",
        help='Length a step dies out over before an end inside the survey, m, or "auto": '
        "each line's own, by least squares beside it.",
    ),
]


def print_breakline_notes(console: Any, cert: dict[str, Any], mean: Any) -> None:
    """Under the results table: what ``breaklines = "auto"`` found and dropped (the
    certificate's ``inputs.breakline_search``), then each fitted step's height with its
    1-sigma (``toolkit.breaklines_io.step_notes``); nothing for a map without breaklines."""
    from rich.markup import escape

    from toolkit.breaklines_io import step_notes

    found = (cert.get("inputs") or {}).get("breakline_search") or []
    for note in [*found, *step_notes(mean)]:
        console.print(f"breaklines: {escape(note)}")
