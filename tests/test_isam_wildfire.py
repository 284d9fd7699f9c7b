"""iSAM2's wildfire threshold (``LocalizeParams.wildfire_threshold``): what localize reads each
step is exact at any threshold, and only a full back-substitution gives the final estimate.

Reference: the same updates with threshold 0 (GTSAM solves every clique afresh each step)
and ``calculateBestEstimate`` (a full back-substitution)."""

from __future__ import annotations

import numpy as np
import pytest

from factorgraph.isam2 import isam2_params
from factorgraph.localize import LocalizeParams
from terrain.errors import InputError

gtsam = pytest.importorskip("gtsam")
X = gtsam.symbol_shorthand.X


def _drive(threshold: float, steps: int = 250, seed: int = 0):
    """A 1 m-per-step straight drive with noisy odometry and a GPS fix every step (Pose3,
    metres / radians). Returns (newest pose read after each update, the iSAM2 object)."""
    rng = np.random.default_rng(seed)
    isam = gtsam.ISAM2(isam2_params(LocalizeParams(wildfire_threshold=threshold)))
    odo_noise = gtsam.noiseModel.Diagonal.Sigmas(np.r_[np.full(3, 1e-3), np.full(3, 0.05)])
    gps_noise = gtsam.noiseModel.Isotropic.Sigma(3, 2.0)
    prior = gtsam.noiseModel.Diagonal.Sigmas(np.r_[np.full(3, 0.01), np.full(3, 5.0)])
    step = gtsam.Pose3(gtsam.Rot3(), np.array([1.0, 0.0, 0.0]))
    newest, guess = [], gtsam.Pose3()
    for k in range(steps):
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        if k == 0:
            graph.add(gtsam.PriorFactorPose3(X(0), gtsam.Pose3(), prior))
        else:
            noisy = step.compose(gtsam.Pose3.Expmap(rng.normal(0, [1e-3] * 3 + [0.05] * 3)))
            graph.add(gtsam.BetweenFactorPose3(X(k - 1), X(k), noisy, odo_noise))
            guess = newest[-1].compose(noisy)
        graph.add(gtsam.GPSFactor(X(k), np.array([k, 0, 0]) + rng.normal(0, 2.0, 3), gps_noise))
        values.insert(X(k), guess)
        isam.update(graph, values)
        newest.append(isam.calculateEstimatePose3(X(k)))
    return newest, isam


def _xyz(values, steps):
    return np.array([values.atPose3(X(k)).translation() for k in range(steps)])


def test_newest_pose_is_exact_and_the_final_estimate_is_a_full_solve():
    exact, isam0 = _drive(0.0)
    full = _xyz(isam0.calculateBestEstimate(), 250)
    lag = {}
    for threshold in (LocalizeParams().wildfire_threshold, 1e9):
        fast, isam = _drive(threshold)
        online = np.array([p.translation() for p in fast])
        np.testing.assert_allclose(online, [p.translation() for p in exact], rtol=0, atol=1e-9)
        # read before the full solve, which also refreshes the deltas calculateEstimate reads
        lag[threshold] = np.abs(_xyz(isam.calculateEstimate(), 250) - full).max()
        np.testing.assert_allclose(_xyz(isam.calculateBestEstimate(), 250), full, atol=1e-9)
    # what the full solve is there for: without it the older poses' deltas lag behind
    assert lag[1e9] > 1e-3, lag


def test_wildfire_threshold_must_be_non_negative():
    with pytest.raises(InputError, match="wildfire_threshold"):
        LocalizeParams(wildfire_threshold=-1.0)
