"""The kernel chosen by evidence: ``TerrainGP(kernel="auto")``.

Real terrain is not one stationary squared exponential. A single SE fitted to a real DEM
gave 1.41x Delaunay's RMSE with half the truth outside its 95 % interval, while a two-scale
Matérn 5/2 gave 0.75x and 93 % (docs/architecture.md §5). Which family suits a site is a
question for the data, so ``"auto"`` fits a small family and keeps the one with the best penalised
evidence:

    BIC = -2 log p(y | theta_hat) + p log n        (Eq 9 at the fitted theta, p parameters)

on the fit subset (Schwarz 1978). The family: SE (Eq 1), Matérn 3/2, 5/2 and 7/2, and the
two-scale sums SE + SE and Matérn ν + Matérn ν (a short scale for the rover-scale relief,
a long one for the glacier's shape). The Matérn 7/2 (three times differentiable) fills the
gap between 5/2 and the SE's infinite smoothness: with dense data a cell's σ is set by the
kernel near the origin, and terrain smoother than 5/2 but rougher than SE read 68 % bands
of 77-78 % at 50,000 samples with the six-member family (docs/terrain.md "Matérn 7/2").
Every candidate is fitted by maximizing the Vecchia likelihood (:mod:`terrain.vecchia`,
m = 10 earlier neighbours from doubling blocks, the winner refined at m = 25) with
L-BFGS-B and its exact gradient, started from the best of a small grid of length scales
(single kernels) or from the family's single fit split into two scales (sums). That
likelihood is not Eq 9 to a few nats on dense data (docs/terrain.md "The kernel search's
likelihood is not Eq 9 to a few nats"). Why BIC and not cross-validated NLPD: docs/terrain.md
"Kernel by evidence". The samples the subset leaves out add their evidence, in windows,
to each candidate's score (:mod:`terrain.window_evidence`).
"""

from __future__ import annotations

import os
import warnings
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import minimize
from scipy.spatial import cKDTree
from threadpoolctl import threadpool_limits

from .candidate_cv import cv_folds, cv_scores
from .errors import DegenerateFitWarning, NumericalError, bad_input
from .heldout_weights import sample_spacing
from .kernels import Matern, SquaredExponential
from .tiled import shortest_lengthscale
from .vecchia import VecchiaPlan, vecchia_lml
from .window_evidence import WindowPlan, score_candidates

__all__ = [
    "FAMILY",
    "KernelChoice",
    "candidate_names",
    "median_spacing",
    "se_sum_inside_gaps",
    "select_kernel",
    "warn_if_degenerate",
]

#: Candidate names of ``kernel="auto"`` and how each single part is built.
_PARTS = {
    "se": lambda v, ls, b: SquaredExponential(v, ls, **b),
    "matern32": lambda v, ls, b: Matern(v, ls, nu=1.5, **b),
    "matern52": lambda v, ls, b: Matern(v, ls, nu=2.5, **b),
    "matern72": lambda v, ls, b: Matern(v, ls, nu=3.5, **b),
}
FAMILY = (
    "se",
    "matern32",
    "matern52",
    "matern72",
    "se+se",
    "matern32+matern32",
    "matern52+matern52",
    "matern72+matern72",
)
#: L-BFGS-B's relative stop while the candidates are screened (the winner: REFINE_FTOL):
#: with |lml| ~ 500-3000 nats it stops within ~0.01-0.03 nats, far inside BIC_TIE. Measured on
#: four real DEMs at 50k: the same picks, BICs within 0.3, fit CPU -13 to -19 % (1e-7 before).
SCREEN_FTOL = 1e-5
#: The same stop for the winner's refine at m = 25. 1e-6 was measured in session 29 (14-16
#: evaluations instead of 26-38 at 50k, the likelihood within 0.07-0.5 nats) and not taken:
#: its effect on the maps could not be told apart from the refine order's own
#: (docs/terrain.md "The refine's order").
REFINE_FTOL = 1e-7
#: Pieces of each likelihood evaluation of the refine, evaluated over threads.
REFINE_PARTS = 2
#: Mean-square differentiability of each part (Matérn nu; SE: infinitely smooth).
_SMOOTHNESS = {"se": np.inf, "matern32": 1.5, "matern52": 2.5, "matern72": 3.5}
#: BIC margin below which the evidence is not "strong" (Kass & Raftery 1995: 2-6 positive,
#: 6-10 strong): within it a Matern is kept over an SE-based winner (docs/terrain.md
#: "Near ties").
BIC_TIE = 6.0
#: The margin a *single* SE winner needs over the best Matern (Kass & Raftery's "very
#: strong", 2 ln B > 10). One SE length must carry every scale of the ground, and its
#: analytic paths make it over-confident between dense data: on real DEMs at 50,000
#: samples with the 8 x 8 prior, single SEs 7-9 BIC ahead of a Matern 7/2 covered 89.9-90.0 %
#: at 95, the Matern 7/2 94.8-96.4 %; leads of 18-45 (line surveys, topobathy, the default
#: site drawn from Eq 1) were in band (docs/terrain.md "Ten windows never looked at, and
#: a single SE needs very strong evidence").
SINGLE_SE_MARGIN = 10.0


