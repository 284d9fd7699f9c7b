"""The certificate's "sigma checked on held-out data" block, from a spatial cross-validation.

:func:`heldout_block` turns :func:`terrain.cross_validate` (or its JSON) into the block the
certificate and the HTML report show: the held-out measurement scores, the map-level scores
with the samples' noise removed (:mod:`terrain.heldout_design`), one z sign convention
(``(map - sample) / sd``, the certificate's) and the verdict in words.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from terrain.errors import bad_input
from terrain.heldout_verdict import coverage_verdict
from terrain.json_safe import json_safe as _clean
from terrain.validation import CrossValidation

__all__ = ["heldout_block"]

_HELDOUT_SCORES = (
    "n",
    "rmse_m",
    "mean_error_m",
    "nlpd",
    "coverage_68",
    "coverage_95",
    "z_mean",
    "z_std",
    "mean_sd_m",
)
#: Map-level scores (terrain.heldout_design: the samples' noise removed), when present.
_HELDOUT_MAP = (
    "variance_ratio",
    "noise_share",
    "map_coverage_68",
    "map_coverage_95",
    "map_coverage_68_interval",
    "map_coverage_95_interval",
    "heldout_distance_median_m",
    "map_distance_median_m",
    "heldout_reach_m",
    "map_beyond_reach",
    "along_track_shared",
    "heldout_dt_median_s",
    "matched_on",
    "distance_matched_coverage_68",
    "distance_matched_coverage_95",
    "neighbourhood_matched_coverage_68",
    "neighbourhood_matched_coverage_95",
    "neighbourhood_difference_sd",
    "design_sd_68",
    "design_sd_95",
    "heldout_effective_share",
    "local_fit_used",
    "local_fit_share",
    "local_fit_radius_m",
    "local_fit_q",
    "local_fit_noise_kept",
    "local_fit_rule",
)
_Z_DEFINITION = "(map - held-out sample) / sd, the sign of mean_error_m"


def heldout_block(
    cv: CrossValidation | Mapping[str, Any], tolerance_points: float = 5.0
) -> dict[str, Any]:
    """The certificate's "sigma checked on held-out data" block (``heldout_calibration``).

    Parameters
    ----------
    cv : terrain.CrossValidation or mapping
        Output of :func:`terrain.cross_validate`, its ``to_dict()`` (e.g. read from JSON), or
        a block this function made (re-read from a certificate).
    tolerance_points : float
        Coverage off nominal by more than this many percentage points gets a verdict
        sentence (:func:`terrain.heldout_verdict.coverage_verdict`).

    Returns
    -------
    dict
        JSON-ready: ``method`` ("spatial block k-fold"), ``block_size_m``, ``n_folds``,
        ``n_blocks``, ``seed``, ``refit``, ``predictive``; pooled ``n, rmse_m, mean_error_m
        (map - held-out sample), nlpd, coverage_68, coverage_95`` (fractions), ``z_mean``
        (of ``(map - sample) / sd``, the sign of ``mean_error_m``), ``z_std, mean_sd_m``;
        ``calibration`` (levels, observed); ``folds`` (one row each); ``tolerance_points``
        and ``verdict`` (sentences, empty when both coverages are in).

    Raises
    ------
    terrain.errors.InputError
        ``cv`` is neither, or lacks pooled scores.
    """
    d = cv.to_dict() if isinstance(cv, CrossValidation) else cv
    fix = "pass terrain.cross_validate(...) or its to_dict()"
    if not isinstance(d, Mapping):
        raise bad_input("heldout", type(cv).__name__, "a terrain.CrossValidation", fix)
    pooled = d.get("pooled", d)  # a block read back from a certificate holds them flat
    missing = [k for k in _HELDOUT_SCORES if not isinstance(pooled, Mapping) or k not in pooled]
    if missing:
        raise bad_input("heldout", f"no pooled {missing}", "CrossValidation.to_dict()", fix)
    # cross_validate's z is (sample - map) / sd; here (map - sample) / sd, like mean_error_m
    sign = 1.0 if d.get("z_definition") == _Z_DEFINITION else -1.0
    scores = [{k: row.get(k) for k in _HELDOUT_SCORES} for row in (pooled, *(d.get("folds") or []))]
    for row in scores:
        row["z_mean"] = None if row["z_mean"] is None else sign * row["z_mean"]
    folds = [
        {**{k: row.get(k) for k in ("fold", "n_train", "n_blocks")}, **sc}
        for row, sc in zip(d.get("folds") or [], scores[1:], strict=True)
    ]
    block = {
        "method": "spatial block k-fold",
        "block_size_m": d.get("block_size_m"),
        "block_size_rule": d.get("block_size_rule"),
        "n_folds": d.get("n_folds"),
        "n_blocks": d.get("n_blocks"),
        "seed": d.get("seed"),
        "refit": d.get("refit"),
        "predictive": d.get("predictive"),
        "hyperparameters": d.get("hyperparameters"),
        **scores[0],
        **{k: pooled[k] for k in _HELDOUT_MAP if k in pooled},
        "z_definition": _Z_DEFINITION,
        "calibration": pooled.get("calibration"),
        "folds": folds,
        "tolerance_points": float(tolerance_points),
        "verdict": coverage_verdict(dict(pooled), tolerance_points)
        + _too_few(pooled.get("n"), tolerance_points),
    }
    return _clean(block)


def _too_few(n: Any, tolerance_points: float) -> list[str]:
    """A sentence when the held-out coverage rests on too few samples to judge the 1-sigma:
    the binomial 1-sigma of a 68 % coverage measured on ``n`` independent samples,
    ``sqrt(0.683 * 0.317 / n)``, exceeds the tolerance (n < 87 at 5 points; spatially
    correlated samples carry less still). A map from 5 samples passed the check while 34 %
    of the truth lay inside its +-1 sigma."""
    if n is None:
        return []
    n = int(n)
    spread = 100.0 * (NOMINAL_68 * (1.0 - NOMINAL_68) / max(n, 1)) ** 0.5
    if spread <= tolerance_points:
        return []
    return [
        f"only {n} held-out samples: a coverage measured on them is uncertain by about "
        f"+-{spread:.0f} points (binomial 1-sigma at 68 %), more than the {tolerance_points:g}-"
        "point tolerance, so this check can neither confirm nor refute the map's 1-sigma; "
        "add samples"
    ]


#: Nominal coverage of +-1 sigma for a Gaussian.
NOMINAL_68 = 0.6826894921370859
