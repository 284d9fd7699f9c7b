"""Held-out residuals with most of their noise averaged away: each held-out sample's
elevation replaced by a local plane fitted to it and its nearest held-out neighbours.

Why. The held-out check removes the samples' stated noise from the residuals
(:func:`terrain.heldout_design.map_calibration`). With 50,000 samples the map's own error is
a few per cent of one sample's noise, so a 1 % error in the noise variance, or the noise's
own draw at the held-out samples, moves the estimated 68 % coverage by 5 points or more
(docs/terrain.md, "Held-out check when noise dominates"). Dense surveys hold the remedy: a
held-out sample has other held-out samples of its fold within a few metres, and none of them
was used by the map that predicts it. A plane fitted by least squares to the nearest of them
(itself included; at most :data:`NEIGHBOURS`) estimates the elevation at the sample with
the noise variance ``sum_j a_j^2 var(eps_j)`` (``a`` the fit's weights for the intercept,
``sum_j a_j = 1``): about a quarter of one sample's with 16 samples in the fit. The map's
error at the sample is unchanged, so the residual ``plane - map`` checks the same 1-sigma
with less noise. What the plane cannot follow (the ground's curvature within the radius)
adds to the residual as map error would; the radius is therefore kept to a few sample
spacings (:data:`RADIUS_SPACINGS`).

Two assumptions are checked on the data before the fits are used:

* **The noise is independent between neighbours.** A rover's samples seconds apart share
  their positioning error (:mod:`terrain.along_track`). Shared noise does not average
  away, so the residuals would keep noise the check no longer removes, and the map's 1-sigma
  would read too small.
* **The ground is a plane at that scale, within the noise.**

Both show in the leave-one-out residuals ``z_i - plane_{-i}(x_i)`` of the same fits: with
independent noise and a plane-like ground their variance is the stated ``var(eps_i) +
sum_j a_j^2 var(eps_j)``. The ratio ``q`` of what is seen to what is stated, over all the
fitted samples, must lie within :data:`Q_TOLERANCE` of 1; otherwise the single-sample
residuals are kept and the reason is reported. Shared noise reads ``q`` well below 1;
ground rougher than the noise at the radius reads it above. ``q`` cannot see a curvature
much smaller than the noise, which still matters where the map's error is smaller still: on
ground rough at a few metres the check can then read the map's 1-sigma a little too small.

Measured on the 38 rows of the real-DEM benchmark at 50,000 samples (eleven DEMs, both
means, two noise draws; docs/terrain.md "Held-out residuals averaged over planes through
their neighbours"), the check read within 3 points of the truth at 68 and 95 % on 25 rows
with these fits and 13 without. At 3,000 samples, 30 of 44 against 28: the planes reach
12 m there, and ``q`` kept them off the six DEMs rough at that scale.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from .heldout_weights import sample_spacing

__all__ = ["NEIGHBOURS", "Q_TOLERANCE", "RADIUS_SPACINGS", "local_plane_residuals"]

#: Held-out samples of one fold in each plane fit, the sample itself included.
NEIGHBOURS = 16
#: Radius of a fit, in median nearest-neighbour spacings of the samples. 3.5: about 8
#: samples of a uniform scatter fall within it, more along tracks. Measured on the
#: benchmark's 0.86 m spacing (docs/terrain.md): 3 m read within 3 points on 26 of 38 rows,
#: 2 m on 23, 1.5 m on 14 (too few neighbours); radii tied to the shortest length scale
#: (2.8-175 m) on 6-18 (the ground's curvature).
RADIUS_SPACINGS = 3.5
#: A fit is used only where it keeps less than this share of the sample's noise variance.
MAX_NOISE_KEPT = 0.5
#: Largest |q - 1| (seen over stated leave-one-out variance) at which the fits are used.
Q_TOLERANCE = 0.15


def _plane_weights(
    xy: np.ndarray, fold: np.ndarray, radius: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Intercept weights of least-squares planes through each sample's nearest same-fold
    samples within ``radius``: ``a`` (n, k) with the sample itself, ``b`` (n, k) the same
    neighbours without it (leave-one-out), and the neighbour indices (n, k). Rows whose
    intercept the neighbours do not determine (fewer than three, or a line not through the
    sample) are 0."""
    n = xy.shape[0]
    a, b = np.zeros((n, NEIGHBOURS)), np.zeros((n, NEIGHBOURS))
    nbr = np.zeros((n, NEIGHBOURS), dtype=np.int64)
    for f in np.unique(fold):
        idx = np.flatnonzero(fold == f)
        k = min(NEIGHBOURS, idx.size)
        dist, near = cKDTree(xy[idx]).query(xy[idx], k=k, distance_upper_bound=radius)
        dist, near = dist.reshape(idx.size, k), near.reshape(idx.size, k)
        found = np.isfinite(dist)
        members = np.where(found, idx[np.minimum(near, idx.size - 1)], idx[:, None])
        d = xy[members] - xy[idx, None, :]  # (ni, k, 2), m
        for out, ok in ((a, found), (b, found & (np.arange(k) > 0))):  # 0: itself
            m = ok.astype(float)
            design = np.concatenate([m[..., None], d * m[..., None]], axis=-1)  # 1, dx, dy
            w = np.linalg.pinv(design, rcond=1e-8)[:, 0, :] * m  # the intercept's row
            fits = np.abs(w.sum(axis=1) - 1.0) < 1e-6
            out[idx, :k] = np.where(fits[:, None], w, 0.0)
        nbr[idx, :k] = members
    return a, b, nbr


