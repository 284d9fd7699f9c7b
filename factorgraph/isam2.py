"""iSAM2's settings for the online pass of :func:`factorgraph.localize.localize`.

Relinearization: per-variable thresholds (tangent units), or none at all online
(``LocalizeParams.relinearize=False``, the default: the batch refinement takes the estimate to
the MAP afterwards).

Wildfire threshold (``LocalizeParams.wildfire_threshold``, rad or m). Each step reads the
newest pose (and GPS bias, odometry drift) through iSAM2's lazy back-substitution, which stops
descending the Bayes tree where a clique's delta moved by less than the threshold. Those
variables sit in the cliques the step re-eliminated, which are always solved afresh, so what
is read is exact at any threshold; older poses' deltas lag (a 250-step drive: 0.19 m at 0.1,
1.3 m with no wildfire; ``tests/test_isam_wildfire.py``), so the final estimate is a full
back-substitution (``calculateBestEstimate``). GTSAM's 1e-3 let every GPS fix, which moves the
whole trajectory by millimetres through the bias chain, descend the whole tree: 22 of the
default run's 45 s localize stage; 0.1 takes 3 s, products the same to 1e-10 m
(docs/localization.md).
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["isam2_params"]


def isam2_params(params: Any) -> Any:
    """``gtsam.ISAM2Params`` from a :class:`factorgraph.localize.LocalizeParams`."""
    import gtsam

    p = gtsam.ISAM2Params()
    th = gtsam.ISAM2ThresholdMap()
    th.insert(("x", np.asarray(params.relinearize_pose, float)))
    th.insert(("b", np.full(3, params.relinearize_bias_m)))
    th.insert(("l", np.full(3, params.relinearize_landmark_m)))
    th.insert(("d", np.asarray(params.relinearize_drift, float)))
    p.setRelinearizeThreshold(th)
    p.relinearizeSkip = params.relinearize_skip
    gauss_newton = gtsam.ISAM2GaussNewtonParams()
    gauss_newton.setWildfireThreshold(float(params.wildfire_threshold))
    p.setOptimizationParams(gauss_newton)
    if not params.relinearize:  # only the forced Gauss-Newton passes at the end relinearize
        th = gtsam.ISAM2ThresholdMap()
        for ch, n in (("x", 6), ("b", 3), ("l", 3), ("d", 2)):
            th.insert((ch, np.full(n, 1e9)))
        p.setRelinearizeThreshold(th)
    return p
