"""Gross GPS outliers: a robust moving-median gate (shared by the field reader and
:func:`factorgraph.localize`).

A fix is gross when it lies farther from the median of its neighbours in time than the
rover can have driven plus a wide noise margin. The median of the neighbours ignores up to
half of them being wrong too, so one fix 5 km off (or a short burst) cannot drag the
reference; the margin is wide on purpose: this gate removes blunders (multipath jumps, a
wrong-zone fix, a corrupted record), the factor graph weighs everything else.
"""

from __future__ import annotations

import numpy as np

__all__ = ["GATE_MIN_M", "GATE_SIGMAS", "GATE_WINDOW_S", "gross_outliers"]

GATE_WINDOW_S = 10.0  # neighbours within +- this many seconds form the reference
GATE_SIGMAS = 10.0  # margin in the fix's own 1-sigma (each axis group)...
GATE_MIN_M = 10.0  # ...but never below this (m): a consumer GPS bias moves metres per minute


def gross_outliers(
    t_s: np.ndarray,
    xyz: np.ndarray,
    sigma: np.ndarray,
    travelled_m: np.ndarray,
    window_s: float = GATE_WINDOW_S,
    n_sigma: float = GATE_SIGMAS,
    min_gate_m: float = GATE_MIN_M,
) -> np.ndarray:
    """Flag fixes far from the moving median of their neighbours.

    Parameters
    ----------
    t_s : ndarray of shape (G,)
        Fix times (s), sorted.
    xyz : ndarray of shape (G, 3)
        Fix positions (m; any metric frame, e.g. local ENU).
    sigma : ndarray of shape (G, 3)
        Each fix's stated 1-sigma (m, E N U).
    travelled_m : ndarray of shape (G,)
        Distance the rover had driven at each fix (m; from odometry), which bounds how far
        two honest fixes can be apart.
    window_s, n_sigma, min_gate_m : float
        Neighbours are the other fixes within ``window_s``; fix ``i`` is gross when its
        horizontal (or vertical) distance to their component-wise median exceeds
        ``max(n_sigma * sigma_i, min_gate_m)`` plus the farthest distance driven between
        ``i`` and a neighbour. A fix with fewer than 2 neighbours is kept (nothing to judge).

    Returns
    -------
    ndarray of shape (G,), bool
        True for a gross outlier.
    """
    t = np.asarray(t_s, float)
    xyz = np.asarray(xyz, float)
    sig = np.asarray(sigma, float)
    dist = np.asarray(travelled_m, float)
    n = t.size
    out = np.zeros(n, bool)
    lo = np.searchsorted(t, t - window_s, side="left")
    hi = np.searchsorted(t, t + window_s, side="right")
    for i in range(n):
        j = np.r_[lo[i] : i, i + 1 : hi[i]]
        if j.size < 2:
            continue
        ref = np.median(xyz[j], axis=0)
        drive = float(np.abs(dist[j] - dist[i]).max())
        gate_h = max(n_sigma * float(np.hypot(sig[i, 0], sig[i, 1])), min_gate_m) + drive
        gate_v = max(n_sigma * float(sig[i, 2]), min_gate_m) + drive
        d = xyz[i] - ref
        out[i] = bool(np.hypot(d[0], d[1]) > gate_h or abs(d[2]) > gate_v)
    return out


def gate_log(log):
    """``log`` without its gross GPS outliers (:func:`gross_outliers` on the keyframe times,
    the fixes' own sigmas and the odometry's distance), the count recorded in
    ``log.ingest["gps_gross_outliers_gated"]``; ``log`` itself when none is gross.

    Raises :class:`~terrain.errors.InputError` when fewer than 2 fixes exist (or remain):
    localization needs them to place the traverse.
    """
    from dataclasses import replace

    from terrain.errors import bad_input

    def _too_few(n: int, what: str):
        return bad_input(
            "gps", f"{n} {what}", "at least 2 GPS fixes", "check the log's gps table / GPS file"
        )

    if log.gps_k.size < 2:
        raise _too_few(log.gps_k.size, "fixes")
    sigma = log.gps_sigma
    if sigma is None:
        sigma = np.broadcast_to(np.asarray(log.sensors.gps.sigma_white_m), log.gps_xyz.shape)
    steps = np.linalg.norm(log.odometry[:, 3:], axis=1)
    travelled = np.concatenate([[0.0], np.cumsum(steps)])
    bad = gross_outliers(log.t[log.gps_k], log.gps_xyz, sigma, travelled[log.gps_k])
    if not bad.any():
        return log
    keep = ~bad
    if keep.sum() < 2:
        raise _too_few(int(keep.sum()), "fixes left after the gross-outlier gate")
    truth = dict(log.truth)
    if "gps_bias" in truth:
        truth["gps_bias"] = truth["gps_bias"][keep]
    ingest = dict(log.ingest)
    ingest["gps_gross_outliers_gated"] = int(bad.sum()) + int(
        ingest.get("gps_gross_outliers_gated", 0)
    )
    return replace(
        log,
        gps_k=log.gps_k[keep],
        gps_xyz=log.gps_xyz[keep],
        gps_sigma=None if log.gps_sigma is None else log.gps_sigma[keep],
        truth=truth,
        ingest=ingest,
    )
