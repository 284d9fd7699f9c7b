"""Coverage metrics (paper Eq 11-16) against values computed by hand beside each assertion."""

import numpy as np
import pytest
from shapely.geometry import Polygon, box

from survey.coverage import (
    candidate_points,
    centeredness,
    distributedness,
    path_length,
    plan_distributedness,
    robot_centric_coverage,
    science_centric_coverage,
)
from survey.lawnmower import lawnmower
from survey.plan import SurveyPlan
from terrain import InputError


def test_science_centric_coverage_by_hand():
    candidates = np.array([[0.0, 0.0], [2.0, 0.0], [4.0, 0.0]])
    samples = np.array([[0.0, 0.0], [3.0, 0.0]])
    # ref = centroid of candidates = (2, 0); T_S = 2 + 0 + 2 = 4; T_M = 2 + 1 = 3
    # Eq 11: %SCC = T_M / T_S = 3 / 4 = 0.75
    assert science_centric_coverage(samples, candidates) == pytest.approx(0.75)
    # explicit ref (0, 0): T_S = 0 + 2 + 4 = 6; T_M = 0 + 3 = 3 -> 0.5
    assert science_centric_coverage(samples, candidates, ref=(0.0, 0.0)) == pytest.approx(0.5)
    # all candidates sampled -> 1 exactly
    assert science_centric_coverage(candidates, candidates) == pytest.approx(1.0)
    # 3-4-5 triangle: candidate (3, 4) and (-3, -4), ref (0, 0): T_S = 10; sample (0, 5): T_M = 5
    two = np.array([[3.0, 4.0], [-3.0, -4.0]])
    assert science_centric_coverage([[0.0, 5.0]], two) == pytest.approx(0.5)


def test_candidate_points_inside_region_only():
    square_with_hole = Polygon([(0, 0), (4, 0), (4, 4), (0, 4)], [[(1, 1), (3, 1), (3, 3), (1, 3)]])
    pts = candidate_points(square_with_hole, 1.0)
    # 16 cell centres (0.5 .. 3.5), the 4 centres (1.5|2.5, 1.5|2.5) lie in the hole -> 12
    assert pts.shape == (12, 2)
    assert not np.any((pts[:, 0] > 1) & (pts[:, 0] < 3) & (pts[:, 1] > 1) & (pts[:, 1] < 3))
    with pytest.raises(InputError, match="spacing"):
        candidate_points(square_with_hole, 0.0)


def test_centeredness_by_hand():
    ref = (0.0, 0.0)
    # symmetric set: CoM = ((-1 + 1) / 2, 0) = (0, 0) -> alpha = 0
    assert centeredness([[-1.0, 0.0], [1.0, 0.0]], ref, d_max=4.0) == 0.0
    # one-sided: CoM = ((1 + 3) / 2, 0) = (2, 0); |CoM - ref| = 2; alpha = 2 / 4 = 0.5
    assert centeredness([[1.0, 0.0], [3.0, 0.0]], ref, d_max=4.0) == pytest.approx(0.5)
    # D_Max from the region: farthest point of box(-3, -4, 3, 4) from (0, 0) is a corner, 5 m;
    # CoM (2, 0) -> alpha = 2 / 5 = 0.4
    region = box(-3, -4, 3, 4)
    assert centeredness([[1.0, 0.0], [3.0, 0.0]], ref, region=region) == pytest.approx(0.4)
    # neither d_max nor region: D_Max = farthest sample from ref = 3 m -> alpha = 2 / 3
    assert centeredness([[1.0, 0.0], [3.0, 0.0]], ref) == pytest.approx(2.0 / 3.0)
    with pytest.raises(InputError, match="d_max"):
        centeredness([[1.0, 0.0]], ref, d_max=0.0)


def test_distributedness_by_hand():
    # 4-sample zigzag around y_swath = 1: y = 0, 2, 0, 2
    # Eq 14: beta_a = (1 + 1 + 1 + 1) / 4 = 1
    # Eq 15: |dy| = 2, 2, 2 (all >= 1 m) -> beta_b = 6 / 3 = 2;  Eq 16: beta = 1 / 2 = 0.5
    assert distributedness([0.0, 2.0, 0.0, 2.0], 1.0) == pytest.approx(0.5)
    # with a sub-metre step: y = 0, 2, 1.5, 3.5 around 1
    # beta_a = (1 + 1 + 0.5 + 2.5) / 4 = 1.25
    # |dy| = 2, 0.5, 2; the 0.5 m pair is left out of the sum, the denominator stays M - 1 = 3:
    # beta_b = (2 + 2) / 3 = 4 / 3;  beta = 1.25 / (4 / 3) = 0.9375
    assert distributedness([0.0, 2.0, 1.5, 3.5], 1.0) == pytest.approx(0.9375)


def test_distributedness_undefined_is_nan():
    # straight swath: beta_a = 0, beta_b = 0 -> 0 / 0, documented NaN
    assert np.isnan(distributedness([5.0, 5.0, 5.0], 5.0))
    # constant 3 m offset: beta_a = 3 but no change >= 1 m -> beta_b = 0, still NaN
    assert np.isnan(distributedness([8.0, 8.2, 8.0], 5.0))
    assert np.isnan(distributedness([1.0], 0.0))  # one sample: no consecutive pair


def test_robot_centric_coverage_and_path_length():
    # D_S = 150 m driven of D_T = 600 m -> 0.25
    assert robot_centric_coverage(150.0, 600.0) == pytest.approx(0.25)
    # (0,0) -> (3,4) -> (3,10): 5 + 6 = 11 m
    assert path_length([[0.0, 0.0], [3.0, 4.0], [3.0, 10.0]]) == pytest.approx(11.0)
    assert path_length(np.zeros((1, 2))) == 0.0
    with pytest.raises(InputError, match="total_length_m"):
        robot_centric_coverage(1.0, 0.0)
    with pytest.raises(InputError, match="path_length_m"):
        robot_centric_coverage(-1.0, 10.0)


def test_plan_distributedness_lawnmower_is_nan_and_zigzag_by_hand():
    plan = lawnmower(box(0, 0, 100, 50), 2, heading=90)
    per, overall = plan_distributedness(plan)
    assert per.shape == (2,) and np.all(np.isnan(per)) and np.isnan(overall)
    # Hand-made plan at heading 90, origin (0, 0): across = northing. Offsets (1, 10):
    # swath 0: y = 0, 2, 0, 2 about 1 -> beta 0.5 (as above); swath 1: y = 10, 10 -> NaN
    samples = np.array([[0, 0], [1, 2], [2, 0], [3, 2], [4, 10], [5, 10]], float)
    zig = SurveyPlan(
        waypoints=samples,
        swath=[0, 0, 0, 0, 1, 1],
        pattern="piecewise_continuous",
        params={},
        samples=samples,
        sample_swath=[0, 0, 0, 0, 1, 1],
        swath_offsets=[1.0, 10.0],
        heading_deg=90.0,
        origin=(0.0, 0.0),
    )
    per, overall = plan_distributedness(zig)
    assert per[0] == pytest.approx(0.5) and np.isnan(per[1])
    assert overall == pytest.approx(0.5)  # mean over the swaths where beta is defined
