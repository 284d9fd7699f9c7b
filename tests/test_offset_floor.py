"""factorgraph.evaluate.offset_floor / gls_offset_sd: the exact GLS accuracy floor of a
constant position offset from Gauss-Markov-biased GPS fixes. Every reference value names where
it comes from."""

from __future__ import annotations

import math

import numpy as np
import pytest

from factorgraph.evaluate import (
    bias_floor,
    frame_floor,
    gls_offset_sd,
    horizontal_floor,
    offset_floor,
)
from factorgraph.sensors import GPSModel
from terrain.errors import InputError


def _kalman_offset_sd(t, sigma_b, tau, sigma_white, prior_sd=1e4):
    """Independent reference: a Kalman filter on the state (p0, b) with a diffuse prior on p0
    (sd ``prior_sd``); p0 is constant, so its filtered variance after the last fix is its
    variance given every fix. O(n) and any spacing (dropouts included)."""
    P = np.diag([prior_sd**2, sigma_b**2])
    H = np.array([1.0, 1.0])
    for i, ti in enumerate(t):
        if i > 0:
            phi = math.exp(-(ti - t[i - 1]) / tau)
            F = np.diag([1.0, phi])
            P = F @ P @ F.T + np.diag([0.0, sigma_b**2 * (1 - phi * phi)])
        g = P @ H / (H @ P @ H + sigma_white**2)
        P = P - np.outer(g, H @ P)
    return math.sqrt(P[0, 0])


def _dense_cov_factor(t, sigma_b, tau, sigma_white):
    """Independent reference: Cholesky factor of the full n x n covariance
    ``sigma_b^2 exp(-|t_i - t_j| / tau) + sigma_white^2 I``."""
    from scipy.linalg import cho_factor

    C = sigma_b**2 * np.exp(-np.abs(t[:, None] - t[None, :]) / tau)
    C[np.diag_indices_from(C)] += sigma_white**2
    return cho_factor(C, lower=True)


def test_white_noise_only_is_sigma_over_root_n():
    """(a) sigma_b = 0: the fixes are iid, the mean is the best estimate, sd = sigma_white /
    sqrt(n) per axis (hand computation); horizontal: sqrt(2) times that."""
    t = np.arange(600.0)
    g = GPSModel(sigma_white_m=(2.5, 2.0, 3.0), bias_sigma_m=(0.0, 0.0, 0.0))
    ref = np.array([2.5, 2.0, 3.0]) / math.sqrt(600)
    np.testing.assert_allclose(offset_floor(g, t, axes=True), ref, rtol=1e-12)
    assert offset_floor(g, t) == pytest.approx(math.hypot(2.5, 2.0) / math.sqrt(600), rel=1e-12)
    # the Cholesky path gives the same when the bias is negligible but not zero
    assert gls_offset_sd(t, 1e-6, 60.0, 2.5) == pytest.approx(2.5 / math.sqrt(600), rel=1e-9)


def test_long_record_limit():
    """(b) T >> tau: var -> (S_b(0) + S_v(0)) / T per axis, the spectral densities at zero
    frequency: 2 sigma_b^2 tau for the Gauss-Markov bias, sigma_v^2 dt for white noise sampled
    every dt (for the mean, GLS and the plain average share this limit). tau = 10 s, T = 200
    tau: the finite-record correction is ~T / (T + 2 tau), 0.5 % on the sd."""
    sb, tau, sv, dt, T = 2.5, 10.0, 2.5, 1.0, 2000.0
    t = np.arange(0.0, T + dt / 2, dt)
    approx = math.sqrt((2 * sb**2 * tau + sv**2 * dt) / T)
    assert gls_offset_sd(t, sb, tau, sv) == pytest.approx(approx, rel=0.03)
    g = GPSModel(sigma_white_m=(sv,) * 3, bias_sigma_m=(sb,) * 3, bias_tau_s=tau)
    assert offset_floor(g, t) == pytest.approx(math.sqrt(2) * approx, rel=0.03)


def test_no_white_noise_ar1_closed_form():
    """sigma_white = 0, fixes every dt: the bias samples are AR(1) with phi = exp(-dt/tau), whose
    precision matrix is tridiagonal, (1/(sigma_b^2 (1 - phi^2))) [1, -phi; -phi, 1 + phi^2,
    -phi; ...; -phi, 1]. Summing its entries (hand derivation): 1^T Q 1 = (n (1 - phi) + 2 phi)
    / (sigma_b^2 (1 + phi)), so var = sigma_b^2 (1 + phi) / (n (1 - phi) + 2 phi)."""
    sb, tau, dt = 2.5, 60.0, 1.0
    for n in (1, 2, 61, 601):
        phi = math.exp(-dt / tau)
        ref = sb * math.sqrt((1 + phi) / (n * (1 - phi) + 2 * phi))
        assert gls_offset_sd(np.arange(n) * dt, sb, tau, 0.0) == pytest.approx(ref, rel=1e-9)


