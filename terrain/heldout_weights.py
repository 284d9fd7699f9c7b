"""Weights that give the held-out samples the neighbourhoods of the map's cells
(:func:`neighbourhood_weights`).

A held-out sample tests the map where its training data surround it as the data surround
a map cell. The block size matches the *nearest* distance (:func:`terrain.heldout_design.
matched_block_size`); what is left is the rest of the neighbourhood. A block cut out of a
dense survey line leaves a gap *along* the line, with hundreds of samples half a block away
on both sides, while the map's cells between the lines see a few scattered samples at the
same nearest distance and the lines far off. A smooth kernel (the squared exponential)
extrapolates a line's slope confidently into such a gap, so its held-out errors there say
little about the map's cells. Measured on the Olinda DEM over 3 km (10 lines 300 m apart
and 2,000 scattered samples, a prior DEM, SE by evidence; ``benchmarks/heldout_lines.py``):
the map covered 73.3 / 95.3 % at 68 / 95 %; the true errors at the held-out line samples
52.1 / 77.2 %, at the scattered ones 74.1 / 93.5 %; the check with distance weights read
57.9 / 80.3 % and said the 1-sigma was too small.

Each point is described by the distances to its 1st, 4th and 16th nearest data
(:data:`NEIGHBOUR_RANKS`, log scale, standardized on the map's cells): the nearest sample,
the nearest few, the neighbourhood. Every map cell (an even stride of at most
:data:`MATCH_TARGETS`) votes for the :data:`MATCH_VOTES` held-out samples nearest to it in
that space; a sample's weight is its share of the votes (a nearest-neighbour density ratio,
Sugiyama, Suzuki & Kanamori 2012, *Density Ratio Estimation in Machine Learning*; the
neighbourhood version of kNNDM's nearest-distance matching, Linnenbrink et al. 2024). A
held-out sample whose neighbourhood no map cell has gets no weight. The weights rest on
fewer samples than the distance weights, so the check uses them only where they move it
beyond chance (:func:`terrain.heldout_design.map_calibration`; docs/terrain.md "Held-out
samples in gaps along dense lines").
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = [
    "MATCH_TARGETS",
    "MATCH_VOTES",
    "NEIGHBOUR_RANKS",
    "effective_share",
    "even_stride",
    "heldout_neighbour_distances",
    "neighbour_distances",
    "neighbourhood_weights",
    "sample_spacing",
]

#: Ranks of the nearest data whose distances describe a point's neighbourhood.
NEIGHBOUR_RANKS = (1, 4, 16)
#: Held-out samples each map cell votes for (its nearest in the neighbourhood space).
MATCH_VOTES = 60
#: Map cells described at most (an even stride through the targets beyond this).
MATCH_TARGETS = 20_000


def even_stride(points: np.ndarray, limit: int = MATCH_TARGETS) -> np.ndarray:
    """At most about ``limit`` rows of ``points`` by an even stride (no random numbers spent):
    the map cells the neighbourhood matching describes."""
    return points[:: max(1, int(np.ceil(points.shape[0] / limit)))]


def sample_spacing(xy: np.ndarray) -> float:
    """Median distance from each sample to its nearest other sample, m (0 for one sample)."""
    if xy.shape[0] < 2:
        return 0.0
    return float(np.median(cKDTree(xy).query(xy, k=2, workers=-1)[0][:, 1]))


def _ranks(ranks: tuple[int, ...], available: int) -> list[int]:
    """Ranks clipped to the data available (at least rank 1)."""
    return [max(1, min(int(r), int(available))) for r in ranks]


def neighbour_distances(
    data_xy: np.ndarray, query_xy: np.ndarray, ranks: tuple[int, ...] = NEIGHBOUR_RANKS
) -> np.ndarray:
    """Distances from each query point to its ``ranks``-th nearest data point, shape (m,
    len(ranks)), m; ranks beyond the data are clipped to the farthest."""
    r = _ranks(ranks, data_xy.shape[0])
    d = cKDTree(data_xy).query(query_xy, k=max(r))[0].reshape(query_xy.shape[0], -1)
    return d[:, [k - 1 for k in r]]


def heldout_neighbour_distances(
    xy: np.ndarray, fold: np.ndarray, ranks: tuple[int, ...] = NEIGHBOUR_RANKS
) -> np.ndarray:
    """Distances from each sample to its ``ranks``-th nearest sample of the other folds (the
    training set that predicts it), shape (n, len(ranks)), m."""
    folds = np.unique(fold)
    n_train = min(int(np.sum(fold != f)) for f in folds)
    r = tuple(_ranks(ranks, n_train))
    d = np.empty((xy.shape[0], len(r)))
    for f in folds:
        test = fold == f
        d[test] = neighbour_distances(xy[~test], xy[test], r)
    return d


def neighbourhood_weights(
    heldout_d: np.ndarray, target_d: np.ndarray, votes: int = MATCH_VOTES
) -> np.ndarray:
    """Weights that give the held-out samples the map cells' neighbourhoods (module
    docstring), normalised to mean 1, shape (n,).

    Parameters
    ----------
    heldout_d : ndarray of shape (n, k)
        Each held-out sample's distances to its ranked nearest training samples, m
        (:func:`heldout_neighbour_distances`).
    target_d : ndarray of shape (m, k)
        Each map cell's distances to its ranked nearest samples, m (the same ranks).
    votes : int
        Held-out samples each cell votes for.
    """
    n = heldout_d.shape[0]
    target_d = even_stride(target_d)
    # log distances, scaled by the map's spread (a small floor keeps cells on samples finite)
    floor = 1e-3 * max(float(np.median(target_d[:, -1])), 1e-9)
    h, t = np.log(heldout_d + floor), np.log(target_d + floor)
    spread = t.std(axis=0)
    spread[spread <= 0] = 1.0
    centre = t.mean(axis=0)
    k = max(1, min(int(votes), n))
    idx = cKDTree((h - centre) / spread).query((t - centre) / spread, k=k)[1]
    w = np.bincount(np.asarray(idx).ravel(), minlength=n).astype(float)
    return w / w.mean()


def effective_share(weights: np.ndarray) -> float:
    """Kish's effective sample size of ``weights`` over their count, 0..1: the share of the
    held-out samples the weighted check effectively rests on."""
    w = np.asarray(weights, dtype=float)
    s2 = float(np.sum(w**2))
    return float(np.sum(w) ** 2 / s2 / w.size) if s2 > 0 else 0.0
