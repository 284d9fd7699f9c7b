"""The checkpoint bias and its standard error when the map's errors are spatially correlated."""

import numpy as np
import pytest
from scipy.spatial.distance import cdist

from toolkit.certify_bias import MIN_SPATIAL_CHECKPOINTS, bias_assessment, mean_error_variance


def _field(n, range_m, nugget_share, seed, sill=0.1, side=600.0):
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0.0, side, (n, 2))
    C = sill * np.exp(-cdist(xy, xy) / range_m) + (nugget_share * sill + 1e-10) * np.eye(n)
    return xy, np.linalg.cholesky(C), C, rng


def test_standard_error_matches_the_true_covariance():
    # Reference: Var(mean) = 1^T C 1 / n^2 of the covariance the errors were drawn from.
    xy, L, C, rng = _field(300, 40.0, 0.2, seed=3)
    true_se = np.sqrt(C.sum()) / 300
    est = [np.sqrt(mean_error_variance(L @ rng.standard_normal(300), xy)["variance_m2"])]
    est += [
        np.sqrt(mean_error_variance(L @ rng.standard_normal(300), xy)["variance_m2"])
        for _ in range(29)
    ]
    assert np.median(est) == pytest.approx(true_se, rel=0.15)
    assert true_se > 2.5 * np.sqrt(C.diagonal().mean() / 300)  # correlation matters here


def test_false_alarms_near_nominal_where_the_textbook_test_fails():
    # No bias, errors correlated over 40 m among 200 checkpoints on 600 m: the t-test that
    # assumes independent errors calls ~half the draws biased; the spatial one ~5 %.
    xy, L, _, rng = _field(200, 40.0, 0.2, seed=5)
    spatial = iid = 0
    for _ in range(120):
        b = bias_assessment(L @ rng.standard_normal(200), xy)
        spatial += b["significant"]
        iid += abs(b["t_statistic_independent"]) > 1.96
    assert spatial / 120 <= 0.12
    assert iid / 120 >= 0.3


def test_a_real_offset_is_still_found():
    xy, L, _, rng = _field(200, 40.0, 0.2, seed=7)
    found = sum(
        bias_assessment(0.25 + L @ rng.standard_normal(200), xy)["significant"] for _ in range(40)
    )
    # offset 0.25 m against a true standard error of 0.053 m (4.7 SE): 34 of 40 found when
    # written; the misses are draws whose correlated field pulls the mean error below 0.1 m
    # or whose variogram reads a long range (n_eff ~ 5)
    assert found >= 30


def test_few_checkpoints_fall_back_to_independent_errors():
    n = MIN_SPATIAL_CHECKPOINTS - 1
    err = 0.1 + 0.3 * np.tile([1.0, -1.0], n)[:n]
    xy = np.random.default_rng(0).uniform(0, 100, (n, 2))
    b = bias_assessment(err, xy)
    assert b["error_variogram"] is None and "independent" in b["standard_error_method"]
    # hand computation: SE = s / sqrt(n), s with n - 1
    assert b["standard_error_m"] == pytest.approx(err.std(ddof=1) / np.sqrt(n))
    assert b["t_statistic"] == pytest.approx(err.mean() / (err.std(ddof=1) / np.sqrt(n)))
    # Student's t with n - 1 = 28 degrees of freedom (tables: 2.048)
    assert b["t_critical"] == pytest.approx(2.048, abs=1e-3)


def test_one_checkpoint_has_no_standard_error_and_no_crash():
    b = bias_assessment(np.array([0.3]), np.array([[0.0, 0.0]]))
    assert not b["significant"] and np.isnan(b["standard_error_m"])
    assert b["error_variogram"] is None


def test_bias_against_the_maps_stated_shared_offset():
    # 40 checkpoints, bias 0.46 m, no coordinates (independent errors): SE = s / sqrt(n) =
    # 0.32 sqrt(40/39) / sqrt(40) = 0.0513 m; z = bias / sqrt(stated^2 + SE^2) by hand:
    err = 0.46 + 0.32 * np.tile([1.0, -1.0], 20)
    se = err.std(ddof=1) / np.sqrt(40)
    ok = bias_assessment(err, stated_shared_std_m=0.5)["against_stated_offset"]
    assert ok["consistent"] and ok["z"] == pytest.approx(0.46 / np.hypot(0.5, se))
    low = bias_assessment(err, stated_shared_std_m=0.05)
    assert not low["against_stated_offset"]["consistent"]
    assert low["against_stated_offset"]["z"] == pytest.approx(0.46 / np.hypot(0.05, se))
    assert "too small" in low["message"]
    assert bias_assessment(err)["against_stated_offset"] is None
