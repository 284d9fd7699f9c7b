"""The ``--breaklines`` and ``--breakline-width`` options ``reconstruct`` and ``process``
share (``toolkit.breaklines_io``; ``terrain.BreaklineMean``)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

Breaklines = Annotated[
    Path | None,
    typer.Option(
        "--breaklines",
        help="Lines the ground steps across (an ice cliff, a moraine's edge), each across "
        "the survey: a GeoPackage, GeoJSON, Shapefile... (reprojected from its CRS) or WKT "
        "(the map's CRS). Step heights fitted with their 1-sigma.",
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
