"""Baselines (GPS only, dead reckoning, the paper's particle filter) and the scores of
factorgraph.evaluate. Every reference value names where it comes from."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from factorgraph.baselines import gps_only, odometry_only, particle_filter
from factorgraph.evaluate import bias_floor, horizontal_floor, horizontal_rmse, nees
from factorgraph.sensors import CameraModel, GPSModel, OdometryModel, SensorSuite
from factorgraph.simulate import simulate_traverse
from terrain.errors import InputError
from terrain.synthetic import default_site

W, N = 526000.0, 6475600.0
STRAIGHT = np.array([[W + 20, N - 75], [W + 320, N - 75]])  # 300 m, 301 keyframes at 1 m/s
TEN_MIN = np.array([[W + 20, N - 50], [W + 580, N - 50], [W + 580, N - 90]])  # 600 m, 600 s
NO_CAMERA = CameraModel(texture_density_per_m2=0.0)  # no features: fast simulation
WHITE_GPS = GPSModel(bias_sigma_m=(0.0, 0.0, 0.0))


@pytest.fixture(scope="module")
def dem():
    return default_site(2.0)


def _log(dem, wp, seed=0, **kw):
    return simulate_traverse(dem, wp, SensorSuite(camera=NO_CAMERA, **kw), seed=seed)


# ---------------------------------------------------------------- evaluate.py


def test_bias_floor_matches_monte_carlo():
    """Reference: 4000 simulated stationary Gauss-Markov sequences (exact AR(1) discretisation
    at dt = 0.05 s, trapezoid time average); MC standard error of the std is ~1.1 %. At
    T = 2 tau the T >> tau limit sigma sqrt(2 tau / T) is 33 % too high: the test tells them
    apart."""
    sigma, tau, T, dt, n = 2.5, 60.0, 120.0, 0.05, 4000
    rng = np.random.default_rng(7)
    phi = math.exp(-dt / tau)
    b = rng.standard_normal(n) * sigma
    total = 0.5 * b
    steps = int(round(T / dt))
    for i in range(steps):
        b = phi * b + rng.standard_normal(n) * sigma * math.sqrt(1 - phi * phi)
        total += b if i < steps - 1 else 0.5 * b
    mc = float(np.std(total * dt / T))
    assert mc == pytest.approx(bias_floor(sigma, tau, T), rel=0.05)
    assert abs(sigma * math.sqrt(2 * tau / T) / mc - 1) > 0.2


def test_bias_floor_limits_and_hand_value():
    s, tau = 2.5, 60.0
    # T >> tau: sigma sqrt(2 tau / T) (docstring limit); T << tau: sigma (bias ~ constant)
    assert bias_floor(s, tau, 1e5 * tau) == pytest.approx(s * math.sqrt(2e-5), rel=1e-4)
    assert bias_floor(s, tau, 1e-5 * tau) == pytest.approx(s, rel=1e-4)
    # T = tau by hand: 2 (1 - (1 - e^-1)) = 2 / e
    assert bias_floor(s, tau, tau) == pytest.approx(s * math.sqrt(2 / math.e), rel=1e-12)
    with pytest.raises(InputError, match="tau_s"):
        bias_floor(s, 0.0, 100.0)


def test_horizontal_floor_combines_axes():
    # linear in sigma_b: sqrt(3^2 + 4^2) = 5 times the unit floor (hand computation)
    g = GPSModel(bias_sigma_m=(3.0, 4.0, 10.0), bias_tau_s=60.0)
    assert horizontal_floor(g, 600.0) == pytest.approx(5 * bias_floor(1.0, 60.0, 600.0))


def test_nees_and_rmse_by_hand():
    e = np.array([[1.0, 2.0, 2.0], [2.0, 1.0, 0.5], [1.0, 1.0, 0.0]])
    eye = np.broadcast_to(np.eye(3), (3, 3, 3))
    np.testing.assert_allclose(nees(e, eye), (e**2).sum(1))  # identity: squared norm
    cov = np.array([np.eye(3), np.diag([4.0, 1.0, 0.25]), [[2, 1, 0], [1, 2, 0], [0, 0, 1]]])
    # 4/4 + 1/1 + 0.25/0.25 = 3; [1 1] inv([[2 1][1 2]]) [1 1]^T = (2 - 1 - 1 + 2) / 3 = 2/3
    np.testing.assert_allclose(nees(e, cov), [9.0, 3.0, 2.0 / 3.0])
    # horizontal errors 5 m and 0 m (z ignored): sqrt(25 / 2)
    est = np.array([[3.0, 4.0, 9.0], [1.0, 1.0, 1.0]])
    true = np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 5.0]])
    assert horizontal_rmse(est, true) == pytest.approx(math.sqrt(12.5))


# ---------------------------------------------------------------- gps_only


def test_gps_only_exact_without_noise_and_interpolates(dem):
    g = GPSModel(rate_hz=0.5, sigma_white_m=(1e-6,) * 3, bias_sigma_m=(0.0, 0.0, 0.0))
    log = _log(dem, STRAIGHT, gps=g)
    tr = gps_only(log)
    truth = log.truth["xyz"]
    np.testing.assert_allclose(tr.xyz[log.gps_k], truth[log.gps_k], atol=1e-4)
    # fixes every 2 s on a straight leg: the midpoints are interpolated (horizontal exact,
    # elevation off by the DEM's curvature only)
    assert tr.params["n_interpolated"] == log.n_keyframes - log.gps_k.size > 100
    np.testing.assert_allclose(tr.xyz[:, :2], truth[:, :2], atol=1e-3)
    # white + bias variance at a fix (1e-12 m^2); allowance (1 m/s * 1 s)^2 / 2 off the fixes
    assert tr.cov_xyz[0, 0, 0] == pytest.approx(1e-12)
    assert tr.cov_xyz[1, 0, 0] == pytest.approx(0.5)


def test_gps_only_dropouts(dem):
    g = GPSModel(dropouts=((0.0, 10.0), (100.0, 160.0)))
    log = _log(dem, STRAIGHT, gps=g)
    tr = gps_only(log)
    assert tr.params["n_interpolated"] == 60  # keyframes t = 100 ... 159 s
    assert tr.params["n_extrapolated"] == 10  # t = 0 ... 9 s: first fix held flat
    np.testing.assert_array_equal(tr.xyz[:10], np.broadcast_to(log.gps_xyz[0], (10, 3)))
    a, b = log.gps_xyz[log.gps_k == 99][0], log.gps_xyz[log.gps_k == 160][0]
    np.testing.assert_allclose(tr.xyz[130], a + (130 - 99) / 61 * (b - a))  # linear in time
    # 2.5^2 + 2.5^2 plus (1 m/s * 30 s)^2 / 2 at t = 130 s, 30 s from the fix at 160 s
    assert tr.cov_xyz[130, 0, 0] == pytest.approx(12.5 + 450.0)
    assert tr.cov_xyz[130, 2, 2] == pytest.approx(12.5)


# ---------------------------------------------------------------- odometry_only


def test_odometry_only_reproduces_truth_with_tiny_noise(dem):
    od = OdometryModel(1e-7, 1e-7, 0.0, 0.0)
    exact_gps = GPSModel(sigma_white_m=(1e-6,) * 3, bias_sigma_m=(0.0, 0.0, 0.0))
    log = _log(dem, STRAIGHT, odometry=od, gps=exact_gps)
    tr = odometry_only(log)
    assert tr.params["init"] == "truth"
    assert np.abs(tr.xyz - log.truth["xyz"]).max() < 0.01  # sub-cm over 300 m
    blind = dataclasses.replace(log, truth={})  # no truth: start from the GPS alignment
    tr = odometry_only(blind)
    assert tr.params["init"] == "gps_alignment"
    # exact GPS fixes the start; the alignment is yaw-only (the 1.4 deg surface tilt at k=0
    # is unknown to it), which bends the elevation but barely the horizontal
    assert horizontal_rmse(tr.xyz, log.truth["xyz"]) < 0.05


def test_odometry_only_drifts_with_distance(dem):
    log = _log(dem, TEN_MIN, seed=1)
    err = np.linalg.norm(odometry_only(log).xyz[:, :2] - log.truth["xyz"][:, :2], axis=1)
    assert err[:50].max() < 1.0  # first 50 m from the true start
    assert err[-50:].min() > 5.0  # scale and heading drift over 600 m
    assert err[300] < err[450] < err[-1]


# ---------------------------------------------------------------- particle filter


def test_particle_filter_is_deterministic(dem):
    log = _log(dem, STRAIGHT)
    a = particle_filter(log, 300, seed=5)
    b = particle_filter(log, 300, seed=5)
    c = particle_filter(log, 300, seed=6)
    assert a.xyz.tobytes() == b.xyz.tobytes() and a.cov_xyz.tobytes() == b.cov_xyz.tobytes()
    assert a.xyz.tobytes() != c.xyz.tobytes()
    assert particle_filter(log, 1, seed=0).xyz.shape == (log.n_keyframes, 3)  # N = 1 runs


def test_particle_filter_beats_gps_with_white_gps(dem):
    log = _log(dem, TEN_MIN, gps=WHITE_GPS)
    truth = log.truth["xyz"]
    rmse_gps = horizontal_rmse(gps_only(log).xyz, truth)  # ~ sqrt(2) 2.5 = 3.5 m
    pf = particle_filter(log)
    rmse_pf = horizontal_rmse(pf.xyz, truth)
    assert rmse_pf < 0.35 * rmse_gps  # measured 0.68 m vs 3.62 m
    assert rmse_pf < horizontal_rmse(odometry_only(log).xyz, truth)
    err = pf.xyz[:, :2] - truth[:, :2]
    assert 0.5 < nees(err, pf.cov_xyz[:, :2, :2]).mean() < 4.0  # 2 dof: 2 if consistent
    assert pf.params["initial"] == "gps_alignment" and pf.params["n_resamples"] > 0
    cold = particle_filter(log, initial_pose="cold")  # uniform yaw at the first fix
    assert horizontal_rmse(cold.xyz, truth) < 0.35 * rmse_gps  # measured 0.76 m


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_particle_filter_cannot_beat_the_bias_floor(dem, seed):
    """With the default biased GPS no filter removes the traverse-mean bias: measured PF
    RMSE 2.8-6 m against a floor of 1.5 m (sigma_b 2.5 m, tau 60 s, T 600 s)."""
    log = _log(dem, TEN_MIN, seed=seed)
    truth = log.truth["xyz"]
    floor = horizontal_floor(log.sensors.gps, log.duration_s)
    mean_bias = float(np.linalg.norm(log.truth["gps_bias"][:, :2].mean(0)))
    for gps_bias in (False, True):
        pf = particle_filter(log, seed=seed, gps_bias=gps_bias)
        rmse = horizontal_rmse(pf.xyz, truth)
        assert rmse > floor and rmse > 0.8 * mean_bias
    # the bias-aware variant states its uncertainty honestly (2 dof NEES ~ 2)
    assert nees(pf.xyz[:, :2] - truth[:, :2], pf.cov_xyz[:, :2, :2]).mean() < 4.0


# ---------------------------------------------------------------- bad input


def test_bad_input(dem):
    log = _log(dem, STRAIGHT)
    for n in (0, -3, 2.5, True):
        with pytest.raises(InputError, match="n_particles"):
            particle_filter(log, n)
    with pytest.raises(InputError, match="initial_pose"):
        particle_filter(log, 10, initial_pose="warm")
    with pytest.raises(InputError, match="resample_ess"):
        particle_filter(log, 10, resample_ess=0.0)
    blind = _log(dem, STRAIGHT, gps=GPSModel(dropouts=((-1.0, 1e6),)))
    assert blind.gps_k.size == 0
    for f in (gps_only, particle_filter):
        with pytest.raises(InputError, match="gps_k"):
            f(blind)
    with pytest.raises(InputError, match="log"):
        gps_only(log.odometry)
