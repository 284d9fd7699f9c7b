"""Survey planning and certification: plans, coverage metrics, mapping standards, Monte Carlo.

``survey`` depends on :mod:`terrain` only (the layout ``toolkit -> {survey, factorgraph} ->
terrain``). Paper Sections III-IV, Eq 10-16, Tables I-III. The names below are the public
contract:

* Plans: :class:`SurveyPlan` from :func:`lawnmower` or :func:`piecewise_continuous` over a
  region (:func:`as_region`), :func:`default_heading`, :func:`path_length`.
* Coverage metrics (Eq 11-16): :func:`candidate_points`, :func:`centeredness`,
  :func:`distributedness`, :func:`plan_distributedness`, :func:`robot_centric_coverage`,
  :func:`science_centric_coverage`.
* Mapping standards: the module :mod:`survey.standards` (ASPRS 2023 / NMAS / NSSDA
  accuracy classes and checkpoint rules: ``from survey import standards``).
* Monte Carlo: :func:`sweep` (:class:`SweepConfig` -> :class:`SweepResult`),
  :func:`summarize`, :func:`class_limits`.
"""

from . import standards
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
    "standards",
    "sweep",
]