def test_below_time_average_without_white_noise():
    """(c) Asked: is the exact floor >= bias_floor (time average of the bias, no white noise)?
    It is not: with sigma_white = 0 the GLS weighting (more weight at the ends of the record)
    beats the plain time average, e.g. T = tau: 2/3 sigma_b^2 (continuous-record GLS, 2 tau /
    (T + 2 tau)) against 2/e = 0.736 sigma_b^2 (bias_floor's docstring formula). So the exact
    floor is the lower one; with the white noise added it can land on either side (default GPS,
    T = 600 s at 1 Hz: 1.460 m against horizontal_floor's 1.500 m)."""
    sb, tau = 2.5, 60.0
    for T in (1.0, 10.0, 60.0, 120.0, 600.0, 1800.0):
        t = np.arange(0.0, T + 0.5)
        gls = gls_offset_sd(t, sb, tau, 0.0)
        assert gls <= bias_floor(sb, tau, T) * (1 + 1e-12)
    gls = gls_offset_sd(np.linspace(0.0, tau, 1201), sb, tau, 0.0)  # near-continuous record
    assert gls**2 == pytest.approx(sb**2 * 2 / 3, rel=1e-4)
    assert bias_floor(sb, tau, tau) ** 2 == pytest.approx(sb**2 * 2 / math.e, rel=1e-12)
    # with white noise (default GPS, 10 min at 1 Hz): below the floor by ~3 %
    g = GPSModel()
    assert offset_floor(g, np.arange(601.0)) == pytest.approx(1.4595, abs=1e-3)
    assert horizontal_floor(g, 600.0) == pytest.approx(1.5000, abs=1e-3)


def test_matches_kalman_filter_with_dropouts():
    """Independent algorithm (O(n) Kalman filter, diffuse prior on p0) on an uneven record:
    1 Hz with two outages and a 0.5 s burst."""
    t = np.arange(300.0)
    t = np.concatenate([t[(t < 80) | (t >= 150)], [151.5, 152.5]])
    t = np.sort(t[(t < 220) | (t >= 231)])
    for sb, tau, sv in ((2.5, 60.0, 2.5), (1.5, 20.0, 0.5), (3.0, 300.0, 4.0)):
        assert gls_offset_sd(t, sb, tau, sv) == pytest.approx(
            _kalman_offset_sd(t, sb, tau, sv), rel=1e-6
        )


def test_dropouts_never_lower_the_floor():
    """(d) Fewer fixes carry less information (the GLS precision 1^T C^-1 1 of a subset is at
    most that of the whole): every outage, nested outages and random thinning raise the floor
    or leave it."""
    g = GPSModel()
    full = np.arange(601.0)
    base = offset_floor(g, full)
    prev = base
    for width in (10.0, 60.0, 180.0, 300.0):  # growing outage centred on the traverse
        t = full[(full < 300 - width / 2) | (full >= 300 + width / 2)]
        f = offset_floor(g, t)
        assert f >= prev * (1 - 1e-12)
        prev = f
    assert prev > base * 1.01  # a 300 s outage out of 600 s costs visibly
    rng = np.random.default_rng(0)
    for _ in range(20):
        keep = np.sort(rng.choice(full.size, size=rng.integers(1, full.size), replace=False))
        sub = keep[rng.random(keep.size) < 0.7] if keep.size > 1 else keep
        if sub.size == 0:
            continue
        assert offset_floor(g, full[keep]) >= base * (1 - 1e-12)
        assert offset_floor(g, full[sub]) >= offset_floor(g, full[keep]) * (1 - 1e-12)


