"""Evidence of the samples the fit subset left out, in local windows.

The kernel search (:mod:`terrain.kernel_search`) fits and scores every candidate on a fit
subset of at most 2,000 samples: about 13 m apart on a 600 m site. A map of 50,000 samples
has data metres apart, and there its 1-σ is set by the kernel at lags the subset never
sees. Candidates that agree at the subset's lags can differ several-fold there: on real
DEMs at 50,000 samples a Matérn 3/2 won the subset's BIC while its second differences at
2-8 m were 1.8-9 x the ground's (docs/terrain.md "Evidence of the samples the fit subset
left out").

By the chain rule the whole data's evidence is

    log p(y) = log p(y_subset) + log p(y_rest | y_subset).

The first term is the subset's (the search's BIC). This module approximates the second,
for each candidate *as fitted on the subset* (no parameter is fitted here, so no penalty
is owed): the samples outside the subset are cut into square windows a few subset spacings
wide, and each window's samples are scored exactly *given the subset's samples near it*,
``log p(y_w | y_near)`` (a block-conditional Vecchia term: Vecchia 1988; Guinness 2018).
What the subset already tells about a window (its level, slope and the scales the subset
resolves) is conditioned away, so what is scored is the ground between the subset's
samples. The windows do not overlap and are summed as independent blocks (a block
composite likelihood: Caragea & Smith 2007; Eidsvik et al. 2014). The candidates' score is
then ``BIC - 2 * window_lml``.

Until session 32 each window took out a plane instead (its restricted likelihood,
Patterson & Thompson 1971). A plane is not what the subset knows: on bei with the 8 x 8
prior at 10,000 samples those windows put a single SE 5.6 nats ahead of a Matérn 7/2,
while the exact ``log p(y_rest | y_subset)`` of all 8,000 left-out samples puts the Matérn
19 nats ahead; the SE won and covered 86.5 / 58.4 % at 95 / 68 (docs/terrain.md "Windows
conditioned on the subset near them").

Windows: side :data:`WINDOW_SPACINGS` x the subset's mean spacing, at least
:data:`MIN_WINDOW_SAMPLES` samples each, at most :data:`MAX_WINDOW_SAMPLES` (a seeded
random subset beyond it), up to :data:`BUDGET_SAMPLES` samples in all: every window when
they fit, else a sample spread evenly over the site (:func:`window_order`). Each is
conditioned on the subset's samples within :data:`NEAR_SIDES` window sides of its centre
(the nearest :data:`MAX_NEAR_SAMPLES` of them). Below
:data:`MIN_WINDOW_SAMPLES` left-out samples per window (a survey the subset holds almost
whole) there are no windows and the score is the BIC alone.
"""

from __future__ import annotations

import json
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from scipy.spatial import cKDTree
from threadpoolctl import threadpool_limits

from .nogil_lapack import cholesky_lower, solve_lower
from .radial_table import tabulate

__all__ = [
    "BUDGET_SAMPLES",
    "MAX_NEAR_SAMPLES",
    "MAX_WINDOW_SAMPLES",
    "MIN_WINDOW_SAMPLES",
    "NEAR_SIDES",
    "WINDOW_SPACINGS",
    "WindowPlan",
    "score_candidates",
    "window_order",
]

#: Window side in mean spacings of the fit subset, sqrt(area / n_fit): a window this wide
#: holds many lags below the subset's spacing, which the subset cannot see.
WINDOW_SPACINGS = 5.0
#: Fewest left-out samples a window needs to be scored.
MIN_WINDOW_SAMPLES = 30
#: Most samples one window keeps (a seeded random subset beyond it): its exact factor costs
#: n^3 / 3 per candidate.
MAX_WINDOW_SAMPLES = 800
#: Most left-out samples scored in all (the windows' cost per candidate grows with it).
BUDGET_SAMPLES = 16_000
#: Radius, in window sides from a window's centre, of the subset samples it is conditioned
#: on: its corners lie 0.71 side out, so every scored sample has subset samples 0.29 side
#: (1.5 subset spacings) beyond it on every side.
NEAR_SIDES = 1.0
#: Most subset samples one window is conditioned on (the nearest; ~80 at the mean density).
MAX_NEAR_SAMPLES = 300


