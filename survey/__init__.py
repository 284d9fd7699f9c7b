"""Survey planning and certification: plans, coverage metrics, mapping standards, Monte Carlo.

Depends on :mod:`terrain` only (DESIGN.md §2). Paper Sections III-IV, Eq 10-16, Tables I-III.
"""

from .coverage import (
    candidate_points,
    centeredness,
    distributedness,
    path_length,
    plan_distributedness,
    robot_centric_coverage,
    science_centric_coverage,
)
from .lawnmower import default_heading, lawnmower
from .piecewise import piecewise_continuous
from .plan import SurveyPlan
from .region import as_region
from .sweep import SweepConfig, SweepResult, class_limits, summarize, sweep

__all__ = [
    "SurveyPlan",
    "SweepConfig",
    "SweepResult",
    "as_region",
    "candidate_points",
    "centeredness",
    "class_limits",
    "default_heading",
    "distributedness",
    "lawnmower",
    "path_length",
    "piecewise_continuous",
    "plan_distributedness",
    "robot_centric_coverage",
    "science_centric_coverage",
    "summarize",
    "sweep",
]
