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
wide, and each window's restricted likelihood (Patterson & Thompson 1971; Eq 9 with a plane
drift whose coefficients are integrated out, R&W §2.7) is computed exactly. The plane takes
out the scales the window shares with the subset, so what is scored is the ground between
the subset's samples; the windows do not overlap and are summed as independent blocks (a
block composite likelihood: Caragea & Smith 2007; Eidsvik et al. 2014). The candidates'
score is then ``BIC - 2 * window_lml``.

Windows: side :data:`WINDOW_SPACINGS` x the subset's mean spacing, at least
:data:`MIN_WINDOW_SAMPLES` samples each, at most :data:`MAX_WINDOW_SAMPLES` (a seeded
random subset beyond it), taken in a seeded random order up to :data:`BUDGET_SAMPLES`
samples in all. Below :data:`MIN_WINDOW_SAMPLES` left-out samples per window (a survey the
subset holds almost whole) there are no windows and the score is the BIC alone.
"""

from __future__ import annotations

import json
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.linalg import LinAlgError, cho_factor, cho_solve
from threadpoolctl import threadpool_limits

from .nogil_lapack import cholesky_lower, solve_lower
from .radial_table import tabulate

__all__ = [
    "BUDGET_SAMPLES",
    "MAX_WINDOW_SAMPLES",
    "MIN_WINDOW_SAMPLES",
    "WINDOW_SPACINGS",
    "WindowPlan",
    "score_candidates",
]

#: Window side in mean spacings of the fit subset, sqrt(area / n_fit): the plane of a
#: window this wide leaves the lags below a few subset spacings, which the subset cannot see.
WINDOW_SPACINGS = 5.0
#: Fewest left-out samples a window needs to be scored (a plane takes three of them).
MIN_WINDOW_SAMPLES = 30
#: Most samples one window keeps (a seeded random subset beyond it): its exact factor costs
#: n^3 / 3 per candidate.
MAX_WINDOW_SAMPLES = 800
#: Most left-out samples scored in all (the windows' cost per candidate grows with it).
BUDGET_SAMPLES = 16_000


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
    """

    X: list
    r: list
    z_var: list
    side: float
    n_left_out: int
    n_capped: int
    n_sparse: int
    n_over_budget: int

    @property
    def n_samples(self) -> int:
        """Samples scored in all."""
        return int(sum(x.shape[0] for x in self.X))

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
        key = cell[:, 0] * (int(cell[:, 1].max()) + 1) + cell[:, 1]
        order = np.argsort(key, kind="stable")
        keys, starts = np.unique(key[order], return_index=True)
        groups = np.split(idx[order], starts[1:])
        sizes = np.array([g.size for g in groups])
        n_sparse = int(sizes[sizes < MIN_WINDOW_SAMPLES].sum())
        wx, wr, wv = [], [], []
        used = capped = over = 0
        for k in rng.permutation(keys.size):
            g = groups[k]
            if g.size < MIN_WINDOW_SAMPLES:
                continue
            if used >= BUDGET_SAMPLES:
                over += g.size
                continue
            if g.size > MAX_WINDOW_SAMPLES:
                capped += g.size - MAX_WINDOW_SAMPLES
                g = np.sort(rng.choice(g, MAX_WINDOW_SAMPLES, replace=False))
            wx.append(X[g] - X[g].mean(axis=0))
            wr.append(np.asarray(r[g], float))
            wv.append(np.asarray(z_var[g], float))
            used += g.size
        if not wx:
            return None
        return cls(wx, wr, wv, float(side), int(rest.sum()), capped, n_sparse, over)

    def describe(self) -> str:
        """The plan's size and counts as JSON (a product's provenance)."""
        return json.dumps(
            {
                "windows": len(self.X),
                "side_m": round(self.side, 3),
                "samples_scored": self.n_samples,
                "left_out": self.n_left_out,
                "beyond_window_cap": self.n_capped,
                "in_sparse_windows": self.n_sparse,
                "beyond_budget": self.n_over_budget,
            }
        )

    def lml(self, kernel, nugget: float) -> float:
        """Sum over the windows of the restricted log likelihood with a plane drift, nats.

        Each window: ``-1/2 (r^T P r + log|C| + log|H^T C^-1 H| + (n - 3) log 2 pi)`` with
        ``C = K + diag(z_var + nugget)``, ``H = [1, x, y]`` and ``P = C^-1 - C^-1 H (H^T
        C^-1 H)^-1 H^T C^-1`` (Harville 1974). ``-inf`` when a window's ``C`` does not
        factor.
        """
        total = 0.0
        # Kernel matrices from a distance table (terrain.radial_table): a window's samples
        # lie in a square of side `side`, so no distance exceeds its diagonal.
        kern = tabulate(kernel, np.sqrt(2.0) * self.side) or kernel
        for X, r, v in zip(self.X, self.r, self.z_var, strict=True):
            C = kern(X)
            C[np.diag_indices_from(C)] += v + nugget
            # One factor, one triangular solve for [H, r]; both release the GIL
            # (terrain.nogil_lapack), so the candidates' threads run side by side.
            L = cholesky_lower(C)
            if L is None:
                return -np.inf
            B = np.asfortranarray(np.column_stack([np.ones(X.shape[0]), X, r]))
            W = solve_lower(L, B)  # [L^-1 H, L^-1 r]
            Wh, u = W[:, :3], W[:, 3]
            try:  # H^T C^-1 H = Wh^T Wh, H^T C^-1 r = Wh^T u, r^T C^-1 r = u^T u
                g = cho_factor(Wh.T @ Wh, lower=True, check_finite=False)
            except (LinAlgError, ValueError):
                return -np.inf
            Hr = Wh.T @ u
            quad = float(u @ u - Hr @ cho_solve(g, Hr, check_finite=False))
            logdet = 2.0 * float(np.log(np.diag(L)).sum() + np.log(np.diag(g[0])).sum())
            total += -0.5 * (quad + logdet + (r.size - 3) * np.log(2.0 * np.pi))
        return total


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