def test_axes_order_and_bad_input():
    g = GPSModel(sigma_white_m=(1.0, 2.0, 3.0), bias_sigma_m=(0.5, 1.0, 1.5))
    t = np.arange(100.0)
    ax = offset_floor(g, t, axes=True)
    assert ax.shape == (3,) and ax[0] < ax[1] < ax[2]
    assert offset_floor(g, t) == pytest.approx(math.hypot(ax[0], ax[1]), rel=1e-12)
    assert gls_offset_sd(t, 0.0, 60.0, 0.0) == 0.0
    with pytest.raises(InputError, match="fix_times_s"):
        offset_floor(g, np.array([]))
    with pytest.raises(InputError, match="fix_times_s"):
        offset_floor(g, np.array([0.0, np.nan]))
    with pytest.raises(InputError, match="gps_model"):
        offset_floor({"bias_sigma_m": 1.0}, t)
    with pytest.raises(InputError, match="tau_s"):
        gls_offset_sd(t, 1.0, 0.0, 1.0)
    with pytest.raises(InputError, match="sigma_white"):
        gls_offset_sd(t, 1.0, 60.0, -1.0)


# ------------------------------------------------------------------------------ frame_floor


def _line(n: int, step: float = 1.0) -> np.ndarray:
    """n points along east, equally spaced, centred on the origin (m)."""
    x = (np.arange(n) - (n - 1) / 2) * step
    return np.stack([x, np.zeros(n)], axis=1)


def test_frame_floor_without_heading_or_scale_is_the_offset_floor():
    """Only the offset estimated: the same GLS problem as offset_floor, on any path."""
    g = GPSModel()
    t = np.arange(601.0)
    rng = np.random.default_rng(3)
    xy = np.cumsum(rng.normal(size=(t.size, 2)), axis=0)
    f = frame_floor(g, t, xy, heading=False, scale_sigma=0.0)
    assert f == pytest.approx(offset_floor(g, t), rel=1e-10)


def test_frame_floor_with_different_noise_per_axis_matches_a_dense_solve():
    """East and north with their own noise (two filter passes) against J^T C^-1 J summed
    from dense Cholesky solves per axis, on an L-shaped path where yaw couples the axes."""
    from scipy.linalg import cho_solve

    from factorgraph.evaluate import _frame_jacobians

    g = GPSModel(sigma_white_m=(2.5, 1.5, 3.0), bias_sigma_m=(2.5, 1.0, 2.5))
    t = np.arange(400.0)
    xy = np.concatenate([_line(250, 1.0), np.stack([np.full(150, 124.5), -np.arange(150.0)], 1)])
    je, jn = _frame_jacobians(xy - xy.mean(axis=0), 3)
    info = sum(
        j.T @ cho_solve(_dense_cov_factor(t, sb, 60.0, sv), j)
        for j, sb, sv in ((je, 2.5, 2.5), (jn, 1.0, 1.5))
    )
    cov = np.linalg.inv(info)
    ref = math.sqrt(
        np.mean(np.einsum("ki,ij,kj->k", je, cov, je) + np.einsum("ki,ij,kj->k", jn, cov, jn))
    )
    assert frame_floor(g, t, xy) == pytest.approx(ref, rel=1e-9)


def test_frame_floor_straight_line_white_noise_hand_values():
    """White noise sigma, n points on a line along east, symmetric about the centre. Hand
    computation: the east error is a mean (sigma^2 / n); with a yaw, north is a straight-line
    regression whose fitted-value variance sigma^2 (1/n + x^2 / sum x^2) averages to
    2 sigma^2 / n over the same points, so the floor is sigma sqrt(3 / n); a free scale makes
    east a regression too: sigma sqrt(4 / n)."""
    s, n = 2.0, 101
    g = GPSModel(sigma_white_m=(s, s, s), bias_sigma_m=(0.0, 0.0, 0.0))
    t, xy = np.arange(float(n)), _line(n, 3.0)
    assert frame_floor(g, t, xy, heading=True) == pytest.approx(s * math.sqrt(3 / n), rel=1e-10)
    free = frame_floor(g, t, xy, heading=True, scale_sigma=math.inf)
    assert free == pytest.approx(s * math.sqrt(4 / n), rel=1e-10)


def test_frame_floor_grows_with_each_unknown_and_is_isotropic():
    """Each parameter added can only raise the floor; a tighter scale prior lowers it; with
    equal noise on both axes, turning the whole path leaves it unchanged."""
    g = GPSModel()
    t = np.arange(621.0)
    xy = np.concatenate([_line(290, 1.0), _line(331, 1.0)[::-1] + [0.0, -40.0]])[: t.size]
    chain = [
        frame_floor(g, t, xy, heading=False),
        frame_floor(g, t, xy, heading=True),
        frame_floor(g, t, xy, heading=True, scale_sigma=0.002),
        frame_floor(g, t, xy, heading=True, scale_sigma=0.01),
        frame_floor(g, t, xy, heading=True, scale_sigma=math.inf),
    ]
    assert all(b > a for a, b in zip(chain, chain[1:], strict=False))
    c, s = math.cos(0.7), math.sin(0.7)
    turned = xy @ np.array([[c, s], [-s, c]]) + [500.0, -200.0]
    assert frame_floor(g, t, turned, scale_sigma=0.01) == pytest.approx(chain[3], rel=1e-9)