def se_sum_inside_gaps(name: str, kernel: Any, widest_gap: float | None) -> bool:
    """Whether an SE + SE winner keeps a near tie: its short length scale is at most the
    survey's widest gap (m).

    The near-tie rule guards against the SE's infinite smoothness carrying confidence
    across the gaps between swaths (Stein 1999, §1.7). A two-scale sum whose short part is
    no longer than the widest gap reverts to that part's full variance inside the gaps, so
    the guard is not needed, and the Matern it would pick was the rougher model: 68 % bands
    of 76-79 % at 3k and 50k. Measured on eleven real DEMs (docs/terrain.md "Near ties
    revisited"): SE + SE fits with short scales of 8-15 m covered 67-76 % / 92-96 %. The
    over-confident ones (glacier, bei: 86 % and 75 % at 95) had short scales of 38-56 m,
    beyond the 30 m widest gap of 3,000 samples. A single SE always takes the guard.
    """
    if widest_gap is None or name != "se+se":
        return False
    return shortest_lengthscale(kernel) <= float(widest_gap)


def smoothness(name: str) -> float:
    """Smoothness of a family name: the smallest nu of its parts (``inf`` for SE only)."""
    return min(_SMOOTHNESS[part] for part in name.split("+"))


def candidate_names(kernel: Any) -> tuple[str, ...]:
    """The candidate list for a ``kernel=`` setting: ``"auto"``, one family name, or a list."""
    names = FAMILY if isinstance(kernel, str) and kernel == "auto" else kernel
    names = (names,) if isinstance(names, str) else tuple(names)
    for n in names:
        if n not in FAMILY:
            raise bad_input(
                "kernel",
                n,
                f'"auto", a Kernel object, or family names among {list(FAMILY)}',
                'use kernel="auto" to choose by evidence, or e.g. kernel="matern52+matern52"',
            )
    if not names:
        raise bad_input("kernel", kernel, "at least one family name", 'kernel="auto"')
    return names


@dataclass
class KernelChoice:
    """The winner of the search and every candidate's score (best first)."""

    kernel: Any
    nugget: float
    name: str
    scores: list[dict[str, Any]] = field(default_factory=list)
    n_fit: int = 0
    neighbours: int = 0  # Vecchia m of the final (refined) fit


def median_spacing(X: np.ndarray) -> float:
    """Median distance from each sample to its nearest neighbour, m (shape (n, 2) in):
    :func:`terrain.heldout_weights.sample_spacing`."""
    return sample_spacing(X)


