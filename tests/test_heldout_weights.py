"""Held-out samples matched to the map cells' neighbourhoods (terrain.heldout_weights) and the
check's switch to them (terrain.heldout_design.map_calibration, ``neighbourhood=``)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.distance import cdist
from scipy.stats import norm

from terrain.heldout_design import (
    NEIGHBOURHOOD_SWITCH_POINTS,
    NEIGHBOURHOOD_SWITCH_SD,
    map_calibration,
)
from terrain.heldout_weights import (
    MATCH_TARGETS,
    effective_share,
    heldout_neighbour_distances,
    neighbour_distances,
    neighbourhood_weights,
)


def test_neighbour_distances_match_brute_force():
    # reference: every pairwise distance (scipy cdist), sorted per query point
    rng = np.random.default_rng(0)
    data, query = rng.uniform(0, 100, (300, 2)), rng.uniform(0, 100, (50, 2))
    ref = np.sort(cdist(query, data), axis=1)
    got = neighbour_distances(data, query, (1, 4, 16))
    np.testing.assert_allclose(got, ref[:, [0, 3, 15]], rtol=1e-12)
    # ranks beyond the data are clipped to the farthest point
    np.testing.assert_allclose(neighbour_distances(data[:3], query, (1, 16))[:, 1], np.sort(
        cdist(query, data[:3]), axis=1)[:, 2])  # fmt: skip


def test_heldout_neighbour_distances_are_to_the_other_folds():
    rng = np.random.default_rng(1)
    xy = rng.uniform(0, 50, (200, 2))
    fold = np.arange(200) % 4
    got = heldout_neighbour_distances(xy, fold, (1, 4))
    for f in range(4):
        test = fold == f
        ref = np.sort(cdist(xy[test], xy[~test]), axis=1)[:, [0, 3]]
        np.testing.assert_allclose(got[test], ref, rtol=1e-12)


def test_weights_pick_the_held_out_samples_whose_neighbourhoods_the_map_has():
    """Two kinds of held-out sample with the same nearest distance (10 m): A with its 4th and
    16th nearest data far off (as a map cell between survey lines), B with them close (a gap
    cut out of a dense line). Map cells are all of kind A: B gets no weight."""
    rng = np.random.default_rng(2)
    d1 = rng.uniform(8, 12, 4000)
    a = np.column_stack([d1[:2000], d1[:2000] * 3, d1[:2000] * 8])  # sparse around
    b = np.column_stack([d1[2000:], d1[2000:] + 2, d1[2000:] + 8])  # a line on both sides
    cells = rng.uniform(8, 12, 3000)
    target = np.column_stack([cells, cells * 3, cells * 8])
    w = neighbourhood_weights(np.vstack([a, b]), target)
    assert w.mean() == pytest.approx(1.0) and (w >= 0).all()
    assert w[2000:].sum() == 0.0  # no map cell has B's neighbourhood
    assert effective_share(w) == pytest.approx(0.5, abs=0.1)  # A alone, roughly evenly
    # same neighbourhoods everywhere: weights near uniform
    same = neighbourhood_weights(a, target)
    assert effective_share(same) > 0.8


def test_weights_are_deterministic_and_stride_large_targets():
    rng = np.random.default_rng(3)
    held = rng.uniform(1, 20, (500, 3))
    target = rng.uniform(1, 20, (MATCH_TARGETS * 3 + 7, 3))
    w1, w2 = neighbourhood_weights(held, target), neighbourhood_weights(held, target)
    assert np.array_equal(w1, w2)
    # a stride of the targets (no random numbers spent): the same as passing the stride
    np.testing.assert_array_equal(w1, neighbourhood_weights(held, target[::4]))
    # fewer held-out samples than votes: every cell votes for all of them
    np.testing.assert_allclose(neighbourhood_weights(held[:5], target[:100]), 1.0)


def test_effective_share_hand_values():
    assert effective_share(np.ones(10)) == pytest.approx(1.0)
    assert effective_share(np.r_[1.0, np.zeros(9)]) == pytest.approx(0.1)
    assert effective_share(np.zeros(4)) == 0.0


def _two_kinds(n: int, seed: int):
    """Residuals of held-out samples of kind A (map error as stated, kappa = 1) and kind B
    (errors 4 x the stated variance), noise share 0.2; blocks of 20 samples."""
    rng = np.random.default_rng(seed)
    latent = rng.uniform(0.5, 2.0, n) * 1e-2
    noise = np.full(n, 0.25 * latent.mean())
    kind_b = np.arange(n) >= n // 2
    kappa = np.where(kind_b, 4.0, 1.0)
    err = rng.normal(0.0, np.sqrt(kappa * latent))
    resid = err + rng.normal(0.0, np.sqrt(noise))
    t = np.abs(err[~kind_b]) / np.sqrt(latent[~kind_b])  # kind A's true coverages, this draw
    truth = (float(np.mean(t < 1.0)), float(np.mean(t < 1.96)))
    return resid, latent, noise, np.arange(n) // 20, kind_b, truth


def test_check_switches_to_the_neighbourhood_weights_when_the_geometry_moves_it():
    # Map cells look like kind A only: the neighbourhood weights put all weight on A. The
    # distance weights (uniform) mix in B and read the coverage far low; the difference is
    # far beyond chance, so the check reports A's: a calibrated map, 68.3 / 95 % (nominal).
    resid, lat, noise, block, kind_b, truth = _two_kinds(8000, 4)
    around = np.where(kind_b, 0.0, 2.0)
    out = map_calibration(resid, lat, noise, np.ones(8000), block, np.random.default_rng(0),
                          n_boot=30, neighbourhood=around)  # fmt: skip
    assert out["matched_on"] == "neighbourhood"
    assert out["neighbourhood_difference_sd"] > NEIGHBOURHOOD_SWITCH_SD
    assert out["map_coverage_68"] == pytest.approx(truth[0], abs=0.03)
    assert out["map_coverage_95"] == pytest.approx(truth[1], abs=0.02)
    lo, hi = out["map_coverage_68_interval"]
    assert lo <= truth[0] + 0.01 and hi >= truth[0] - 0.01
    assert out["neighbourhood_matched_coverage_68"] == out["map_coverage_68"]
    assert out["distance_matched_coverage_68"] < 0.6  # the distance-matched reading
    plain = map_calibration(resid, lat, noise, np.ones(8000), block, np.random.default_rng(0),
                            n_boot=30)  # fmt: skip
    assert plain["map_coverage_68"] < 0.6  # the distance-matched reading, with B in it


def test_no_switch_by_chance_and_then_the_same_bits_as_without():
    # Both weightings over one population (kind A only): they differ by sampling alone, the
    # check keeps the distance-matched scores, bit for bit as without neighbourhood weights.
    resid, lat, noise, block, _, _ = _two_kinds(4000, 5)
    a = slice(0, 2000)
    resid, lat, noise, block = resid[a], lat[a], noise[a], block[a]
    around = np.random.default_rng(6).uniform(0.0, 2.0, 2000)
    out = map_calibration(resid, lat, noise, np.ones(2000), block, np.random.default_rng(0),
                          n_boot=30, neighbourhood=around)  # fmt: skip
    plain = map_calibration(resid, lat, noise, np.ones(2000), block, np.random.default_rng(0),
                            n_boot=30)  # fmt: skip
    assert out["matched_on"] == "nearest distance"
    assert out["neighbourhood_difference_sd"] < NEIGHBOURHOOD_SWITCH_SD
    for key, value in plain.items():
        if not key.endswith("_interval"):
            assert out[key] == value, key
    assert out["distance_matched_coverage_68"] == plain["map_coverage_68"]
    # the intervals are the bootstrap's, widened only by a difference beyond chance (if any)
    for level in ("68", "95"):
        lo, hi = out[f"map_coverage_{level}_interval"]
        plo, phi = plain[f"map_coverage_{level}_interval"]
        assert lo <= plo + 1e-12 and hi >= phi - 1e-12  # widened: equal up to rounding
        gap = abs(out[f"neighbourhood_matched_coverage_{level}"] - plain[f"map_coverage_{level}"])
        assert 0.0 <= out[f"design_sd_{level}"] < gap + 1e-12


def _b_rougher(kappa_b: float, seed: int, n: int = 20000):
    """Residuals of n held-out samples: kind A's map errors at the stated variance, kind B's
    (the second half) at ``kappa_b`` times it, noise a quarter of the mean stated variance."""
    rng = np.random.default_rng(seed)
    latent = rng.uniform(0.5, 2.0, n) * 1e-2
    noise = np.full(n, 0.25 * latent.mean())
    kind_b = np.arange(n) >= n // 2
    err = rng.normal(0.0, np.sqrt(np.where(kind_b, kappa_b, 1.0) * latent))
    return err + rng.normal(0.0, np.sqrt(noise)), latent, noise, kind_b


def test_interval_carries_what_the_two_matchings_differ_by_beyond_chance():
    # Kind B's errors 1.5 x the stated variance: the neighbourhood weights (A only) read the
    # 68 % coverage ~4 points above the distance weights (A and B), far beyond chance with
    # 20,000 samples. That difference is the check's design uncertainty: the reported
    # interval is the bootstrap's with 1.96 x design_sd added in quadrature to each side
    # (hand formula below), where the bootstrap alone would be a point wide.
    resid, latent, noise, kind_b = _b_rougher(1.5, seed=8)
    n = resid.size
    args = (resid, latent, noise, np.ones(n), np.arange(n) // 20)
    out = map_calibration(*args, np.random.default_rng(0), n_boot=30,
                          neighbourhood=np.where(kind_b, 0.0, 2.0))  # fmt: skip
    plain = map_calibration(*args, np.random.default_rng(0), n_boot=30)
    assert out["matched_on"] == "nearest distance"  # under the verdict's 5 points
    diff = out["neighbourhood_matched_coverage_68"] - out["distance_matched_coverage_68"]
    assert 0.02 < diff < NEIGHBOURHOOD_SWITCH_POINTS / 100.0
    design = out["design_sd_68"]
    assert 0.8 * diff < design <= diff  # nearly all of it beyond chance
    full = out["map_coverage_68"]
    plo, phi = plain["map_coverage_68_interval"]
    assert phi - plo < 0.02  # the bootstrap alone: a point or two wide
    below, above, half = full - plo, phi - full, norm.ppf(0.975) * design
    lo, hi = out["map_coverage_68_interval"]
    assert lo == pytest.approx(plo - (np.hypot(below, half) - below), abs=1e-9)
    assert hi == pytest.approx(phi + (np.hypot(above, half) - above), abs=1e-9)
    assert hi - lo > 3.0 * diff


def test_no_switch_for_a_difference_beyond_chance_but_within_the_verdicts_tolerance():
    # Kind B's errors 1.3 x the stated variance: A alone covers 68.3 %, A and B together
    # about 65 % (2 Phi(1 / sqrt(1.3)) - 1 = 62 % for B; hand). With 20,000 samples the
    # 3-point difference between the two weightings is far beyond chance, but under the
    # verdict's 5 points: the distance-matched scores stay.
    resid, latent, noise, kind_b = _b_rougher(1.3, seed=7)
    n = resid.size
    around = np.where(kind_b, 0.0, 2.0)
    out = map_calibration(resid, latent, noise, np.ones(n), np.arange(n) // 20,
                          np.random.default_rng(0), n_boot=30, neighbourhood=around)  # fmt: skip
    diff = out["neighbourhood_matched_coverage_68"] - out["distance_matched_coverage_68"]
    assert 0.015 < diff < NEIGHBOURHOOD_SWITCH_POINTS / 100.0
    assert out["neighbourhood_difference_sd"] > NEIGHBOURHOOD_SWITCH_SD
    assert out["matched_on"] == "nearest distance"
    assert out["map_coverage_68"] == out["distance_matched_coverage_68"]
