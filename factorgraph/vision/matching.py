"""Descriptor association between consecutive frames: Lowe's ratio test among the
candidates inside each feature's search window (around the pixel the odometry predicts),
then a mutual forward-backward check. Only the pairs inside the windows are looked at (a
k-d tree finds them), so the cost follows the features, not their product."""

from __future__ import annotations

import numpy as np

__all__ = ["match_descriptors"]


def _distances(a, b, binary: bool) -> np.ndarray:
    """Descriptor distances (n_a, n_b): L2, or Hamming for binary descriptors."""
    if binary:
        bits = np.unpackbits(a[:, None, :] ^ b[None, :, :], axis=2)
        return bits.sum(2).astype(np.float32)
    a, b = a.astype(np.float32), b.astype(np.float32)
    d2 = (a * a).sum(1)[:, None] + (b * b).sum(1)[None, :] - 2.0 * a @ b.T
    return np.sqrt(np.clip(d2, 0, None))


def match_descriptors(prev, pts, cur_desc, params, counts, binary: bool, pred=None):
    """Mutual ratio-test matches ``(i_prev, j_cur)`` of the previous frame's features
    (``prev.pts`` (n, 2) px, ``prev.desc``) with the current ones (``pts`` (m, 2) px,
    ``cur_desc``); with ``pred`` ((n, 2) predicted pixels and a validity mask) only
    candidates inside the search window compete. Rejections are added to ``counts``
    (``no_candidate``, ``ratio_test``, ``not_mutual``).

    Both routes give the matches of a dense argsort over all pairs with the pairs outside
    the windows set to infinity (the code before session 11; tests/test_vision_matching.py).
    With windows only the pairs inside them are looked at: the front-end went from 235 to
    ~130 ms a frame on sunny snow, same tracks."""
    if prev.desc is None or cur_desc is None or len(prev.desc) < 2 or len(cur_desc) < 2:
        return np.zeros(0, int), np.zeros(0, int)
    D = _distances(prev.desc, cur_desc, binary)
    if pred is None:
        best, second, best_j, back = _nearest_two_dense(D)
    else:
        i, j = _window_pairs(prev.pts, pts, pred, params)
        best, second, best_j, back = _nearest_two_pairs(i, j, D[i, j], D.shape)
    # a tie between the best and the second best fails the ratio test, so which of two
    # equals is "best" never decides a match
    has = np.isfinite(best)
    counts["no_candidate"] += int((~has).sum())
    ratio_ok = has & (best < params.ratio * second)
    counts["ratio_test"] += int((has & ~ratio_ok).sum())
    ii = np.flatnonzero(ratio_ok)
    jj = best_j[ratio_ok]
    mutual = back[jj] == ii  # forward-backward: the current feature's nearest is ii too
    counts["not_mutual"] += int((~mutual).sum())
    return ii[mutual], jj[mutual]


def _nearest_two_dense(D: np.ndarray):
    """Per row of ``D`` (n, m), m >= 2: the smallest and second smallest value and the
    column of the smallest; per column the row of its smallest (first on ties)."""
    rows = np.arange(len(D))
    two = np.argpartition(D, 1, axis=1)[:, :2]  # the two smallest, in either order
    d2 = np.take_along_axis(D, two, axis=1)
    first = (d2[:, 1] < d2[:, 0]).astype(int)
    return d2[rows, first], d2[rows, 1 - first], two[rows, first], np.argmin(D, axis=0)


def _nearest_two_pairs(i: np.ndarray, j: np.ndarray, d: np.ndarray, shape: tuple[int, int]):
    """:func:`_nearest_two_dense` of a matrix of ``shape`` that is infinite except at the
    pairs ``(i, j)`` with values ``d``; a column without pairs gets row -1."""
    n, m = shape
    best = np.full(n, np.inf, d.dtype)
    second = np.full(n, np.inf, d.dtype)
    best_j = np.zeros(n, int)
    back = np.full(m, -1)
    if i.size == 0:
        return best, second, best_j, back
    o = np.lexsort((d, i))  # by row, then value
    i_s, j_s, d_s = i[o], j[o], d[o]
    start = np.flatnonzero(np.r_[True, i_s[1:] != i_s[:-1]])
    best[i_s[start]], best_j[i_s[start]] = d_s[start], j_s[start]
    nxt = start + 1
    two = start[nxt < i_s.size]
    two = two[i_s[two + 1] == i_s[two]]
    second[i_s[two]] = d_s[two + 1]
    o = np.lexsort((i, d, j))  # by column, then value, then row (argmin's first on ties)
    j_s = j[o]
    first = np.flatnonzero(np.r_[True, j_s[1:] != j_s[:-1]])
    back[j_s[first]] = i[o][first]
    return best, second, best_j, back


def _window_pairs(prev_pts, pts, pred, params) -> tuple[np.ndarray, np.ndarray]:
    """Pairs ``(i_prev, j_cur)`` whose current feature lies in the previous one's search
    window: ``|uv_i - p_j| <= search_px + search_frac * |uv_i - prev_i|`` around the
    predicted pixel ``uv_i`` (valid predictions only). A k-d tree gives a superset; the
    test itself is the per-axis sum of squares and square root of ``np.linalg.norm``."""
    from scipy.spatial import cKDTree

    uv, valid = pred
    radius = params.search_px + params.search_frac * np.linalg.norm(uv - prev_pts, axis=1)
    rows = np.flatnonzero(valid)
    if rows.size == 0 or len(pts) == 0:
        return np.zeros(0, int), np.zeros(0, int)
    hits = cKDTree(np.asarray(pts, float)).query_ball_point(
        np.asarray(uv[rows], float), radius[rows] * (1 + 1e-9) + 1e-9
    )
    sizes = np.fromiter((len(h) for h in hits), int, rows.size)
    i = np.repeat(rows, sizes)
    j = np.fromiter((x for h in hits for x in h), int, int(sizes.sum()))
    du = uv[i, 0] - pts[j, 0]
    dv = uv[i, 1] - pts[j, 1]
    inside = ~(np.sqrt(du * du + dv * dv) > radius[i])
    return i[inside], j[inside]
