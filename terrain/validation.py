"""Spatial block cross-validation: the map's 1-sigma checked on held-out samples, no truth.

A GP on dense rover tracks predicts a randomly held-out sample from a neighbour a metre away,
so random point folds flatter it: they test interpolation along the tracks, not the map
between them. :func:`cross_validate` holds out whole square blocks of the survey instead
(Roberts et al. 2017, *Ecography* 40: 913, "block cross-validation"): the samples' bounding
box is cut into blocks of ``block_size`` metres on a lattice anchored at its south-west
corner, the non-empty blocks are shuffled with ``numpy.random.default_rng(seed)`` and dealt
greedily, each to the fold that holds the fewest samples so far (folds balanced by count).

Each fold is predicted by a clone of the estimator fitted on the other folds. A held-out
*sample* is an observation, not the surface: its predictive distribution is
``N(mu, sd_f^2 + nugget + z_var_i)``, with ``mu``, ``sd_f`` from
``predict(xy, return_std=True)``, the fitted ``nugget_`` and ``z_var_i`` the sample's own
stated variance (Eq 6). The scores use :mod:`terrain.metrics` on that distribution: coverage is a
fraction (0.6827 and 0.95 nominal), ``z = (obs - mu) / sd`` (the metrics' sign), while the
mean error is ``mu - obs`` (the certificate's sign: positive, the map is too high).

Those are the coverages of a new *measurement*. The map's own 1-sigma is checked through
them (:mod:`terrain.heldout_design`): the default block side is chosen so that held-out
samples lie as far from the data as the map's cells do (and, where it moves the check, are
matched to the map cells' whole neighbourhoods: :mod:`terrain.heldout_weights`), and the
map-level scores
(``variance_ratio``, ``map_coverage_68``, ``map_coverage_95``) remove the samples' noise,
which otherwise hides a map 1-sigma that is too small. Where held-out samples are dense,
planes through their neighbours average most of the noise away first
(:mod:`terrain.heldout_local_fit`), fitted to what each fold's prior mean leaves of the
elevations: a step the mean holds (:class:`terrain.BreaklineMean`) is not a plane's misfit.
The verdict speaks of those.

Cost: O(n log n) for the blocks plus one fit and one predict per fold in the estimator.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from numbers import Integral
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from .along_track import ALONG_TRACK_FRACTION, ALONG_TRACK_TAU_S
from .errors import bad_input
from .estimator_clone import clone, fixed_overrides, is_fitted
from .fold_fit import fold_predictor
from .heldout_blocks import design_folds, spatial_blocks, target_points
from .heldout_design import (
    along_track_shared,
    distance_weights,
    map_calibration,
)
from .heldout_local_fit import local_plane_residuals
from .heldout_verdict import coverage_verdict
from .heldout_weights import (
    effective_share,
    even_stride,
    heldout_neighbour_distances,
    neighbour_distances,
    neighbourhood_weights,
)
from .json_safe import json_safe
from .metrics import calibration_curve, interval_coverage, nlpd, rmse, standardized_error_stats
from .samples import ElevationSamples

__all__ = [
    "CrossValidation",
    "coverage_verdict",
    "cross_validate",
    "design_folds",
    "json_safe",
    "spatial_blocks",
    "target_points",
]

REFIT_MODES = ("hyperparameters-fixed", "all")
#: Quantile of held-out distances to the folds' data bounding the check's reach.
REACH_QUANTILE = 0.99


@dataclass(frozen=True, eq=False)
class CrossValidation:
    """Held-out scores of a GP map's mean and 1-sigma (:func:`cross_validate`).

    Attributes
    ----------
    folds : list of dict
        One row per fold: ``fold, n, n_train, n_blocks`` and the scores of ``pooled`` (no
        curve), plus ``kernel`` / ``nugget`` of the fold's fit when the estimator has them.
    pooled : dict
        Scores over every held-out sample: ``n``, ``rmse_m``, ``mean_error_m`` (mu - obs),
        ``nlpd`` (nats per sample), ``coverage_68``, ``coverage_95`` (fractions),
        ``z_mean``, ``z_std``, ``mean_sd_m`` and ``calibration`` ``{"levels", "observed"}``.
    block_size : float
        Side of the square blocks, metres.
    n_folds, seed : int
        Number of folds; seed of the one generator that dealt the blocks.
    refit : str
        ``"hyperparameters-fixed"`` or ``"all"``.
    n_blocks : int
        Non-empty blocks.
    block_size_rule : str
        How ``block_size`` was chosen (``"given"`` or the default rule applied).
    hyperparameters : dict or None
        ``{"kernel": repr, "nugget": m^2}`` shared by every fold when fixed (the keys the
        estimator has), else None.
    fold : ndarray of shape (n,)
        Fold of each sample (int).
    block : ndarray of shape (n,)
        Block of each sample (int, ``0 .. n_blocks - 1``); a block lies in one fold.
    prediction, predictive_sd : ndarray of shape (n,)
        Held-out predictive mean and sd of each sample's observation, metres.
    """

    folds: list[dict[str, Any]]
    pooled: dict[str, Any]
    block_size: float
    n_folds: int
    seed: int
    refit: str
    n_blocks: int
    block_size_rule: str
    hyperparameters: dict[str, Any] | None
    fold: np.ndarray = field(repr=False)
    block: np.ndarray = field(repr=False)
    prediction: np.ndarray = field(repr=False)
    predictive_sd: np.ndarray = field(repr=False)

    def verdict(self, tolerance_points: float = 5.0) -> list[str]:
        """Plain-language sentences for pooled coverages off nominal by more than
        ``tolerance_points`` percentage points; empty when both are within it."""
        return coverage_verdict(self.pooled, tolerance_points)

    def to_dict(self, include_samples: bool = False) -> dict[str, Any]:
        """JSON-safe dict (Python scalars and lists) with ``verdict`` at the default tolerance;
        the per-sample arrays (``fold``, ``block``, ``prediction``, ``predictive_sd``) only
        on request."""
        out = {
            "method": "spatial block k-fold",
            "block_size_m": self.block_size,
            "block_size_rule": self.block_size_rule,
            "n_folds": self.n_folds,
            "n_blocks": self.n_blocks,
            "seed": self.seed,
            "refit": self.refit,
            "predictive": "N(mu, sd^2 + nugget + z_var) of each held-out sample",
            "hyperparameters": self.hyperparameters,
            "pooled": self.pooled,
            "folds": self.folds,
            "verdict": self.verdict(),
        }
        if include_samples:
            out.update(
                fold=self.fold.tolist(),
                block=self.block.tolist(),
                prediction=self.prediction.tolist(),
                predictive_sd=self.predictive_sd.tolist(),
            )
        return json_safe(out)


def _masks_in_order(extra_variance: Callable, order: np.ndarray) -> Callable:
    """``extra_variance`` called with its training mask and held-out rows in the caller's
    order of rows (``order``: the caller's row of each row here)."""

    def in_order(train: np.ndarray, xy: np.ndarray, var_f: np.ndarray) -> np.ndarray:
        mask = np.empty_like(train)
        mask[order] = train
        rows = np.argsort(order[~train])  # the held-out rows as the caller has them
        var = np.empty(rows.size)
        var[rows] = extra_variance(mask, xy[rows], var_f[rows])
        return var

    return in_order


def _scores(obs: np.ndarray, mu: np.ndarray, sd: np.ndarray) -> dict[str, Any]:
    z_mean, z_std = standardized_error_stats(mu, sd, obs)
    return {
        "n": int(obs.size),
        "rmse_m": rmse(mu, obs),
        "mean_error_m": float(np.mean(mu - obs)),
        "nlpd": nlpd(mu, sd, obs),
        "coverage_68": interval_coverage(mu, sd, obs, z=1.0),
        "coverage_95": interval_coverage(mu, sd, obs, z=1.96),
        "z_mean": z_mean,
        "z_std": z_std,
        "mean_sd_m": float(np.mean(sd)),
    }


def cross_validate(
    estimator: Any,
    samples: ElevationSamples,
    block_size: float | None = None,
    n_folds: int = 5,
    seed: int = 0,
    refit: str = "hyperparameters-fixed",
    targets: Any = None,
    extra_variance: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray] | None = None,
) -> CrossValidation:
    """Spatial block K-fold cross-validation of a GP map's mean and 1-sigma.

    Parameters
    ----------
    estimator : TerrainGP or estimator of the same shape
        ``fit(samples)``, ``predict(xy, return_std=True, include_nugget=True)`` and constructor
        parameters readable as attributes. Never modified: every fit is on a clone.
    samples : ElevationSamples
        The survey; ``z_var`` is each sample's own noise variance, m^2.
    block_size : float, optional
        Side of the square blocks, metres. Default: distance-matched
        (:func:`terrain.heldout_design.matched_block_size`): the side, from a ladder of 1-16 x
        the median distance from ``targets`` to the samples, whose held-out samples lie as far
        from their training samples as the map's cells lie from the data, with at least
        2 x ``n_folds`` non-empty blocks. When no rung has that many blocks: 3 x the shortest
        fitted length scale (a tenth of the extent without one), halved until it does.
        ``CrossValidation.block_size_rule`` says which.
    n_folds : int
        Number of folds, >= 2, at most the number of non-empty blocks.
    seed : int
        Seed of the one ``numpy.random.Generator`` that deals the blocks to folds. The
        estimator keeps its own ``seed`` for its own fits.
    refit : {"hyperparameters-fixed", "all"}
        ``"hyperparameters-fixed"`` (fast): every fold's clone takes the fitted ``kernel_``
        and ``nugget_`` with ``nugget_bounds="fixed", optimize=False``, and the original
        ``mean`` setting, so a mean fitted to data (``"constant"``) is re-fitted on the
        training folds. An unfitted estimator is first fitted (a clone, on all samples) to
        get them. The hyperparameters have then seen the held-out samples, a mild leak that
        ``"all"`` (slow, honest) avoids by refitting everything per fold.
    targets : terrain.Grid or ndarray of shape (m, 2), optional
        Where the map is used (its grid), m, in the samples' CRS: sets the block size and the
        distance-matching weights of the map-level check. Default: a 100 x 100 lattice over
        the samples' bounding box.
    extra_variance : callable, optional
        ``extra_variance(train, xy, var_f) -> var`` (m^2, shape (m,)): variance the map states
        beyond the GP's at held-out points ``xy`` (m, 2) given the training mask ``train``
        (n,) and the fold's GP variance ``var_f`` there, counted as map variance. The rover
        pipeline passes its error budget's along-track term (``toolkit.error_budget``), so
        the check is of the 1-sigma the product states, less the map-wide shared terms that
        held-out samples carry too and cannot see.

    Returns
    -------
    CrossValidation
        Per-fold and pooled scores, the fold of each sample and its held-out prediction.

    Raises
    ------
    terrain.errors.InputError
        ``samples`` not ElevationSamples, ``n_folds`` < 2, ``block_size`` <= 0 or not finite,
        unknown ``refit``, an estimator without ``fit`` / ``predict``, or fewer non-empty
        blocks than folds.
    """
    if not isinstance(samples, ElevationSamples):
        fix = "wrap arrays with ElevationSamples(xy, z, z_var)"
        raise bad_input("samples", type(samples).__name__, "terrain.ElevationSamples", fix)
    if not all(callable(getattr(estimator, name, None)) for name in ("fit", "predict")):
        fix = "pass a terrain.TerrainGP (or an estimator with fit and predict)"
        raise bad_input("estimator", type(estimator).__name__, "an estimator", fix)
    if isinstance(n_folds, bool) or not isinstance(n_folds, Integral) or n_folds < 2:
        raise bad_input("n_folds", n_folds, "an integer >= 2", "e.g. n_folds=5")
    n_folds = int(n_folds)
    if refit not in REFIT_MODES:
        raise bad_input("refit", refit, '"hyperparameters-fixed" or "all"', "pick one")

    order = samples.position_order()  # sums and draws in one order: any row order, same bits
    samples = samples.by_position()
    if extra_variance is not None:  # its training mask in the caller's order of rows
        extra_variance = _masks_in_order(extra_variance, order)
    reference = estimator
    if refit == REFIT_MODES[0] and not is_fitted(estimator):
        reference = clone(estimator).fit(samples)
    target_xy = target_points(targets, samples.xy)
    target_d = cKDTree(samples.xy).query(target_xy)[0]
    size, rule, fold, block = design_folds(
        samples.xy, target_d, n_folds, seed, reference, block_size
    )
    n_blocks = int(block.max()) + 1
    block_fold = np.empty(n_blocks, dtype=np.int64)
    block_fold[block] = fold
    blocks_per_fold = np.bincount(block_fold, minlength=n_folds)

    hyper = None
    if refit == REFIT_MODES[0]:
        overrides = fixed_overrides(reference)
        hyper = {k: overrides[k] for k in ("kernel", "nugget") if k in overrides} or None
        if hyper and "kernel" in hyper:
            hyper["kernel"] = repr(hyper["kernel"])
    fit_predict = fold_predictor(estimator, reference, samples.n, refit == REFIT_MODES[0])
    mu = np.empty(samples.n)
    prior = np.zeros(samples.n)  # each fold's prior mean at its held-out samples, m
    sd = np.empty(samples.n)
    latent_var = np.empty(samples.n)
    noise_var = np.empty(samples.n)
    rows = []
    for k in range(n_folds):
        test = fold == k
        model, m, s = fit_predict(samples.subset(~test), samples.xy[test])
        mu[test] = m
        if callable(getattr(model, "mean_", None)):
            prior[test] = model.mean_(samples.xy[test])
        latent_var[test] = np.asarray(s, dtype=float) ** 2
        if extra_variance is not None:
            latent_var[test] += extra_variance(~test, samples.xy[test], latent_var[test])
        noise_var[test] = float(getattr(model, "nugget_", 0.0)) + samples.z_var[test]
        sd[test] = np.sqrt(latent_var[test] + noise_var[test])
        row = {"fold": k, "n_train": int((~test).sum()), "n_blocks": int(blocks_per_fold[k])}
        row.update(_scores(samples.z[test], mu[test], sd[test]))
        if hasattr(model, "kernel_"):
            row["kernel"] = repr(model.kernel_)
        if hasattr(model, "nugget_"):
            row["nugget"] = float(model.nugget_)
        rows.append(row)

    pooled = _scores(samples.z, mu, sd)
    heldout_nd = heldout_neighbour_distances(samples.xy, fold)  # 1st, 4th, 16th nearest
    heldout_d = heldout_nd[:, 0]
    weights = distance_weights(heldout_d, target_d)
    # the same samples matched to the map cells' whole neighbourhoods (heldout_weights)
    cells = even_stride(target_xy)  # the cells the weights describe: only those measured
    around = neighbourhood_weights(heldout_nd, neighbour_distances(samples.xy, cells))
    # where the noise is independent between held-out neighbours, planes through them
    # average most of it away before the check removes what is left (heldout_local_fit):
    # planes through what each fold's prior mean leaves, not through a step it holds
    # (a BreaklineMean's; docs/terrain.md "The held-out check beside a breakline")
    resid, resid_noise, local = local_plane_residuals(
        samples.xy, samples.z - prior, mu - prior, noise_var, fold, weights
    )
    boot_rng = np.random.default_rng([seed, 1])  # the bootstrap's own stream of the seed
    calib = map_calibration(
        resid, latent_var, resid_noise, weights, block, boot_rng, neighbourhood=around
    )
    pooled.update(calib)
    pooled.update(local)
    if calib.get("matched_on") == "neighbourhood":
        weights = around
    pooled["heldout_effective_share"] = effective_share(weights)
    t_s = samples.extra.get("t_s")
    if t_s is not None and np.shape(t_s) == (samples.n,) and np.isfinite(t_s).all():
        pooled["along_track_shared"], pooled["heldout_dt_median_s"] = along_track_shared(
            samples.xy,
            np.asarray(t_s, dtype=float),
            fold,
            samples.z_var,
            latent_var + noise_var,
            weights,
            ALONG_TRACK_FRACTION,
            ALONG_TRACK_TAU_S,
        )
    pooled["heldout_distance_median_m"] = float(np.median(heldout_d))
    pooled["map_distance_median_m"] = float(np.median(target_d))
    # The check's reach: cells farther from data than its held-out samples are not vouched
    # for (docs/terrain.md "σ checked without truth": half-surveyed sites).
    pooled["heldout_reach_m"] = float(np.quantile(heldout_d, REACH_QUANTILE))
    pooled["map_beyond_reach"] = float(np.mean(target_d > pooled["heldout_reach_m"]))
    levels, observed = calibration_curve(mu, sd, samples.z)
    pooled["calibration"] = {"levels": levels.tolist(), "observed": observed.tolist()}
    back = np.argsort(order)  # the caller's row i is row back[i] here
    fold, block, mu, sd = (a[back] for a in (fold, block, mu, sd))
    for a in (fold, block, mu, sd):
        a.setflags(write=False)
    return CrossValidation(
        folds=json_safe(rows),
        pooled=json_safe(pooled),
        block_size=float(size),
        n_folds=n_folds,
        seed=int(seed),
        refit=refit,
        n_blocks=int(n_blocks),
        block_size_rule=rule,
        hyperparameters=json_safe(hyper),
        fold=fold,
        block=block,
        prediction=mu,
        predictive_sd=sd,
    )