def test_frame_floor_bad_input():
    g = GPSModel()
    t = np.arange(10.0)
    with pytest.raises(InputError, match="fix_xy"):
        frame_floor(g, t, np.zeros((9, 2)))
    with pytest.raises(InputError, match="path_xy"):
        frame_floor(g, t, _line(10), path_xy=np.zeros((0, 2)))
    with pytest.raises(InputError, match="scale_sigma"):
        frame_floor(g, t, _line(10), scale_sigma=-0.01)
    with pytest.raises(InputError, match="fix_xy"):
        frame_floor(g, t, np.where(np.arange(10)[:, None] == 3, np.nan, _line(10)))


def test_frame_floor_kalman_information_matches_cholesky():
    """The O(n) Kalman accumulation of J^T C^-1 J against the dense Cholesky solve, on
    irregular times (dropouts) and random columns."""
    from scipy.linalg import cho_solve

    from factorgraph.evaluate import _gm_information

    rng = np.random.default_rng(0)
    t = np.sort(rng.uniform(0.0, 900.0, 500))
    jac = rng.normal(size=(500, 4))
    for sb, tau, sv in ((2.5, 60.0, 2.5), (1.0, 5.0, 0.3), (0.0, 60.0, 1.0)):
        ref = jac.T @ cho_solve(_dense_cov_factor(t, sb, tau, sv), jac)
        got = _gm_information(t[::-1].copy(), jac[::-1].copy(), sb, tau, sv)  # any order
        np.testing.assert_allclose(got, ref, rtol=1e-10, atol=1e-12 * np.abs(ref).max())


def test_frame_floor_stationary_rover_is_the_offset_floor():
    """No extent: yaw and scale move nothing, so they cost nothing (pseudo-inverse)."""
    g = GPSModel()
    t = np.arange(300.0)
    xy = np.tile([[526000.0, 6475000.0]], (t.size, 1))
    assert frame_floor(g, t, xy) == pytest.approx(offset_floor(g, t), rel=1e-9)


def test_frame_floor_is_the_monte_carlo_error_of_the_frame_fit():
    """Independent check of the formula: draw Gauss-Markov biases by their exact AR(1)
    recursion, white noise, and a scale error from its prior; fit offset, yaw and scale by
    GLS; the RMS error over the path across draws matches the floor (Monte Carlo, 400 draws:
    the mean square has ~5 % sampling error)."""
    from scipy.linalg import cho_solve

    from factorgraph.evaluate import _frame_jacobians

    sb, sv, tau, s_scale = 2.5, 2.5, 60.0, 0.01
    g = GPSModel(sigma_white_m=(sv, sv, sv), bias_sigma_m=(sb, sb, sb), bias_tau_s=tau)
    t = np.arange(621.0)
    xy = np.concatenate([_line(290, 1.0), _line(331, 1.0)[::-1] + [0.0, -40.0]])[: t.size]
    d = xy - xy.mean(axis=0)
    je, jn = _frame_jacobians(d, 4)
    cf = _dense_cov_factor(t, sb, tau, sv)
    info = je.T @ cho_solve(cf, je) + jn.T @ cho_solve(cf, jn) + np.diag([0, 0, 0, s_scale**-2])
    rng = np.random.default_rng(7)
    phi = math.exp(-1.0 / tau)
    sq = []
    for _ in range(400):
        theta = np.array([0.0, 0.0, 0.0, rng.normal(0.0, s_scale)])
        noise = np.empty((2, t.size))
        noise[:, 0] = rng.normal(0.0, sb, 2)
        for i in range(1, t.size):
            noise[:, i] = phi * noise[:, i - 1] + rng.normal(0.0, sb * math.sqrt(1 - phi * phi), 2)
        ye = je @ theta + noise[0] + rng.normal(0.0, sv, t.size)
        yn = jn @ theta + noise[1] + rng.normal(0.0, sv, t.size)
        est = np.linalg.solve(info, je.T @ cho_solve(cf, ye) + jn.T @ cho_solve(cf, yn))
        err = est - theta
        sq.append(np.mean((je @ err) ** 2 + (jn @ err) ** 2))
    floor = frame_floor(g, t, xy, scale_sigma=s_scale)
    assert math.sqrt(np.mean(sq)) == pytest.approx(floor, rel=0.06)
