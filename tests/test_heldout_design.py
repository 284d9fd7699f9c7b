"""The held-out check's deconvolution (terrain.heldout_design.map_calibration) on residuals
whose map part and noise part are drawn here, so the map's true coverage is known."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import ndtr

from terrain.heldout_design import map_calibration, one_scale_ratio


def _residuals(n: int, kappa: float, noise_share: float, seed: int, heavy: bool = False):
    """Held-out residuals r = e + eps with e / sigma_f ~ N(0, kappa) (or a two-scale
    mixture with the same variance when ``heavy``) and var(eps) set by ``noise_share``."""
    rng = np.random.default_rng(seed)
    latent = rng.uniform(0.5, 2.0, n) * 1e-3  # stated map variance, m^2
    noise = np.full(n, latent.mean() * noise_share / (1.0 - noise_share))
    if heavy:  # 80 % at 0.5 kappa, 20 % at 3 kappa: same mean variance, heavier tails
        s2 = np.where(rng.random(n) < 0.8, 0.5 * kappa, 3.0 * kappa)
    else:
        s2 = np.full(n, kappa)
    e = rng.normal(0.0, np.sqrt(s2 * latent))
    r = e + rng.normal(0.0, np.sqrt(noise))
    t = np.abs(e) / np.sqrt(latent)
    truth = (float(np.mean(t < 1.0)), float(np.mean(t < 1.96)))
    block = np.arange(n) // 20
    return r, latent, noise, np.ones(n), block, truth


@pytest.mark.parametrize("noise_share", [0.5, 0.9, 0.96])
def test_gaussian_map_error_read_back_when_noise_dominates(noise_share):
    # A calibrated map (kappa = 1): its 68 % coverage is 2 Phi(1) - 1 = 0.683 by definition.
    # The EM once started from a flat mixture read 0.74-0.79 here at noise share 0.96 (the
    # unidentified small scales kept their start mass); from the one-scale fit it stays near.
    r, lv, nv, w, b, truth = _residuals(40_000, 1.0, noise_share, seed=1)
    out = map_calibration(r, lv, nv, w, b, np.random.default_rng(0), n_boot=10)
    assert out["map_coverage_68"] == pytest.approx(truth[0], abs=0.04)
    assert out["map_coverage_95"] == pytest.approx(truth[1], abs=0.025)
    lo, hi = out["map_coverage_68_interval"]
    assert lo <= truth[0] + 0.01 and hi >= truth[0] - 0.01


def test_heavy_tailed_map_error_found_when_noise_is_small():
    # Low noise: the mixture is identified, and a two-scale error (68 % coverage far from a
    # one-scale Gaussian's with the same variance) is read back.
    r, lv, nv, w, b, truth = _residuals(20_000, 1.0, 0.1, seed=2, heavy=True)
    out = map_calibration(r, lv, nv, w, b, np.random.default_rng(0), n_boot=10)
    one = 2.0 * ndtr(1.0 / np.sqrt(out["one_scale_ratio"])) - 1.0
    assert abs(one - truth[0]) > 0.04  # one scale alone would miss it
    assert out["map_coverage_68"] == pytest.approx(truth[0], abs=0.02)
    assert out["map_coverage_95"] == pytest.approx(truth[1], abs=0.015)


def test_one_scale_ratio_matches_its_closed_form_without_noise():
    # With no noise, the ML kappa is the weighted mean of r^2 / sigma_f^2 (hand-derived).
    rng = np.random.default_rng(3)
    lv = rng.uniform(0.5, 2.0, 5000)
    r = rng.normal(0.0, np.sqrt(1.7 * lv))
    w = rng.uniform(0.5, 1.5, 5000)
    expect = float(np.sum(w * r**2 / lv) / np.sum(w))
    got = one_scale_ratio(r, lv, np.zeros_like(lv), w)
    assert got == pytest.approx(expect, rel=1e-4)


def test_bootstrap_same_bits_for_any_thread_count(monkeypatch):
    # The resamples are drawn in order, then estimated over threads (os.cpu_count() of them).
    import terrain.heldout_design as hd

    rng = np.random.default_rng(5)
    n = 1500
    lat = rng.uniform(0.002, 0.03, n)
    noise = np.full(n, 0.04)
    resid = rng.normal(0.0, np.sqrt(lat * rng.choice([0.5, 1.0, 2.0], n) + noise))
    w, block = rng.uniform(0.5, 2.0, n), rng.integers(0, 120, n)
    outs = []
    for cpus in (1, 3):
        monkeypatch.setattr(hd.os, "cpu_count", lambda c=cpus: c)
        outs.append(hd.map_calibration(resid, lat, noise, w, block, np.random.default_rng(0), 20))
    assert outs[0] == outs[1]
    assert outs[0]["map_coverage_68_interval"] is not None


def test_mixture_em_matches_the_textbook_responsibilities():
    # Laird (1978) EM written out: responsibilities g_ik = lik_ik pi_k / sum_k lik_ik pi_k,
    # new pi_k = sum_i w_i g_ik / sum_i w_i; the module never forms g (two mat-vecs a step).
    from terrain.heldout_design import _mixture

    rng = np.random.default_rng(4)
    lik = rng.uniform(0.01, 1.0, (400, 24))
    w = rng.uniform(0.0, 2.0, 400)
    w[rng.uniform(size=400) < 0.3] = 0.0
    pi = np.full(24, 1.0 / 24)
    for _ in range(50):
        g = lik * pi
        g /= g.sum(axis=1, keepdims=True)
        pi = (w @ g) / w.sum()
    out = _mixture(lik, w, np.full(24, 1.0 / 24), 50)
    assert np.allclose(out, pi, rtol=1e-12, atol=1e-15)
    assert out.sum() == pytest.approx(1.0, abs=1e-12)


def test_mixture_em_for_many_weightings_at_once_equals_one_at_a_time():
    """The bootstrap runs its EMs as one batch (two matrix products a step for all of them,
    session 27: the held-out check's bootstrap 2.3 -> 0.8 s at 3,800 samples); each row must
    stop on its own, as the one-at-a-time EM does."""
    from terrain.heldout_design import _mixture

    rng = np.random.default_rng(7)
    lik = rng.uniform(0.01, 1.0, (300, 24))
    W = rng.uniform(0.0, 2.0, (4, 300))
    W[1] = W[0]  # the same weights from another start
    P = rng.dirichlet(np.ones(24), 4)
    P[3] = _mixture(lik, W[3], P[3], 5000)  # already converged: stops at its first step
    for iters in (1, 40, 3000):
        batch = _mixture(lik, W, P, iters)
        alone = np.array([_mixture(lik, W[b], P[b], iters) for b in range(4)])
        np.testing.assert_allclose(batch, alone, rtol=1e-12, atol=1e-15)
