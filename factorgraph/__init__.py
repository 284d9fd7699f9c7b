"""Localization: sensors, traverse simulation, the GTSAM iSAM2 factor graph, landmark selection.

Depends on :mod:`terrain` only (DESIGN.md §2). Filled by the localization issue.
"""

from .control import ControlPoints, check_in_area, check_independent, read_control
from .control_sim import simulate_control

__all__ = [
    "ControlPoints",
    "check_in_area",
    "check_independent",
    "read_control",
    "simulate_control",
]
