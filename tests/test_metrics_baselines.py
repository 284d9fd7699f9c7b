import numpy as np
import pytest

from terrain import CRSMismatchError, ElevationSamples, Grid, InputError
from terrain.baselines import delaunay_linear
from terrain.metrics import (
    calibration_curve,
    evaluate,
    interval_coverage,
    nlpd,
    rmse,
    standardized_error_stats,
)


def test_metrics_hand_computed():
    pred = np.array([1.0, 2.0, 3.0, np.nan])
    truth = np.array([1.0, 4.0, 2.0, 7.0])
    std = np.array([1.0, 1.0, 2.0, 1.0])
    # errors 0, -2, 1 -> RMSE sqrt(5/3), MAE 1, max 2; 3 of 4 cells covered
    out = evaluate(pred, truth, std)
    assert out["rmse"] == pytest.approx(np.sqrt(5 / 3))
    assert out["mae"] == pytest.approx(1.0) and out["max_abs_error"] == 2.0
    assert out["covered_fraction"] == 0.75
    # |err|/std = 0, 2, 0.5 -> inside 1 sigma: 2/3; inside 1.96 sigma: 2/3
    assert out["coverage_68"] == pytest.approx(2 / 3)
    assert interval_coverage(pred, std, truth, z=2.0) == pytest.approx(1.0)
    # z = (truth - pred)/std = 0, 2, -0.5 -> mean 0.5, population std sqrt(((.5)^2+1.5^2+1^2)/3)
    zm, zs = standardized_error_stats(pred, std, truth)
    assert zm == pytest.approx(0.5) and zs == pytest.approx(np.sqrt((0.25 + 2.25 + 1.0) / 3))
    # NLPD: mean of 0.5 log(2 pi s^2) + 0.5 z^2
    ref = np.mean(0.5 * np.log(2 * np.pi * np.array([1, 1, 4.0])) + 0.5 * np.array([0, 4, 0.25]))
    assert nlpd(pred, std, truth) == pytest.approx(ref)
    with pytest.raises(InputError, match="shape"):
        rmse(pred, truth[:2])


def test_calibration_curve_on_exact_gaussian_errors():
    # Errors drawn from N(0, std^2): observed coverage equals nominal up to sampling noise
    # (binomial sd <= 0.5 / sqrt(200000) ~ 0.0011).
    rng = np.random.default_rng(0)
    std = rng.uniform(0.1, 2.0, 200_000)
    truth = rng.normal(0.0, std)
    levels, observed = calibration_curve(np.zeros_like(std), std, truth)
    np.testing.assert_allclose(observed, levels, atol=0.006)
    # Over-confident std (half the truth) covers far less than nominal at 95 %.
    _, over = calibration_curve(np.zeros_like(std), std / 2, truth, levels=[0.95])
    # Hand computation: P(|Z| <= 1.95996 / 2) = 2 Phi(0.97998) - 1 = 0.67290
    assert over[0] == pytest.approx(0.6729, abs=0.006)
    with pytest.raises(InputError, match="levels"):
        calibration_curve([0.0], [1.0], [0.0], levels=[1.0])


def test_delaunay_reproduces_plane_inside_hull_nan_outside():
    grid = Grid.from_bounds((0, 0, 100, 100), 5.0)
    xy = np.array([[20, 20], [80, 20], [80, 80], [20, 80], [50, 50.0]])
    plane = lambda p: 3.0 + 0.1 * p[:, 0] - 0.05 * p[:, 1]  # noqa: E731
    ds = delaunay_linear(ElevationSamples(xy, plane(xy)), grid)
    z = ds["elevation"].values.ravel()
    inside = np.isfinite(z)
    np.testing.assert_allclose(z[inside], plane(grid.xy()[inside]), atol=1e-9)
    # Hull is the square [20, 80]^2 -> 12 x 12 cell centres of 20 x 20 (cells 22.5..77.5)
    assert inside.sum() == 144 and ds.attrs["covered_fraction"] == pytest.approx(144 / 400)


def test_delaunay_bad_input():
    grid = Grid.from_bounds((0, 0, 10, 10), 1.0)
    with pytest.raises(InputError, match="not collinear"):
        delaunay_linear(ElevationSamples([[0, 0], [1, 1], [2, 2]], [1, 2, 3]), grid)
    with pytest.raises(CRSMismatchError):
        delaunay_linear(ElevationSamples([[0, 0], [1, 0], [0, 1]], [1, 2, 3], crs=32607), grid)
