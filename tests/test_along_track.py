"""terrain.along_track: the O(n) quadratic form against a dense covariance, a hand value,
the empirical correlation and its fit.

References: the dense ``C_ij = s_i s_j exp(-|t_i - t_j| / tau)`` built directly with numpy
(no recursion); for n = 2 the hand value ``a1^2 + a2^2 + 2 a1 a2 exp(-|dt| / tau)``.
"""

from __future__ import annotations

import numpy as np
import pytest

from terrain import InputError
from terrain.along_track import (
    AlongTrackModel,
    along_track_quadratic,
    empirical_time_correlation,
    fit_along_track,
    pool_time_correlations,
)


def _dense(t, s, tau):
    return s[:, None] * s[None, :] * np.exp(-np.abs(t[:, None] - t[None, :]) / tau)


@pytest.mark.parametrize("n", [1, 2, 7, 60])
def test_quadratic_equals_dense_form(n):
    rng = np.random.default_rng(n)
    t = rng.uniform(0, 600, n)  # unsorted on purpose: the recursion sorts
    t[n // 2 :: 5] = t[0]  # ties (landmarks with the same mean time)
    s = rng.uniform(0.1, 1.0, n)
    u = rng.normal(0, 1, (n, 3))
    C = _dense(t, s, 45.0)
    got = along_track_quadratic(u, t, s, 45.0)
    assert got == pytest.approx(np.einsum("im,ij,jm->m", u, C, u), rel=1e-10, abs=1e-12)
    off = along_track_quadratic(u[:, 0], t, s, 45.0, off_diagonal=True)
    ref = u[:, 0] @ (C - np.diag(np.diag(C))) @ u[:, 0]
    assert isinstance(off, float) and off == pytest.approx(ref, rel=1e-10, abs=1e-12)


def test_quadratic_hand_value_n2():
    # u = (2, -1), s = (0.5, 1.0), t = (10, 70), tau = 60: a = (1, -1),
    # 1 + 1 + 2 * (1)(-1) * exp(-1) = 2 - 2/e = 1.2642411...
    got = along_track_quadratic(np.array([2.0, -1.0]), [70.0, 10.0][::-1], [0.5, 1.0], 60.0)
    assert got == pytest.approx(2.0 - 2.0 / np.e, rel=1e-12)
    # infinite tau: fully correlated, (sum a)^2 = 0
    assert along_track_quadratic([2.0, -1.0], [10.0, 70.0], [0.5, 1.0], np.inf) == 0.0


def test_quadratic_limits():
    n = 50
    t = np.arange(n) * 1000.0  # far apart: independent
    s = np.full(n, 0.3)
    u = np.ones(n)
    assert along_track_quadratic(u, t, s, 1.0) == pytest.approx(n * 0.09, rel=1e-12)
    assert along_track_quadratic(u, t, s, 1.0, off_diagonal=True) == pytest.approx(0.0, abs=1e-12)
    # all at one time: fully correlated
    assert along_track_quadratic(u, np.zeros(n), s, 60.0) == pytest.approx((n * 0.3) ** 2)


def test_quadratic_bad_input():
    with pytest.raises(InputError, match="t_s"):
        along_track_quadratic([1.0, 2.0], [0.0], [1.0, 1.0], 60.0)
    with pytest.raises(InputError, match="sigma_m"):
        along_track_quadratic([1.0, 2.0], [0.0, 1.0], [1.0, -1.0], 60.0)
    with pytest.raises(InputError, match="tau_s"):
        along_track_quadratic([1.0, 2.0], [0.0, 1.0], [1.0, 1.0], 0.0)
    with pytest.raises(InputError, match="u"):
        along_track_quadratic([1.0, np.nan], [0.0, 1.0], [1.0, 1.0], 60.0)
    with pytest.raises(InputError, match="fraction"):
        AlongTrackModel(fraction=-0.1)
    with pytest.raises(InputError, match="tau_s"):
        AlongTrackModel(tau_s=-1.0)


def test_fit_recovers_a_drawn_ou_process():
    """Errors drawn from the model itself (fraction 0.7, tau 40 s; 24 surveys of 1500 s
    pooled, as the calibration pools surveys; seeded). Sampling spread measured over seeds
    3-8: fraction 0.65-0.73, e-folding tau 36.7-43.7 s; asserted within 10 % / 15 %."""
    rng = np.random.default_rng(3)
    frac, tau, n = 0.7, 40.0, 1500
    edges = np.array([0.0, 5, 10, 20, 30, 45, 60, 90, 120, 180, 240, 360, 1e4])
    parts = []
    for _ in range(24):
        t = np.sort(rng.uniform(0, 1500, n))
        sig = rng.uniform(0.3, 1.0, n)
        a = np.empty(n)  # exact OU sampling on the irregular times
        a[0] = rng.normal()
        for i in range(1, n):
            r = np.exp(-(t[i] - t[i - 1]) / tau)
            a[i] = r * a[i - 1] + np.sqrt(1 - r**2) * rng.normal()
        e = sig * (np.sqrt(frac) * a + np.sqrt(1 - frac) * rng.normal(size=n))
        parts.append(empirical_time_correlation(t, e, sig, edges) | {"n": n})
    c = pool_time_correlations(parts)
    assert float(c["nees"]) == pytest.approx(1.0, abs=0.1)
    fit = fit_along_track(c["lag_s"], c["corr"], c["pairs"], float(c["nees"]))
    assert fit["fraction"] == pytest.approx(frac, rel=0.10)
    assert fit["tau_s"] == pytest.approx(tau, rel=0.15)


def test_fit_needs_short_lags():
    with pytest.raises(InputError, match="lag_s"):
        fit_along_track(np.array([20.0, 40, 80]), np.array([0.5, 0.3, 0.1]), np.ones(3), 1.0)
