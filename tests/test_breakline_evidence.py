"""A breakline's width refined by the map's evidence (``terrain.breakline_evidence``).

References: the ground's own step (a logistic 1.5 m wide, 4 m high, laid by hand on the
default site), and the eleven real DEMs measured in docs/terrain.md ("The step's width by
the map's evidence": |z| <= 2 on 16 of 22 scarp rows against 2 of 22 before).
"""

from __future__ import annotations

import copy

import numpy as np
import pytest
from scipy.special import expit

from terrain import BreaklineMean, ElevationSamples, TerrainGP, default_site
from terrain.breakline_evidence import SPAN, gls_mean, width_uncertainty, widths_by_evidence
from terrain.sampling import sample_dem

X0, Y0, CRS = 526000.0, 6475000.0, "EPSG:32608"
WIDTH, HEIGHT = 1.5, 4.0


def _line(x):
    return Y0 + 300.0 + 20.0 * np.sin((x - X0) / 90.0)


def _survey(height: float, seed: int):
    """The default site with a sinuous step ``height`` m high, 1.5 m wide; 1,500 samples,
    5 cm noise (``seed``); the default map with the line drawn (width "auto")."""
    site = default_site(resolution=2.0)
    X, Y = np.meshgrid(site.x.values, site.y.values)
    truth = site.copy(data=site.values + height * expit((Y - _line(X)) / WIDTH))
    rng = np.random.default_rng(seed)
    xy = rng.uniform([X0 + 5, Y0 + 5], [X0 + 595, Y0 + 595], (1500, 2))
    z = sample_dem(truth, xy) + rng.normal(0.0, 0.05, 1500)
    samples = ElevationSamples(xy, z, np.full(1500, 0.0025), crs=CRS)
    u = np.linspace(X0 - 50, X0 + 650, 141)
    gp = TerrainGP(seed=0, mean=BreaklineMean([np.column_stack([u, _line(u)])])).fit(samples)
    return gp, samples


@pytest.fixture(scope="module")
def fitted():
    """The 4 m step, seed 0 (:func:`_survey`)."""
    return _survey(HEIGHT, 0)


def _refine(gp, samples, mean):
    nv = gp.z_var_ + gp.nugget_
    return widths_by_evidence(mean, gp.kernel_, gp.X_train_, gp.samples_.xy, gp.samples_.z, nv)


def test_the_map_takes_the_grounds_width_and_step(fitted):
    # measured (seed 0): the local planes alone chose 1.77 m; with the evidence 1.55 m, the
    # step 3.87 +- 0.07 m for 4
    gp, _ = fitted
    k = gp.mean_.coef_names.index("step1_m")
    step, sd = gp.mean_.coef_[k], np.sqrt(gp.mean_.coef_cov_[k, k])
    assert gp.mean_.widths_[0] == pytest.approx(WIDTH, abs=0.25)
    assert abs(step - HEIGHT) < 3.0 * sd + 0.05


def test_a_start_far_off_comes_back_and_the_misfit_falls(fitted):
    # the local planes' start replaced by 0.6 m (as olinda's 0.98 m for 1.5): the evidence
    # brings it back to the ground's width, and the GLS residual form can only fall
    gp, samples = fitted
    start = copy.copy(gp.mean_)
    start.widths_ = (0.6,)
    refined, L = _refine(gp, samples, start)
    assert L is not None and refined is not start
    assert refined.widths_[0] == pytest.approx(gp.mean_.widths_[0], abs=0.15)
    nv = gp.z_var_ + gp.nugget_
    args = (gp.kernel_, gp.X_train_, gp.samples_.xy, gp.samples_.z, nv, L)
    _, beta, _ = gls_mean(refined, *args)
    assert beta[refined.coef_names.index("step1_m")] == pytest.approx(HEIGHT, abs=0.3)


def test_a_given_width_and_other_means_are_kept(fitted):
    gp, samples = fitted
    given = copy.copy(gp.mean_)
    given.width = (0.6,)  # a width the user gave: not refined, no 1-sigma of its own
    given.widths_, given.widths_sd_, given.width_cov_ = (0.6,), None, None
    assert _refine(gp, samples, given)[0] is given
    # a width rebuilt from a product that recorded its 1-sigma (glacimap change): kept, its
    # 1-sigma derived again
    rebuilt = copy.copy(gp.mean_)
    rebuilt.width = gp.mean_.widths_
    out = _refine(gp, samples, rebuilt)[0]
    assert out.widths_ == gp.mean_.widths_
    assert out.widths_sd_ == pytest.approx(gp.mean_.widths_sd_, rel=1e-6)
    assert _refine(gp, samples, "constant") == ("constant", None)


