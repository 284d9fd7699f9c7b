"""The terrain layer: grids and CRS, synthetic glaciers, satellite priors, GP reconstruction.

``terrain`` is the base of glacimap (DESIGN.md §2): it imports nothing from ``survey``,
``factorgraph`` or ``toolkit``.
"""

from .errors import (
    CRSMismatchError,
    DuplicateLocationError,
    GlacimapError,
    InputError,
    JitterWarning,
    NotFittedError,
    NumericalError,
)
from .grid import DEFAULT_CRS, Grid
from .samples import ElevationSamples

__all__ = [
    "DEFAULT_CRS",
    "CRSMismatchError",
    "DuplicateLocationError",
    "GlacimapError",
    "ElevationSamples",
    "Grid",
    "InputError",
    "JitterWarning",
    "NotFittedError",
    "NumericalError",
]
