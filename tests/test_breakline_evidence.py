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
from terrain.breakline_evidence import gls_mean, widths_by_evidence
from terrain.sampling import sample_dem

X0, Y0, CRS = 526000.0, 6475000.0, "EPSG:32608"
WIDTH, HEIGHT = 1.5, 4.0


def _line(x):
    return Y0 + 300.0 + 20.0 * np.sin((x - X0) / 90.0)


@pytest.fixture(scope="module")
def fitted():
    """The default site with a sinuous 4 m step 1.5 m wide; 1,500 samples, 5 cm noise; the
    default map with the line drawn (width "auto")."""
    site = default_site(resolution=2.0)
    X, Y = np.meshgrid(site.x.values, site.y.values)
    truth = site.copy(data=site.values + HEIGHT * expit((Y - _line(X)) / WIDTH))
    rng = np.random.default_rng(0)
    xy = rng.uniform([X0 + 5, Y0 + 5], [X0 + 595, Y0 + 595], (1500, 2))
    z = sample_dem(truth, xy) + rng.normal(0.0, 0.05, 1500)
    samples = ElevationSamples(xy, z, np.full(1500, 0.0025), crs=CRS)
    u = np.linspace(X0 - 50, X0 + 650, 141)
    gp = TerrainGP(seed=0, mean=BreaklineMean([np.column_stack([u, _line(u)])])).fit(samples)
    return gp, samples


def _refine(gp, samples, mean):
    nv = gp.z_var_ + gp.nugget_
    return widths_by_evidence(mean, gp.kernel_, gp.X_train_, samples.xy, samples.z, nv)


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
    args = (gp.kernel_, gp.X_train_, samples.xy, samples.z, nv, L)
    _, beta, _ = gls_mean(refined, *args)
    assert beta[refined.coef_names.index("step1_m")] == pytest.approx(HEIGHT, abs=0.3)


def test_a_given_width_and_other_means_are_kept(fitted):
    gp, samples = fitted
    given = copy.copy(gp.mean_)
    given.width = (0.6,)  # a width the user gave: not refined
    given.widths_ = (0.6,)
    assert _refine(gp, samples, given)[0] is given
    assert _refine(gp, samples, "constant") == ("constant", None)
