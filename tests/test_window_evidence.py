"""Windows of the samples the fit subset leaves out (terrain.window_evidence)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.linalg import null_space
from scipy.stats import multivariate_normal

from terrain import ElevationSamples, TerrainGP
from terrain.kernels import Matern, SquaredExponential
from terrain.window_evidence import (
    BUDGET_SAMPLES,
    MAX_WINDOW_SAMPLES,
    MIN_WINDOW_SAMPLES,
    WINDOW_SPACINGS,
    WindowPlan,
    score_candidates,
)


def _one_window(n=60, seed=0):
    rng = np.random.default_rng(seed)
    X = rng.uniform(-30, 30, (n, 2))
    r = np.sin(X[:, 0] / 9.0) + 0.02 * X[:, 1] + rng.normal(0, 0.2, n)
    v = np.full(n, 0.04)
    return WindowPlan([X], [r], [v], 60.0, n, 0, 0, 0), X, r, v


def test_restricted_lml_equals_the_contrasts_density_by_scipy():
    # Reference: the density of the error contrasts A^T r, A an orthonormal basis of the
    # null space of H^T (Patterson & Thompson 1971), by scipy.stats. Harville's form
    # differs from it by -1/2 log|H^T H|, which no kernel changes.
    plan, X, r, v = _one_window()
    k, nug = Matern(2.0, 15.0, nu=2.5), 0.01
    H = np.column_stack([np.ones(len(X)), X])
    A = null_space(H.T)
    C = k(X) + np.diag(v + nug)
    ref = multivariate_normal(np.zeros(A.shape[1]), A.T @ C @ A).logpdf(A.T @ r)
    got = plan.lml(k, nug) + 0.5 * np.linalg.slogdet(H.T @ H)[1]
    assert got == pytest.approx(ref, abs=1e-8)


def test_a_plane_added_to_a_window_leaves_its_lml_unchanged():
    plan, X, r, v = _one_window(seed=3)
    k = SquaredExponential(1.5, 12.0)
    tilted = WindowPlan([X], [r + 4.0 + 0.3 * X[:, 0] - 0.2 * X[:, 1]], [v], 60.0, 60, 0, 0, 0)
    assert tilted.lml(k, 0.0) == pytest.approx(plan.lml(k, 0.0), abs=1e-7)


def test_a_rougher_kernel_than_the_ground_scores_lower():
    # Smooth ground (one long sine) densely sampled: the Matern 3/2 whose small lags are
    # rough must score below a smooth SE of the same variance and length.
    rng = np.random.default_rng(1)
    X = rng.uniform(-30, 30, (400, 2))
    r = 2.0 * np.sin(X[:, 0] / 12.0) * np.cos(X[:, 1] / 15.0) + rng.normal(0, 0.05, 400)
    plan = WindowPlan([X], [r], [np.full(400, 0.0025)], 60.0, 400, 0, 0, 0)
    assert plan.lml(SquaredExponential(2.0, 15.0), 0.0) > plan.lml(Matern(2.0, 15.0, nu=1.5), 0.0)


def _survey(n=6000, seed=0):
    rng = np.random.default_rng(seed)
    X = rng.uniform(0, 600, (n, 2))
    return X, np.arange(n, dtype=float), np.full(n, 0.04)  # r labels each sample


def test_windows_hold_only_left_out_samples_once_and_count_the_rest():
    X, r, v = _survey()
    fit = np.sort(np.random.default_rng(1).choice(len(r), 2000, replace=False))
    plan = WindowPlan.build(X, r, v, fit, np.random.default_rng(2))
    assert plan is not None
    labels = np.concatenate(plan.r).astype(int)
    assert labels.size == np.unique(labels).size  # no sample twice
    assert not np.isin(labels, fit).any()  # none from the fit subset
    assert plan.n_left_out == 4000
    counts = plan.n_samples + plan.n_capped + plan.n_sparse + plan.n_over_budget
    assert counts == plan.n_left_out  # nothing unaccounted for
    area = np.prod(np.ptp(X, axis=0))
    assert plan.side == pytest.approx(WINDOW_SPACINGS * np.sqrt(area / 2000))
    for x in plan.X:  # each window lies inside one square of that side
        assert MIN_WINDOW_SAMPLES <= len(x) <= MAX_WINDOW_SAMPLES
        assert np.ptp(x, axis=0).max() <= plan.side
        assert np.allclose(x.mean(axis=0), 0.0)
    desc = json.loads(plan.describe())
    assert desc["windows"] == len(plan.X) and desc["left_out"] == 4000


def test_crowded_windows_are_thinned_and_the_budget_holds():
    rng = np.random.default_rng(4)
    X = rng.uniform(0, 600, (60_000, 2))
    fit = np.arange(0, 60_000, 60)  # 1,000 samples: 95 m windows of ~1,500 samples
    plan = WindowPlan.build(X, np.zeros(60_000), np.full(60_000, 0.04), fit, rng)
    assert plan.n_capped > 0
    assert max(len(x) for x in plan.X) == MAX_WINDOW_SAMPLES  # edge squares hold fewer
    assert BUDGET_SAMPLES <= plan.n_samples < BUDGET_SAMPLES + MAX_WINDOW_SAMPLES
    assert plan.n_over_budget > 0


def test_no_windows_when_the_subset_holds_the_survey():
    X, r, v = _survey(n=500)
    assert WindowPlan.build(X, r, v, np.arange(500), np.random.default_rng(0)) is None
    assert WindowPlan.build(X, r, v, np.arange(490), np.random.default_rng(0)) is None


def test_scores_are_the_same_for_any_number_of_threads():
    plan, X, r, v = _one_window(n=200, seed=5)
    fits = {
        "se": (SquaredExponential(1.0, 10.0), 0.0, 0.0, 1),
        "matern32": (Matern(1.0, 10.0, nu=1.5), 0.0, 0.0, 1),
    }
    one = [{"name": n, "bic": 10.0} for n in fits]
    two = [dict(row) for row in one]
    score_candidates(one, fits, plan, workers=1)
    score_candidates(two, fits, plan, workers=2)
    assert one == two
    for row in one:
        assert row["score"] == row["bic"] - 2.0 * row["window_lml"]
    none = [{"name": "se", "bic": 3.0}]
    score_candidates(none, fits, None, workers=1)
    assert none[0]["score"] == 3.0 and none[0]["window_lml"] is None


def _field(n, seed):
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, 300, (n, 2))
    z = 5.0 * np.sin(xy[:, 0] / 40.0) * np.cos(xy[:, 1] / 55.0) + rng.normal(0, 0.1, n)
    return ElevationSamples(xy, z, np.full(n, 0.01), crs="EPSG:32608")


def test_the_search_keeps_the_best_score_and_records_the_windows():
    gp = TerrainGP(kernel=["matern32", "matern52"], max_fit_samples=400, seed=0)
    gp.fit(_field(3000, 0))
    rows = [r for r in gp.kernel_scores_ if r["bic"] is not None]
    for row in rows:
        assert row["score"] == pytest.approx(row["bic"] - 2.0 * row["window_lml"])
    best = min(rows, key=lambda r: r["score"])
    assert best["selected"] and gp.kernel_name_ == best["name"]
    windows = json.loads(gp.provenance()["kernel_windows"])
    assert windows["windows"] > 0 and windows["left_out"] == 2600
    # same seed, same scores
    again = TerrainGP(kernel=["matern32", "matern52"], max_fit_samples=400, seed=0)
    again.fit(_field(3000, 0))
    assert [r["score"] for r in again.kernel_scores_] == [r["score"] for r in gp.kernel_scores_]


def test_a_subset_holding_every_sample_scores_by_the_bic_alone():
    gp = TerrainGP(kernel=["matern32", "matern52"], seed=0).fit(_field(300, 1))
    assert gp.provenance()["kernel_windows"] == "none"
    for row in gp.kernel_scores_:
        assert row["window_lml"] is None and row["score"] == row["bic"]