def local_plane_residuals(
    xy: np.ndarray,
    z: np.ndarray,
    mu: np.ndarray,
    noise_var: np.ndarray,
    fold: np.ndarray,
    weights: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """Held-out residuals from local planes through same-fold held-out samples (module
    docstring), where the data show the noise independent and the ground plane-like.

    Parameters
    ----------
    xy : ndarray of shape (n, 2)
        Sample locations, m.
    z : ndarray of shape (n,)
        Sample elevations, m. :func:`terrain.cross_validate` passes them less each fold's
        prior mean, and ``mu`` less the same: the planes then fit what the mean leaves (not
        a breakline's step, nor the curvature a DEM prior already holds), and the residuals
        are unchanged where no plane is used.
    mu : ndarray of shape (n,)
        Each sample's held-out prediction (the map of the folds without it), m.
    noise_var : ndarray of shape (n,)
        Each sample's noise variance (stated + nugget), m^2.
    fold : ndarray of shape (n,)
        Fold of each sample.
    weights : ndarray of shape (n,)
        The check's weights of the held-out samples (for ``local_fit_noise_kept``).

    Returns
    -------
    resid : ndarray of shape (n,)
        ``plane - mu`` where a fit is used, ``z - mu`` elsewhere, m.
    noise : ndarray of shape (n,)
        The noise variance each residual carries, m^2.
    info : dict
        ``local_fit_used`` (bool), ``local_fit_share`` (fraction of held-out samples with a
        fit), ``local_fit_radius_m``, ``local_fit_q`` (None without fits),
        ``local_fit_noise_kept`` (weighted noise variance kept over the samples' own) and
        ``local_fit_rule`` (in words, with the reason when not used).
    """
    resid, noise = z - mu, np.array(noise_var, dtype=float)
    radius = RADIUS_SPACINGS * sample_spacing(xy)
    info: dict[str, Any] = {
        "local_fit_used": False,
        "local_fit_share": 0.0,
        "local_fit_radius_m": radius,
        "local_fit_q": None,
        "local_fit_noise_kept": 1.0,
    }
    if not radius > 0:
        info["local_fit_rule"] = "not used: the samples have no spacing"
        return resid, noise, info
    a, b, nbr = _plane_weights(xy, fold, radius)
    kept = np.sum(a**2 * noise_var[nbr], axis=1)
    use = (a.sum(axis=1) > 0.5) & (kept < MAX_NOISE_KEPT * noise_var)
    info["local_fit_share"] = float(use.mean())
    if not use.any():
        info["local_fit_rule"] = (
            f"not used: no held-out sample has neighbours within {radius:.3g} m"
        )
        return resid, noise, info
    # leave-one-out residuals of the same fits: is the noise independent, the ground a plane?
    check = use & (b.sum(axis=1) > 0.5)
    seen = (z - np.sum(b * z[nbr], axis=1))[check] ** 2
    stated = (noise_var + np.sum(b**2 * noise_var[nbr], axis=1))[check]
    # unweighted: the noise and the ground at the radius do not depend on where the map's
    # cells are, and the weights rest on few samples (a noisier q)
    q = float(np.sum(seen) / np.sum(stated)) if np.sum(stated) > 0 else float("nan")
    info["local_fit_q"] = q
    where = (
        f"planes through the {NEIGHBOURS} nearest held-out samples of the fold within "
        f"{radius:.3g} m ({RADIUS_SPACINGS:g} sample spacings) at {100 * use.mean():.0f} % of "
        f"the held-out samples; leave-one-out variance {q:.3f} x stated"
    )
    if not q >= 1.0 - Q_TOLERANCE:
        info["local_fit_rule"] = (
            f"not used: {where}: the neighbours share their noise, which would not average away"
        )
        return resid, noise, info
    if not q <= 1.0 + Q_TOLERANCE:
        info["local_fit_rule"] = (
            f"not used: {where}: more than the stated noise (ground rougher than a plane at "
            "that radius, or noise understated)"
        )
        return resid, noise, info
    resid[use] = np.sum(a * z[nbr], axis=1)[use] - mu[use]
    noise[use] = kept[use]
    info["local_fit_used"] = True
    info["local_fit_noise_kept"] = float(np.sum(weights * noise) / np.sum(weights * noise_var))
    info["local_fit_rule"] = "used: " + where
    return resid, noise, info