def warn_if_degenerate(kernel: Any, X: np.ndarray | None, spacing: float | None = None) -> bool:
    """Warn (:class:`DegenerateFitWarning`) when the shortest length scale is below 3/4 of
    the median sample spacing of ``X`` (n, 2; ``spacing``, m, when known): the kernel then
    imitates white noise and the map is flat between samples. Returns whether it warned."""
    if X is None or X.shape[0] < 2:
        return False
    spacing = median_spacing(X) if spacing is None else float(spacing)
    parts = getattr(kernel, "parts", (kernel,))
    ls = float(min(np.min(p.lengths) for p in parts))
    if ls >= 0.75 * spacing:
        return False
    warnings.warn(
        f"degenerate fit: the shortest length scale {ls:.3g} m is below the median sample "
        f"spacing {spacing:.3g} m, so the map is flat between samples and reverts to its "
        "mean. Check the samples' units and CRS, use kernel='auto', or give a prior mean that "
        "holds the terrain's shape.",
        DegenerateFitWarning,
        stacklevel=3,
    )
    return True


class FamilySearch:
    """One search over the family on one fit subset (shared plan and bounds): Vecchia
    likelihoods (``lml``) and L-BFGS-B fits (``optimize``, ``single``, ``pair``)."""

    def __init__(self, X, r, z_var, fit_nugget, nugget, nugget_bounds, spacing, m, rng, ftol):
        self.X, self.r, self.z_var = X, r, z_var
        self.ftol = ftol  # L-BFGS-B's relative reduction stop
        self.fit_nugget, self.nugget = fit_nugget, float(nugget)
        self.nugget_bounds = nugget_bounds
        self.plan = VecchiaPlan.build(X, m, rng)
        self.pool, self.parts = None, 1  # the refine's single chain: REFINE_PARTS in threads
        extent = float(np.ptp(X, axis=0).max()) or 1.0
        var = float(np.var(r)) or 1.0
        self.var = var
        # A length scale below half the sample spacing cannot be learnt from these data:
        # the optimizer would use it to mimic white noise (a degenerate, flat map).
        self.ls_bounds = (max(0.5 * spacing, 1e-3 * extent, 0.05), 5.0 * extent)
        self.var_bounds = (1e-6 * var, 100.0 * var)
        self.extent = extent

    # -- hyperparameter vector: log([kernel params..., nugget]) -----------------------
    def _bounds(self, kernel) -> np.ndarray:
        b = kernel.bounds
        return np.vstack([b, np.log(self.nugget_bounds)]) if self.fit_nugget else b

    def _split(self, theta, kernel):
        k = kernel.n_params
        nug = float(np.exp(theta[k])) if self.fit_nugget else self.nugget
        return kernel.with_theta(theta[:k]), nug

    def lml(self, kernel, nugget, grad=False):
        nv = self.z_var + nugget
        nug = nugget if self.fit_nugget else None
        return vecchia_lml(
            kernel, self.X, self.r, nv, self.plan, grad, nug, pool=self.pool, parts=self.parts
        )

    def part(self, name, v, ls):
        b = {"variance_bounds": self.var_bounds, "lengthscale_bounds": self.ls_bounds}
        v = float(np.clip(v, *self.var_bounds))
        ls = float(np.clip(ls, *self.ls_bounds))
        return _PARTS[name](v, ls, b)

    def optimize(self, kernel, nugget, maxiter=200, ftol=None):
        bounds = self._bounds(kernel)

        def objective(theta):
            k, nug = self._split(theta, kernel)
            try:
                val, g = self.lml(k, nug, grad=True)
            except NumericalError:
                return np.inf, np.zeros_like(theta)
            return -val, -g

        theta0 = kernel.theta
        if self.fit_nugget:
            theta0 = np.append(theta0, np.log(nugget))
        theta0 = np.clip(theta0, bounds[:, 0], bounds[:, 1])
        res = minimize(
            objective,
            theta0,
            jac=True,
            method="L-BFGS-B",
            bounds=bounds,
            options={"maxiter": maxiter, "ftol": self.ftol if ftol is None else ftol},
        )
        if not np.isfinite(res.fun):
            return None
        k, nug = self._split(res.x, kernel)
        return k, nug, float(-res.fun), int(res.nfev)

    def single(self, name, nugget0):
        """Best start on a grid of length scales, then L-BFGS-B."""
        lo, hi = self.ls_bounds
        grid = np.geomspace(max(lo * 2, self.extent / 200), min(hi, self.extent / 2), 7)
        v0 = max(self.var - nugget0, 1e-3 * self.var)
        best = None
        for ls in grid:
            k = self.part(name, v0, ls)
            try:
                val = self.lml(k, nugget0)
            except NumericalError:
                continue
            if best is None or val > best[0]:
                best = (val, k)
        if best is None:
            return None
        return self.optimize(best[1], nugget0)

    def pair(self, name, single, nugget0):
        """Two scales of one family, started from its single fit split in two."""
        if single is None:
            return None
        k1, nug, _, _ = single
        v, ls = k1.variance, float(k1.lengths[0])
        starts = [
            self.part(name, 0.3 * v, 0.5 * ls) + self.part(name, v, 4.0 * ls),
            self.part(name, v, ls) + self.part(name, 0.1 * v, 0.2 * ls),
        ]
        out = None
        for start in starts:
            fit = self.optimize(start, max(nug, nugget0 * 0.1))
            if fit is not None and (out is None or fit[2] > out[2]):
                out = fit
        return out