def test_the_widths_uncertainty_by_hand():
    # hand computation: a misfit (-2 log p) quadratic in u = log w, (u - u0)^2 / s^2, has
    # observed information 1 / s^2 in u, so sd(w) = w s; a coefficient linear in u,
    # beta = (3 u, -u), moves with J = (3, -1): cov = s^2 J J^T
    u0, s = np.log(1.5), 0.08

    def gls(widths):
        u = np.log(widths[0])
        return (u - u0) ** 2 / s**2, np.array([3.0 * u, -u])

    sds, cov = width_uncertainty(gls, [1.5])
    assert sds[0] == pytest.approx(1.5 * s, rel=1e-6)
    np.testing.assert_allclose(cov, s**2 * np.outer([3.0, -1.0], [3.0, -1.0]), rtol=1e-6)
    # a misfit that does not curve about the width: the search's whole span as its 1-sigma
    sds, cov = width_uncertainty(lambda w: (0.0, np.array([np.log(w[0])])), [1.5])
    assert sds[0] == pytest.approx(1.5 * np.log(SPAN))
    assert cov[0, 0] == pytest.approx(np.log(SPAN) ** 2)


def test_the_steps_sigma_carries_the_widths(fitted):
    # the step's 1-sigma is its GLS 1-sigma at the chosen width plus what the width's own
    # uncertainty adds (J var(u) J^T): larger than the GLS alone, and the truth within 2 sd
    # (measured, seed 0: 3.87 +- 0.11 m for 4, 1.55 +- 0.07 m wide, where the GLS alone said
    # +- 0.07; the eleven real DEMs' scarps at 3k: |z| <= 2 on 21 of 22 rows against 16 of
    # 22, benchmarks/breakline_steps.py)
    gp, samples = fitted
    k = gp.mean_.coef_names.index("step1_m")
    step, sd = gp.mean_.coef_[k], np.sqrt(gp.mean_.coef_cov_[k, k])
    nv = gp.z_var_ + gp.nugget_
    H = gp.mean_.basis(gp.samples_.xy)
    from terrain.gp_mean import gls_coefficients

    _, cov = gls_coefficients(gp.kernel_, gp.X_train_, gp.samples_.z, nv, H)
    assert sd > np.sqrt(cov[k, k]) * 1.05
    assert abs(step - HEIGHT) <= 2.0 * sd
    (w_sd,) = gp.mean_.widths_sd_
    assert 0.0 < w_sd < 0.5 and abs(gp.mean_.widths_[0] - WIDTH) <= 2.5 * w_sd


def test_the_step_at_its_own_width_is_the_maps_and_a_shared_width_reads_a_growth(fitted):
    # terrain.breakline_change. Reference 1, the fit itself: at the width the map chose,
    # step_at_width gives the map's own step, and GLS variance + J^2 var(log w) is the map's
    # step variance (width_uncertainty's sum). Reference 2, a known change: the same ground
    # surveyed again after the step grew 1 m (another noise and sample draw): the change at
    # one shared width lies within 2 sd of +1 m with a 1-sigma below the two maps' combined.
    from terrain.breakline_change import shared_width_change, step_at_width

    gp, samples = fitted
    k = gp.mean_.coef_names.index("step1_m")
    w, sd = gp.mean_.widths_[0], gp.mean_.widths_sd_[0]
    step, var, slope = step_at_width(gp, 0, w)
    assert step == pytest.approx(gp.mean_.coef_[k], abs=1e-8)
    assert var + slope**2 * (sd / w) ** 2 == pytest.approx(gp.mean_.coef_cov_[k, k], rel=1e-6)
    gp_after = _survey(HEIGHT + 1.0, 1)[0]
    change = shared_width_change(gp, gp_after, 0)
    assert abs(change["change_m"] - 1.0) <= 2.0 * change["change_sd_m"]
    ka = gp_after.mean_.coef_names.index("step1_m")
    independent = np.sqrt(gp.mean_.coef_cov_[k, k] + gp_after.mean_.coef_cov_[ka, ka])
    assert change["change_sd_m"] < independent
    lo, hi = sorted((w, gp_after.mean_.widths_[0]))
    assert lo <= change["width_m"] <= hi
