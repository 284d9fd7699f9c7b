"""Odometry drift states (``LocalizeParams(odometry_drift=True)``): the factor's Jacobians,
the exact marginals with the extra per-keyframe state, and recovery of a scale error."""

from __future__ import annotations

import numpy as np
import pytest

from factorgraph.factors import drift_odometry_factor
from factorgraph.localize import LocalizeParams, localize
from factorgraph.sensors import GPSModel, OdometryModel, SensorSuite
from factorgraph.simulate import simulate_traverse
from terrain.synthetic import default_site

W, N = 526000.0, 6475600.0


def test_drift_factor_jacobians_match_central_differences():
    """Reference: central differences of the unwhitened error through ``Values.retract``
    (GTSAM's own tangent convention), step 1e-6."""
    import gtsam

    X, D = gtsam.symbol_shorthand.X, gtsam.symbol_shorthand.D
    rng = np.random.default_rng(1)
    T1 = gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(0, 0.3, 3)), rng.normal(0, 5, 3))
    step = gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(0, 0.05, 3)), np.array([1.0, 0.1, 0.05]))
    values = gtsam.Values()
    values.insert(X(0), T1)
    values.insert(X(1), T1.compose(step))
    values.insert(D(0), np.array([0.015, 0.004]))
    measured = np.r_[rng.normal(0, 0.03, 3), 1.02, 0.08, 0.04]
    f = drift_odometry_factor(X(0), X(1), D(0), measured, np.full(6, 0.1))
    A, _ = f.linearize(values).jacobian()
    layout = ((X(0), 6), (X(1), 6), (D(0), 2))

    def shifted(key, i, h):
        dv = gtsam.VectorValues()
        for kk, dim in layout:
            z = np.zeros(dim)
            if kk == key:
                z[i] = h
            dv.insert(kk, z)
        return values.retract(dv)

    cols = [
        (f.unwhitenedError(shifted(k, i, 1e-6)) - f.unwhitenedError(shifted(k, i, -1e-6))) / 2e-6
        for k, dim in layout
        for i in range(dim)
    ]
    np.testing.assert_allclose(A, np.array(cols).T / 0.1, atol=1e-6)
    # at the true drift the corrected measurement reproduces the step exactly
    s, w = 0.02, 1e-3
    d = np.linalg.norm(step.translation() * (1 + s))
    R_m = step.rotation().compose(gtsam.Rot3.Rz(w * d))
    meas = np.r_[gtsam.Rot3.Logmap(R_m), step.translation() * (1 + s)]
    values.update(D(0), np.array([s, w]))
    f = drift_odometry_factor(X(0), X(1), D(0), meas, np.full(6, 0.1))
    np.testing.assert_allclose(f.unwhitenedError(values), 0.0, atol=1e-12)


@pytest.fixture(scope="module")
def scaled_log():
    """A 2-leg 240 m traverse, white GPS, odometry with a scale error over 2 % (stated
    sigma 3 %) and little heading drift: a 120 m leg comes out > 2.4 m long in dead
    reckoning."""
    odo = OdometryModel(scale_error_sigma=0.03, heading_drift_sigma_deg_per_m=0.005)
    sensors = SensorSuite(gps=GPSModel(bias_sigma_m=(0.0, 0.0, 0.0)), odometry=odo)
    wp = np.array([[W + 20, N - 60], [W + 140, N - 60], [W + 140, N - 90], [W + 20, N - 90]])
    for seed in range(20):  # the first seed whose drawn scale error exceeds 2 % (P = 0.5)
        log = simulate_traverse(default_site(2.0), wp, sensors, seed=seed)
        if abs(log.truth["odometry_drift"][0]) > 0.02:
            return log
    raise AssertionError("no seed with a 2 % scale error in 20")


def test_drift_states_recover_the_scale_and_marginals_stay_exact(scaled_log):
    import gtsam

    log = scaled_log
    folded = localize(log, LocalizeParams(gps_model="white"))
    res = localize(log, LocalizeParams(gps_model="white", odometry_drift=True))
    assert res.odometry_drift.shape == (log.n_keyframes, 2) and folded.odometry_drift is None
    true_s = log.truth["odometry_drift"][0]
    # white GPS (2.5 m) on 2 x 121 fixes along 120 m legs fixes the scale to about
    # 2.5 / sqrt(242 * 120^2 / 12) = 0.46 % (the slope of a line fit, hand computation):
    # recovered within 3 sigma, where dead reckoning is off by the whole > 2 %
    assert abs(res.odometry_drift[-1, 0] - true_s) < 3 * 0.0046 < abs(true_s)

    def hrmse(r):
        d = r.keyframe_xyz[:, :2] - log.truth["xyz"][:, :2]
        return float(np.sqrt(np.mean(np.sum(d**2, axis=1))))

    assert hrmse(res) < 0.7 * hrmse(folded)
    # marginals with the (pose, drift) keyframe layout against gtsam.Marginals
    m = gtsam.Marginals(res.graph, res.estimate)
    L = gtsam.symbol_shorthand.L
    for j in np.linspace(0, res.n_landmarks - 1, 4).astype(int):
        ref = m.marginalCovariance(L(int(res.landmark_id[j])))
        np.testing.assert_allclose(res.landmark_cov[j], ref, rtol=1e-3, atol=1e-4)
