"""Descriptor association (factorgraph/vision/matching.py) against the dense reference it
replaced in session 11: all pairs' distances, the pairs outside each search window set to
infinity, a full argsort per row and an argmin per column. Same matches and the same
rejection counts, with and without windows, for float (SIFT) and binary (ORB) descriptors,
ties included."""

from collections import Counter
from types import SimpleNamespace

import numpy as np
import pytest

from factorgraph.vision.matching import _distances, match_descriptors
from factorgraph.vision.tracking import TrackParams


def _reference(prev, pts, cur_desc, params, counts, binary, pred=None):
    """The front-end's matcher up to session 10, verbatim in what it computes."""
    D = _distances(prev.desc, cur_desc, binary)
    if pred is not None:
        uv, valid = pred
        radius = params.search_px + params.search_frac * np.linalg.norm(uv - prev.pts, axis=1)
        far = np.linalg.norm(uv[:, None, :] - pts[None, :, :], axis=2) > radius[:, None]
        far |= ~valid[:, None]
        D[far] = np.inf
    order = np.argsort(D, axis=1)[:, :2]
    rows = np.arange(len(D))
    best, second = D[rows, order[:, 0]], D[rows, order[:, 1]]
    has = np.isfinite(best)
    counts["no_candidate"] += int((~has).sum())
    ratio_ok = has & (best < params.ratio * second)
    counts["ratio_test"] += int((has & ~ratio_ok).sum())
    ii = rows[ratio_ok]
    jj = order[ratio_ok, 0]
    back = np.argmin(D, axis=0)
    mutual = back[jj] == ii
    counts["not_mutual"] += int((~mutual).sum())
    return ii[mutual], jj[mutual]


def _case(rng, binary: bool, n: int = 300, m: int = 350, dup: int = 40):
    """Previous and current features: the current ones are the previous ones moved by a
    flow field plus pixel noise, with descriptor noise, shuffled, plus clutter; ``dup``
    previous descriptors copied exactly (ties)."""
    prev_pts = rng.uniform([0, 0], [640, 480], (n, 2)).astype(np.float32)
    flow = np.array([3.0, 12.0]) + rng.normal(0, 2.0, (n, 2))
    if binary:
        prev_desc = rng.integers(0, 256, (n, 32), dtype=np.uint8)
        flips = rng.random((n, 32)) < 0.05
        cur_desc = prev_desc ^ (flips * rng.integers(1, 256, (n, 32))).astype(np.uint8)
        clutter = rng.integers(0, 256, (m - n, 32), dtype=np.uint8)
    else:
        prev_desc = rng.uniform(0, 100, (n, 128)).astype(np.float32)
        cur_desc = (prev_desc + rng.normal(0, 8, (n, 128))).astype(np.float32)
        clutter = rng.uniform(0, 100, (m - n, 128)).astype(np.float32)
    prev_desc[:dup] = prev_desc[dup : 2 * dup]  # exact ties in the forward direction
    cur = np.vstack([prev_pts + flow + rng.normal(0, 1.0, (n, 2)), rng.uniform(0, 640, (m - n, 2))])
    desc = np.vstack([cur_desc, clutter])
    perm = rng.permutation(m)
    pts, desc = cur[perm].astype(np.float32), desc[perm]
    desc[:dup] = desc[dup : 2 * dup]  # and in the backward direction
    uv = prev_pts + np.array([3.0, 12.0]) + rng.normal(0, 3.0, (n, 2))
    valid = rng.random(n) > 0.1
    prev = SimpleNamespace(pts=prev_pts, desc=prev_desc)
    return prev, pts, desc, (uv, valid)


@pytest.mark.parametrize("binary", [False, True])
@pytest.mark.parametrize("windows", [False, True])
@pytest.mark.parametrize("seed", range(4))
def test_matches_and_counts_equal_the_dense_reference(binary, windows, seed):
    rng = np.random.default_rng(seed)
    prev, pts, desc, pred = _case(rng, binary)
    params = TrackParams(search_px=24.0 if seed % 2 else 8.0)
    got_counts, ref_counts = Counter(), Counter()
    got = match_descriptors(prev, pts, desc, params, got_counts, binary, pred if windows else None)
    ref = _reference(prev, pts, desc, params, ref_counts, binary, pred if windows else None)
    np.testing.assert_array_equal(got[0], ref[0])
    np.testing.assert_array_equal(got[1], ref[1])
    assert got_counts == ref_counts
    assert got[0].size > 20  # the case has real matches, not only rejections
    assert ref_counts["not_mutual"] + ref_counts["ratio_test"] > 0


def test_no_feature_in_any_window_is_counted_not_matched():
    rng = np.random.default_rng(0)
    prev, pts, desc, (uv, valid) = _case(rng, binary=False)
    counts = Counter()
    far_uv = uv + 5000.0  # every prediction off the image
    ii, jj = match_descriptors(prev, pts, desc, TrackParams(), counts, False, (far_uv, valid))
    assert ii.size == jj.size == 0
    assert counts["no_candidate"] == len(prev.pts)


def test_a_feature_exactly_on_the_window_edge_competes():
    """|uv - p| == radius is inside (the reference's test is ``> radius`` for 'far')."""
    prev = SimpleNamespace(
        pts=np.array([[100.0, 100.0], [300.0, 300.0]], np.float32),
        desc=np.array([[0.0, 0.0], [50.0, 50.0]], np.float32),
    )
    pts = np.array([[124.0, 100.0], [400.0, 400.0]], np.float32)  # 24 px from the prediction
    desc = np.array([[1.0, 0.0], [90.0, 90.0]], np.float32)
    uv, valid = prev.pts.astype(float), np.array([True, True])  # radius = search_px = 24
    params = TrackParams(search_px=24.0)
    for fn in (match_descriptors, _reference):
        counts = Counter()
        ii, jj = fn(prev, pts, desc, params, counts, False, (uv, valid))
        assert ii.tolist() == [0] and jj.tolist() == [0], fn.__name__
