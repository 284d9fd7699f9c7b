"""Batch refinement of the online iSAM2 estimate (factorgraph.refine)."""

from __future__ import annotations

import numpy as np
import pytest

from factorgraph.localize import LocalizeParams, localize
from factorgraph.refine import levenberg_marquardt, split_landmark_factors
from factorgraph.simulate import simulate_traverse
from terrain.synthetic import default_site

W, N = 526000.0, 6475600.0


@pytest.fixture(scope="module")
def result():
    """An L-shaped 200 m traverse: the turn makes the online linear estimate visibly off."""
    dem = default_site(2.0)
    wp = np.array([[W + 20, N - 75], [W + 140, N - 75], [W + 140, N - 155]])
    return localize(simulate_traverse(dem, wp, seed=5))


def _truth_values(res):
    import gtsam

    X, B, L = gtsam.symbol_shorthand.X, gtsam.symbol_shorthand.B, gtsam.symbol_shorthand.L
    D = gtsam.symbol_shorthand.D
    tr = res.log.truth
    v = gtsam.Values()
    for k in range(res.log.n_keyframes):
        roll, pitch, yaw = tr["rpy"][k]
        v.insert(X(k), gtsam.Pose3(gtsam.Rot3.Ypr(yaw, pitch, roll), tr["xyz"][k]))
        v.insert(B(k), tr["gps_bias"][k])
        v.insert(D(k), tr["odometry_drift"])  # drawn once per traverse: constant
    for lid, xyz in zip(res.landmark_id, res.true_landmarks(), strict=True):
        v.insert(L(int(lid)), xyz)
    return v


def test_refined_estimate_is_a_map(result):
    """A MAP estimate has a lower graph error than the truth (the truth is one draw of the
    noise; the optimum fits it better) and than the online linear pass."""
    rep = result.refine
    truth_error = result.graph.error(_truth_values(result))
    assert rep["error_final"] == pytest.approx(result.graph.error(result.estimate), rel=1e-9)
    assert rep["error_final"] < truth_error
    assert rep["error_final"] <= rep["error_start"] <= rep["error_online"]
    assert rep["iterations"] >= 1 and rep["retriangulation_failed"] == 0


def test_levenberg_marquardt_matches_gtsam(result):
    """Reference: gtsam.LevenbergMarquardtOptimizer from the same start reaches the same
    minimum (same error to 1e-4 relative, poses to a millimetre)."""
    import gtsam

    pose_graph, _ = split_landmark_factors(result.graph)
    start = gtsam.Values()
    X, B, D = gtsam.symbol_shorthand.X, gtsam.symbol_shorthand.B, gtsam.symbol_shorthand.D
    rng = np.random.default_rng(0)
    for k in range(result.log.n_keyframes):  # perturb the refined poses by ~0.5 m, 1 deg
        p = result.estimate.atPose3(X(k))
        d = np.r_[rng.normal(0, 0.017, 3), rng.normal(0, 0.5, 3)]
        start.insert(X(k), p.retract(d))
        start.insert(B(k), result.estimate.atPoint3(B(k)))
        start.insert(D(k), result.estimate.atPoint2(D(k)))
    ours, its, errors = levenberg_marquardt(pose_graph, start, max_iterations=50, rtol=1e-10)
    lm = gtsam.LevenbergMarquardtParams()
    lm.setRelativeErrorTol(1e-10)
    lm.setAbsoluteErrorTol(1e-10)
    lm.setMaxIterations(100)
    ref = gtsam.LevenbergMarquardtOptimizer(pose_graph, start, lm).optimize()
    assert its >= 2 and np.all(np.diff(errors) <= 0)
    assert errors[-1] == pytest.approx(pose_graph.error(ref), rel=1e-4)
    for k in range(0, result.log.n_keyframes, 25):
        np.testing.assert_allclose(
            ours.atPose3(X(k)).translation(), ref.atPose3(X(k)).translation(), atol=1e-3
        )


def test_refinement_beats_the_online_pass(result):
    """Against truth: the refined trajectory is closer than the online (filtered) one."""
    truth = result.log.truth["xyz"]
    rms = lambda a: float(np.sqrt(((a - truth)[:, :2] ** 2).sum(1).mean()))  # noqa: E731
    assert rms(result.keyframe_xyz) < rms(result.online_xyz)


def test_refine_off_keeps_the_online_estimate():
    dem = default_site(2.0)
    log = simulate_traverse(dem, np.array([[W + 20, N - 75], [W + 80, N - 75]]), seed=1)
    res = localize(log, LocalizeParams(refine=False))
    assert res.refine == {}
