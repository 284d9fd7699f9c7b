"""Held-out residuals from local planes through same-fold neighbours
(terrain.heldout_local_fit).

Reference values and their origin:
- The intercept weights of a least-squares plane reproduce any plane exactly:
  sum a = 1, sum a dx = 0, sum a dy = 0 (normal equations; hand).
- With independent noise of variance s^2, the plane's value at a sample carries
  sum a^2 s^2 of it (variance of a linear combination; hand), so the returned noise variance
  must match the empirical variance of (plane - truth) over many samples.
- A calibrated map (errors N(0, sigma_f^2) with sigma_f stated) covers 2 Phi(1) - 1 = 0.683
  of its errors at +-1 sigma (standard normal table).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from terrain import ElevationSamples, cross_validate
from terrain.heldout_local_fit import (
    NEIGHBOURS,
    Q_TOLERANCE,
    _plane_weights,
    local_plane_residuals,
)

NOISE = 0.2  # m


def _scatter(n: int, side: float, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).uniform(0.0, side, (n, 2))


def _folds(xy: np.ndarray, block: float = 10.0, n_folds: int = 5) -> np.ndarray:
    """Checkerboard-like deal of square blocks to folds."""
    bx, by = np.floor(xy[:, 0] / block), np.floor(xy[:, 1] / block)
    return ((bx + 3 * by) % n_folds).astype(np.int64)


def _smooth_error(xy: np.ndarray, sd: float, seed: int) -> np.ndarray:
    """A smooth map error: 24 random-phase plane waves (wavelengths 15-40 m), sd ``sd``."""
    rng = np.random.default_rng(seed)
    k = 2 * np.pi / rng.uniform(15.0, 40.0, 24)
    ang = rng.uniform(0.0, np.pi, 24)
    phase = rng.uniform(0.0, 2 * np.pi, 24)
    arg = np.outer(xy[:, 0], k * np.cos(ang)) + np.outer(xy[:, 1], k * np.sin(ang)) + phase
    return sd * math.sqrt(2.0 / 24) * np.cos(arg).sum(axis=1)


def test_plane_weights_reproduce_planes_and_stay_in_the_fold():
    xy = _scatter(3000, 50.0, 0)
    fold = _folds(xy)
    a, b, nbr = _plane_weights(xy, fold, radius=2.0)
    fitted = np.abs(a.sum(axis=1) - 1.0) < 1e-9
    assert fitted.mean() > 0.9
    d = xy[nbr] - xy[:, None, :]
    np.testing.assert_allclose(np.sum(a * d[..., 0], axis=1)[fitted], 0.0, atol=1e-9)
    np.testing.assert_allclose(np.sum(a * d[..., 1], axis=1)[fitted], 0.0, atol=1e-9)
    on = a != 0.0
    assert np.all(fold[nbr][on] == np.broadcast_to(fold[:, None], on.shape)[on])
    assert np.all(np.hypot(d[..., 0], d[..., 1])[on] <= 2.0 + 1e-12)
    assert a.shape[1] == NEIGHBOURS
    # leaving the sample out gives it no weight
    own = nbr == np.arange(xy.shape[0])[:, None]
    assert np.all(b[own] == 0.0)


def test_independent_noise_is_averaged_and_its_variance_stated():
    xy = _scatter(20000, 100.0, 1)
    rng = np.random.default_rng(2)
    truth = 3.0 + 0.2 * xy[:, 0] + 2.0 * np.sin(xy[:, 1] / 30.0)  # smooth at a few metres
    z = truth + rng.normal(0.0, NOISE, xy.shape[0])
    mu = truth  # a perfect map: the residual is noise only
    fold = _folds(xy)
    w = np.ones(xy.shape[0])
    resid, noise, info = local_plane_residuals(xy, z, mu, np.full(xy.shape[0], NOISE**2), fold, w)
    assert info["local_fit_used"], info["local_fit_rule"]
    assert abs(info["local_fit_q"] - 1.0) < 0.05
    assert info["local_fit_share"] > 0.8
    assert info["local_fit_noise_kept"] < 0.35  # a third of one sample's noise or less
    used = noise < NOISE**2
    # the variance the residuals carry is the one stated (hand: sum a^2 s^2)
    assert np.mean(resid[used] ** 2) / np.mean(noise[used]) == pytest.approx(1.0, abs=0.04)
    # samples without a fit keep their own residual and noise
    np.testing.assert_array_equal(resid[~used], (z - mu)[~used])


def test_noise_shared_between_neighbours_is_not_averaged():
    """A rover's neighbouring samples share their positioning error: here a smooth noise
    field (sd 0.2 m, wavelengths 15-40 m), which a plane through neighbours keeps whole."""
    xy = _scatter(12000, 100.0, 3)
    shared = _smooth_error(xy, NOISE, 4)
    z = shared + np.random.default_rng(5).normal(0.0, 0.02, xy.shape[0])
    nv = np.full(xy.shape[0], NOISE**2)
    resid, noise, info = local_plane_residuals(
        xy, z, np.zeros(xy.shape[0]), nv, _folds(xy), np.ones(xy.shape[0])
    )
    assert not info["local_fit_used"]
    assert info["local_fit_q"] < 1.0 - Q_TOLERANCE
    assert "share their noise" in info["local_fit_rule"]
    np.testing.assert_array_equal(resid, z)
    np.testing.assert_array_equal(noise, nv)


def test_ground_rougher_than_a_plane_at_the_radius_is_not_averaged():
    xy = _scatter(12000, 100.0, 6)
    rough = 0.5 * np.sin(2 * np.pi * xy[:, 0] / 3.0)  # 3 m ripples, 0.5 m amplitude
    z = rough + np.random.default_rng(7).normal(0.0, NOISE, xy.shape[0])
    resid, _, info = local_plane_residuals(
        xy, z, np.zeros(xy.shape[0]), np.full(xy.shape[0], NOISE**2), _folds(xy), np.ones(12000)
    )
    assert not info["local_fit_used"]
    assert info["local_fit_q"] > 1.0 + Q_TOLERANCE
    assert "rougher" in info["local_fit_rule"]
    np.testing.assert_array_equal(resid, z)


def test_samples_without_neighbours_keep_their_residuals():
    xy = _scatter(10, 100.0, 8)
    z = np.arange(10.0)
    fold = np.arange(10)  # every sample alone in its fold
    resid, noise, info = local_plane_residuals(
        xy, z, np.zeros(10), np.full(10, 0.04), fold, np.ones(10)
    )
    assert not info["local_fit_used"] and info["local_fit_share"] == 0.0
    assert "no held-out sample has neighbours" in info["local_fit_rule"]
    np.testing.assert_array_equal(resid, z)


class _ErrorMap:
    """A map whose error at x is a known smooth field, with a calibrated stated 1-sigma."""

    sd = 0.05  # m: the map's error is a quarter of one sample's noise

    def fit(self, samples):
        self.nugget_ = 0.0
        return self

    def predict(self, xy, return_std=False, include_nugget=False):
        mu = _smooth_error(np.asarray(xy), self.sd, 11)
        return (mu, np.full(len(xy), self.sd)) if return_std else mu


def test_cross_validate_reads_a_noise_dominated_map_through_local_planes():
    """Noise is 94 % of a held-out residual's variance. The map's true coverage at the
    held-out samples is the fraction of |error| <= sd (~0.683 for Gaussian-like errors);
    the check, through local planes, reads it within 4 points and reports how."""
    xy = _scatter(15000, 100.0, 9)
    z = np.random.default_rng(10).normal(0.0, NOISE, xy.shape[0])  # truth is 0 m
    samples = ElevationSamples(xy, z, NOISE**2)
    cv = cross_validate(_ErrorMap(), samples, block_size=12.0, seed=0)
    p = cv.pooled
    err = _smooth_error(xy, _ErrorMap.sd, 11)
    truth68 = float(np.mean(np.abs(err) <= _ErrorMap.sd))
    assert p["local_fit_used"], p["local_fit_rule"]
    assert p["local_fit_noise_kept"] < 0.75  # weighted to the far samples (fewer neighbours)
    assert p["noise_share"] < 0.04 / 0.0425 - 0.02  # the single samples': 0.94
    assert abs(p["map_coverage_68"] - truth68) <= 0.04
    for key in ("local_fit_share", "local_fit_radius_m", "local_fit_q", "local_fit_rule"):
        assert key in p
    # the measurement-level scores stay those of the single held-out samples
    assert p["rmse_m"] == pytest.approx(float(np.sqrt(np.mean((z - err) ** 2))), rel=1e-9)


def test_the_verdict_says_when_local_planes_were_read():
    from terrain.heldout_verdict import coverage_verdict

    pooled = {
        "map_coverage_68": 0.55,
        "map_coverage_68_interval": [0.50, 0.60],  # excludes nominal
        "map_coverage_95": 0.95,
        "map_coverage_95_interval": [0.94, 0.96],
        "noise_share": 0.5,
    }
    (plain,) = coverage_verdict(pooled)
    (planes,) = coverage_verdict({**pooled, "local_fit_used": True})
    assert "(held-out, noise removed)" in plain
    assert "(held-out, local planes, noise removed)" in planes
    assert planes.endswith("the map's 1-sigma is too small")