def nugget_start(search: FamilySearch, fit_nugget: bool, nugget: float, bounds: Any) -> float:
    """Nugget start: what nearest-neighbour differences show beyond the stated noise."""
    if not fit_nugget:
        return float(nugget)
    _, nn = cKDTree(search.X).query(search.X, k=2)
    semiv = 0.5 * float(np.median((search.r - search.r[nn[:, 1]]) ** 2))
    lo, hi = bounds
    return float(np.clip(max(semiv - float(np.mean(search.z_var)), 1e-3 * search.var), lo, hi))


def select_kernel(
    X: np.ndarray,
    r: np.ndarray,
    z_var: np.ndarray,
    names: tuple[str, ...],
    *,
    fit_nugget: bool,
    nugget: float,
    nugget_bounds: Any,
    spacing: float | None,
    neighbours: tuple[int, int] = (10, 25),
    criterion: str = "bic",
    gap: float | None = None,
    widest_gap: float | None = None,
    windows: WindowPlan | None = None,
    rng: np.random.Generator,
    workers: int | None = None,
) -> KernelChoice:
    """Fit each candidate by the Vecchia likelihood and keep the best BIC (a near tie, within
    :data:`BIC_TIE`, between an SE-based winner and a Matern goes to the Matern, unless the
    winner is an SE + SE whose short scale fits inside the survey's widest gap:
    :func:`se_sum_inside_gaps`; a single SE keeps its win only beyond
    :data:`SINGLE_SE_MARGIN`).

    Parameters
    ----------
    X : ndarray of shape (n, 2)
        Fit-subset locations, centred, m.
    r : ndarray of shape (n,)
        Samples minus the prior mean, m.
    z_var : ndarray of shape (n,)
        Stated per-sample variance, m^2 (Eq 6).
    names : tuple of str
        Candidates among :data:`FAMILY`.
    fit_nugget, nugget, nugget_bounds
        As in :class:`terrain.TerrainGP`.
    spacing : float, optional
        Median nearest-neighbour spacing of *all* samples, m (lower length-scale bound:
        half of it); default: that of ``X``.
    neighbours : (int, int)
        Vecchia conditioning-set sizes m: every candidate is screened with the first (cheap,
        ~6x faster than m = 25), the winner refined with the second.
    criterion : {"cv_nlpd", "bic"}
        Keep the lowest BIC (default) or the lowest spatial-block cross-validated NLPD
        (each candidate's CV scores are then computed and recorded; not with the BIC).
    gap : float, optional
        Median distance from the map's cells to their nearest sample, m: sets the CV block
        size (4 x gap, so held-out samples sit as far from data as the map's gaps);
        default: measured on the bounding box of ``X``.
    widest_gap : float, optional
        The survey's widest gap, m (:func:`terrain.tiled.largest_gap` of *all* samples):
        an SE + SE winner whose short scale is at most this keeps a near tie. Default
        ``None``: every near tie goes to the Matern.
    windows : terrain.window_evidence.WindowPlan, optional
        The samples outside the fit subset: candidates are scored ``BIC - 2 * window_lml``
        (their evidence by the chain rule), near ties read that score. ``None``: the BIC.
    rng : numpy.random.Generator
        Orders the Vecchia plan and deals the CV blocks.
    workers : int, optional
        Threads fitting the candidate families side by side (default: the number of CPUs);
        the choice and every score are the same for any number.

    Returns
    -------
    KernelChoice
        ``scores`` rows: name, kernel (repr), lml (nats, the Vecchia likelihood of Eq 9
        named in ``likelihood``), n_params, bic, delta_bic (to the best), window_lml
        (nats, or None), score (``bic - 2 window_lml``, or the BIC), delta_score, nugget,
        evaluations, likelihood, selected; with ``criterion="cv_nlpd"`` also cv_nlpd,
        cv_coverage_95, cv_z_std, cv_variance_ratio and cv_block_m.
    """
    if criterion not in ("bic", "cv_nlpd"):
        raise bad_input("criterion", criterion, '"bic" or "cv_nlpd"', 'criterion="bic"')
    n = r.size
    spacing = median_spacing(X) if spacing is None else float(spacing)
    m_screen, m_refine = neighbours
    args = (X, r, z_var, fit_nugget, nugget, nugget_bounds, spacing)
    search = FamilySearch(*args, m_screen, rng, SCREEN_FTOL)
    nug0 = nugget_start(search, fit_nugget, nugget, nugget_bounds)
    # One chain per family: its single fit, then the two-scale fit started from it. The
    # chains share nothing but the plan (read-only) and use no random numbers, so they run
    # in threads (numpy and LAPACK release the GIL) and give the same fits, bit for bit,
    # whatever the number of threads; the results are gathered in family order.
    groups: dict[str, list[str]] = {}
    for name in sorted(set(names), key=lambda s: "+" in s):  # singles first
        groups.setdefault(name.split("+")[0], []).append(name)

    # Each fit's window evidence is scored in its chain's thread as soon as it is fitted: no
    # barrier between the fits and the windows (at 50k it left a core idle 0.2-0.4 s).
    def chain(base: str) -> dict[str, Any]:
        single = search.single(base, nug0)
        out = {}
        for name in groups[base]:
            fit = single if "+" not in name else search.pair(base, single, nug0)
            win = None if windows is None or fit is None else windows.lml(*fit[:2])
            out[name] = (fit, win)
        return out

    fits: dict[str, Any] = {}
    window_lml: dict[str, float | None] = {}
    workers = max(1, min(len(groups), workers if workers is not None else os.cpu_count() or 1))
    with threadpool_limits(1), ThreadPoolExecutor(max_workers=workers) as pool:
        for out in pool.map(chain, groups):
            for name, (fit, win) in out.items():
                fits[name], window_lml[name] = fit, win
    rows = []
    for name in names:
        fit = fits.get(name)
        if fit is None:
            rows.append({"name": name, "lml": None, "bic": None, "error": "no start factored"})
            continue
        k, nug, lml, nfev = fit
        p = k.n_params + int(fit_nugget)
        rows.append(
            {
                "name": name,
                "kernel": repr(k),
                "lml": lml,
                "n_params": p,
                "bic": -2.0 * lml + p * np.log(n),
                "nugget": nug,
                "evaluations": nfev,
                # not Eq 9 to a few nats on dense data: docs/terrain.md (session 20)
                "likelihood": f"Vecchia, doubling blocks, m = {m_screen}",
            }
        )
    scored = [row for row in rows if row["bic"] is not None]
    # The folds are dealt from the main stream even when the BIC ranks: the refine's plan is
    # drawn next, and its order moves the refined nugget, hence the 1-sigma (docs/terrain.md
    # "The refine's order"): a criterion, or a speed-up, does not redraw it.
    folds, block = cv_folds(X, gap, spacing, rng)
    if criterion == "cv_nlpd":  # 0.1 thread-s a candidate at 2,000 samples: only when it ranks

        def cv(row: dict[str, Any]) -> dict[str, float]:
            k, nug, _, _ = fits[row["name"]]
            return cv_scores(k, nug, X, r, z_var, folds)

        with threadpool_limits(1), ThreadPoolExecutor(max_workers=workers) as pool:
            for row, scores in zip(scored, pool.map(cv, scored), strict=True):
                row.update(scores, cv_block_m=block)
    score_candidates(scored, fits, windows, workers, values=window_lml)
    key = "score" if criterion == "bic" else "cv_nlpd"
    ok = [r_ for r_ in rows if r_["bic"] is not None]
    if not ok:
        raise NumericalError(
            "no candidate kernel could be fitted (every start failed to factor). Fix: check "
            "the samples for duplicates with conflicting z, or pass a larger nugget."
        )
    ok.sort(key=lambda r_: r_[key])
    best = ok[0]
    if criterion == "bic":
        # A near tie between an SE-based winner and a Matern goes to the Matern: the
        # evidence cannot tell them apart, and the SE's infinite smoothness is what makes
        # sigma over-confident in the gaps between swaths (Stein 1999, Interpolation of
        # Spatial Data, 1.7; measured on real DEMs: docs/terrain.md "Near ties").
        # A single SE must lead by more: one length carries every scale (SINGLE_SE_MARGIN).
        margin = SINGLE_SE_MARGIN if best["name"] == "se" else BIC_TIE
        tied = [r_ for r_ in ok if r_["score"] - best["score"] <= margin]
        finite = [r_ for r_ in tied if np.isfinite(smoothness(r_["name"]))]
        kept = se_sum_inside_gaps(best["name"], fits[best["name"]][0], widest_gap)
        if not np.isfinite(smoothness(best["name"])) and finite and not kept:
            best = finite[0]  # ok is sorted by BIC
    low = min(r_["bic"] for r_ in ok)
    top = min(r_["score"] for r_ in ok)
    for r_ in rows:
        r_["selected"] = r_ is best
        r_["delta_bic"] = None if r_["bic"] is None else r_["bic"] - low
        r_["delta_score"] = None if r_["bic"] is None else r_["score"] - top
    rows.sort(key=lambda r_: (not r_["selected"], np.inf if r_["bic"] is None else r_[key]))
    k, nug, _, _ = fits[best["name"]]
    # Refine the winner on larger conditioning sets (closer to the exact Eq 9).
    refine = FamilySearch(*args, m_refine, rng, REFINE_FTOL)
    # One chain now: each likelihood's rows go in REFINE_PARTS pieces over the threads (the
    # pieces, not the thread count, fix the bits; measured: docs/terrain.md).
    refine.parts = REFINE_PARTS
    with threadpool_limits(1), ThreadPoolExecutor(max_workers=workers) as pool:
        refine.pool = pool if workers > 1 else None
        fine = refine.optimize(k, nug)
    if fine is not None:
        k, nug, lml, nfev = fine
        best.update(
            refined_lml=lml, refined_kernel=repr(k), refined_nugget=nug, refined_evaluations=nfev
        )
    return KernelChoice(k, nug, best["name"], rows, n, refine.plan.m)