@dataclass(frozen=True)
class WindowPlan:
    """Square windows of the samples outside the fit subset.

    Attributes
    ----------
    X : list of ndarray of shape (n_w, 2)
        Each window's sample locations, centred on the window, m.
    r : list of ndarray of shape (n_w,)
        Each window's samples minus the prior mean, m.
    z_var : list of ndarray of shape (n_w,)
        Each window's stated noise variances, m^2.
    side : float
        Window side, m.
    n_left_out : int
        Samples outside the fit subset.
    n_capped : int
        Left-out samples inside scored windows but beyond :data:`MAX_WINDOW_SAMPLES`.
    n_sparse : int
        Left-out samples in windows with fewer than :data:`MIN_WINDOW_SAMPLES`.
    n_over_budget : int
        Left-out samples in windows beyond :data:`BUDGET_SAMPLES`. The four counts add up
        to ``n_left_out``.
    X_near, r_near, z_var_near : list of ndarray, optional
        Each window's conditioning set: the fit subset's samples near it (same frame as
        ``X``). ``None``: no window is conditioned on anything.
    """

    X: list
    r: list
    z_var: list
    side: float
    n_left_out: int
    n_capped: int
    n_sparse: int
    n_over_budget: int
    X_near: list | None = None
    r_near: list | None = None
    z_var_near: list | None = None

    @property
    def n_samples(self) -> int:
        """Samples scored in all."""
        return int(sum(x.shape[0] for x in self.X))

    def transformed(self, matrix: np.ndarray) -> WindowPlan:
        """The same windows in the coordinates ``x @ matrix.T`` (a linear map, m: the
        kernel's space of a geometric anisotropy, :mod:`terrain.anisotropy`)."""

        def move(xs: list | None) -> list | None:
            return None if xs is None else [x @ matrix.T for x in xs]

        return replace(self, X=move(self.X), X_near=move(self.X_near))

    @classmethod
    def build(
        cls,
        X: np.ndarray,
        r: np.ndarray,
        z_var: np.ndarray,
        fit_index: np.ndarray,
        rng: np.random.Generator,
    ) -> WindowPlan | None:
        """Windows of the samples not in ``fit_index``; ``None`` when none holds enough.

        Parameters
        ----------
        X : ndarray of shape (n, 2)
            All sample locations, m.
        r : ndarray of shape (n,)
            All samples minus the prior mean, m.
        z_var : ndarray of shape (n,)
            Stated noise variances, m^2.
        fit_index : ndarray of int
            The fit subset's rows.
        rng : numpy.random.Generator
            Orders the windows and thins the crowded ones.
        """
        n = r.size
        rest = np.ones(n, bool)
        rest[np.asarray(fit_index, int)] = False
        n_fit = n - int(rest.sum())
        if rest.sum() < MIN_WINDOW_SAMPLES or n_fit < 3:
            return None
        lo, hi = X.min(axis=0), X.max(axis=0)
        area = float(np.prod(np.maximum(hi - lo, 1e-9)))
        side = WINDOW_SPACINGS * np.sqrt(area / n_fit)
        idx = np.flatnonzero(rest)
        cell = np.floor((X[idx] - lo) / side).astype(np.int64)
        rows = int(cell[:, 1].max()) + 1
        key = cell[:, 0] * rows + cell[:, 1]
        order = np.argsort(key, kind="stable")
        keys, starts = np.unique(key[order], return_index=True)
        groups = np.split(idx[order], starts[1:])
        sizes = np.array([g.size for g in groups])
        n_sparse = int(sizes[sizes < MIN_WINDOW_SAMPLES].sum())
        fit = np.asarray(fit_index, int)
        tree = cKDTree(X[fit])
        wx, wr, wv, nx, nr, nv = [], [], [], [], [], []
        used = capped = over = 0
        scored = np.where(sizes >= MIN_WINDOW_SAMPLES, np.minimum(sizes, MAX_WINDOW_SAMPLES), 0)
        for k in window_order(keys // rows, keys % rows, scored, rng):
            g = groups[k]
            if g.size < MIN_WINDOW_SAMPLES:
                continue
            if used >= BUDGET_SAMPLES:
                over += g.size
                continue
            if g.size > MAX_WINDOW_SAMPLES:
                capped += g.size - MAX_WINDOW_SAMPLES
                g = np.sort(rng.choice(g, MAX_WINDOW_SAMPLES, replace=False))
            centre = X[g].mean(axis=0)
            # the subset's samples near the window, nearest first (ties by row: same bits)
            dist, near = tree.query(centre, k=min(MAX_NEAR_SAMPLES, fit.size))
            near = fit[np.atleast_1d(near)[np.atleast_1d(dist) <= NEAR_SIDES * side]]
            wx.append(X[g] - centre)
            wr.append(np.asarray(r[g], float))
            wv.append(np.asarray(z_var[g], float))
            nx.append(X[near] - centre)
            nr.append(np.asarray(r[near], float))
            nv.append(np.asarray(z_var[near], float))
            used += g.size
        if not wx:
            return None
        counts = (int(rest.sum()), capped, n_sparse, over)
        return cls(wx, wr, wv, float(side), *counts, nx, nr, nv)

    def describe(self) -> str:
        """The plan's size and counts as JSON (a product's provenance)."""
        return json.dumps(
            {
                "windows": len(self.X),
                "side_m": round(self.side, 3),
                "conditioned_on": sum(x.shape[0] for x in self.X_near or []),
                "samples_scored": self.n_samples,
                "left_out": self.n_left_out,
                "beyond_window_cap": self.n_capped,
                "in_sparse_windows": self.n_sparse,
                "beyond_budget": self.n_over_budget,
            }
        )

    def lml(self, kernel, nugget: float) -> float:
        """Sum over the windows of ``log p(r_w | r_near)``, nats.

        Each window: the joint covariance ``C = K + diag(z_var + nugget)`` of its
        conditioning set (first) and its own samples is factored, ``C = L L^T``; the lower
        right block of ``L`` factors the conditional covariance, so with ``u = L^-1 r``
        the term is ``-1/2 (sum_w u^2 + 2 sum_w log L_ii + n_w log 2 pi)`` (R&W Eq A.6;
        one factor instead of two). ``-inf`` when a window's ``C`` does not factor.
        """
        total = 0.0
        near = self.X_near or [np.zeros((0, 2))] * len(self.X)
        r_near = self.r_near or [np.zeros(0)] * len(self.X)
        v_near = self.z_var_near or [np.zeros(0)] * len(self.X)
        # Kernel matrices from a distance table (terrain.radial_table): a window's samples
        # lie within sqrt(2) sides of its centre (their mean, inside their square), its
        # conditioning set within NEAR_SIDES sides, so no two lie farther apart than the sum.
        kern = tabulate(kernel, (np.sqrt(2.0) + NEAR_SIDES) * self.side) or kernel
        windows = zip(self.X, self.r, self.z_var, near, r_near, v_near, strict=True)
        for X, r, v, Xn, rn, vn in windows:
            XX = np.concatenate([Xn, X])
            C = kern(XX)
            C[np.diag_indices_from(C)] += np.concatenate([vn, v]) + nugget
            # One factor, one triangular solve; both release the GIL
            # (terrain.nogil_lapack), so the candidates' threads run side by side.
            L = cholesky_lower(C)
            if L is None:
                return -np.inf
            u = solve_lower(L, np.asfortranarray(np.concatenate([rn, r])[:, None]))[:, 0]
            m = Xn.shape[0]
            logdet = 2.0 * float(np.log(np.diag(L)[m:]).sum())
            total += -0.5 * (float(u[m:] @ u[m:]) + logdet + r.size * np.log(2.0 * np.pi))
        return total


def window_order(
    column: np.ndarray, row: np.ndarray, scored: np.ndarray, rng: np.random.Generator
) -> np.ndarray:
    """The order in which the windows are taken until :data:`BUDGET_SAMPLES` is spent.

    Where every window fits the budget, a seeded permutation: all are taken. Otherwise the
    windows taken are a *systematic sample along a serpentine path* through the cells (up
    one column of cells and down the next; a seeded random start, a stride of the scored
    samples over the budget), then the others in seeded random order. Neighbouring windows
    tell alike (on bei with the 8 x 8 prior at 30,000 samples, the Matérn 7/2 minus SE
    difference of adjacent windows correlates at 0.26), so a sample spread evenly over the
    site varies less from seed to seed than a random one: sd 3.8 against 5.9 nats for that
    difference over 400 draws of 47 of its 81 windows (docs/terrain.md "Windows spread over
    the site"; a spatially balanced sample, as in Stevens & Olsen 2004).

    Parameters
    ----------
    column, row : ndarray of int, shape (n_windows,)
        Each window's cell.
    scored : ndarray of int, shape (n_windows,)
        Samples each window would score (0: too few to be scored).
    rng : numpy.random.Generator
        Draws the start and the others' order.

    Returns
    -------
    ndarray of int, shape (n_windows,)
        A permutation of the windows.
    """
    n = scored.size
    total = int(scored.sum())
    if total <= BUDGET_SAMPLES:
        return rng.permutation(n)
    path = np.lexsort((np.where(column % 2 == 0, row, -row), column))
    path = path[scored[path] > 0]
    stride = total / BUDGET_SAMPLES  # windows along the path per window taken, > 1
    start = rng.uniform(0.0, stride)
    first = path[np.arange(start, path.size, stride).astype(int)]
    others = np.setdiff1d(np.arange(n), first)
    return np.concatenate([first, others[rng.permutation(others.size)]])


def score_candidates(
    rows: list[dict[str, Any]],
    fits: dict[str, Any],
    windows: WindowPlan | None,
    workers: int | None,
    values: dict[str, float | None] | None = None,
) -> None:
    """Set each candidate row's ``window_lml`` (nats) and ``score`` (``bic - 2 window_lml``).

    ``rows`` carry ``name`` and ``bic``; ``fits[name]`` is ``(kernel, nugget, lml, nfev)``
    as fitted on the subset. Without windows, or when no candidate factors them, the score
    is the BIC; a candidate whose windows do not factor scores ``inf``. The candidates run
    in threads and give the same values for any number. ``values``: each row's
    ``windows.lml`` already computed (by name; the kernel search scores each fit in its
    own thread as soon as it is fitted), so none is computed here.
    """
    if windows is None:
        for row in rows:
            row.update(window_lml=None, score=row["bic"])
        return

    def lml(row: dict[str, Any]) -> float:
        kernel, nugget = fits[row["name"]][:2]
        return windows.lml(kernel, nugget)

    if values is not None:
        got = [values[row["name"]] for row in rows]
    else:
        w = max(1, workers if workers is not None else os.cpu_count() or 1)
        with threadpool_limits(1), ThreadPoolExecutor(max_workers=w) as pool:
            got = list(pool.map(lml, rows))
    factored = any(np.isfinite(v) for v in got)
    for row, v in zip(rows, got, strict=True):
        if not factored:
            row.update(window_lml=None, score=row["bic"])
        else:
            row.update(window_lml=v, score=row["bic"] - 2.0 * v if np.isfinite(v) else np.inf)
        row.update(window_samples=windows.n_samples, window_side_m=windows.side)
