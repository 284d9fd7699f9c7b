"""The ``--breaklines``, ``--breakline-width`` and ``--breakline-taper`` options
``reconstruct`` and ``process`` share (``toolkit.breaklines_io``; ``terrain.BreaklineMean``)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

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
