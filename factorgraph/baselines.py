"""Baselines the iSAM2 localizer (:mod:`factorgraph.localize`) is scored against on the same
logs: GPS alone, odometry alone (dead reckoning), and the paper's own method, a particle filter
fusing low-quality GPS with visual odometry (glacier-terrain paper, Section III-A: "typical
accuracies of less than 1.0 m"). Positions are keyframe body origins, local ENU (m).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from terrain.errors import bad_input

from .localize import LocalizeParams, _initial_pose
from .log import MeasurementLog

__all__ = ["BaselineTrack", "gps_only", "odometry_only", "particle_filter"]


@dataclass
class BaselineTrack:
    """Keyframe positions estimated by one baseline.

    Attributes
    ----------
    name : str
        ``"gps_only"``, ``"odometry_only"`` or ``"particle_filter"``.
    xyz : ndarray of shape (K, 3)
        Estimated keyframe positions, local ENU (m).
    cov_xyz : ndarray of shape (K, 3, 3) or None
        Stated covariance of each position (m^2, ENU axes); None where the baseline has none.
    params : dict
        Settings used and diagnostics (counts, timings).
    """

    name: str
    xyz: np.ndarray
    cov_xyz: np.ndarray | None = None
    params: dict[str, Any] = field(default_factory=dict)


def _check_log(log: Any, gps_for: str | None = None) -> MeasurementLog:
    if not isinstance(log, MeasurementLog):
        raise bad_input("log", type(log).__name__, "a MeasurementLog", "use read_log()")
    if gps_for and log.gps_k.size == 0:
        raise bad_input("log.gps_k", "no GPS fixes", f"a GPS fix for {gps_for}", "log GPS")
    return log


def gps_only(log: MeasurementLog) -> BaselineTrack:
    """Positions from the GPS fixes; keyframes without one interpolated linearly in time
    between the neighbouring fixes (the first/last fix held flat outside them).

    Covariance: ``diag(sigma_white^2 + sigma_b^2)`` (white noise plus the stationary variance
    of the Gauss-Markov bias, :class:`factorgraph.sensors.GPSModel`); at a keyframe without a
    fix each horizontal axis gets a motion allowance ``(v d)^2 / 2`` (rover speed ``v``, time
    ``d`` to the nearest fix: the rover may be up to ``v d`` off the interpolant).

    Parameters
    ----------
    log : MeasurementLog
        With at least one GPS fix.

    Returns
    -------
    BaselineTrack
        ``params``: ``n_fixes``, ``n_interpolated`` (keyframes between fixes, without one),
        ``n_extrapolated`` (before the first or after the last fix).
    """
    log = _check_log(log, "gps_only")
    t, tf, gps = log.t, log.t[log.gps_k], log.sensors.gps
    xyz = np.column_stack([np.interp(t, tf, log.gps_xyz[:, i]) for i in range(3)])
    var = np.square(gps.sigma_white_m) + np.square(gps.bias_sigma_m)
    cov = np.broadcast_to(np.diag(var), (log.n_keyframes, 3, 3)).copy()
    j = np.searchsorted(tf, t)  # gap: time (s) to the nearest fix
    gap = np.abs(np.minimum(t - tf[np.maximum(j - 1, 0)], tf[np.minimum(j, tf.size - 1)] - t))
    cov[:, [0, 1], [0, 1]] += 0.5 * (log.sensors.speed_mps * gap[:, None]) ** 2
    G, n_out = int(log.gps_k.size), int(((t < tf[0]) | (t > tf[-1])).sum())
    info = dict(n_fixes=G, n_interpolated=log.n_keyframes - n_out - G, n_extrapolated=n_out)
    return BaselineTrack("gps_only", xyz, cov, info)


def _pose_rt(pose: Any) -> tuple[np.ndarray, np.ndarray]:
    """``(R (3,3), p (3,))`` of a ``gtsam.Pose3`` or a 4x4 homogeneous matrix."""
    m = np.asarray(pose.matrix() if hasattr(pose, "matrix") else pose, float)
    if m.shape != (4, 4) or not np.isfinite(m).all():
        raise bad_input("initial_pose", m.shape, "a gtsam.Pose3 or a finite 4x4 matrix", "")
    return m[:3, :3], m[:3, 3]


def _dead_reckon(odometry: np.ndarray, R0: np.ndarray, p0: np.ndarray):
    """Odometry composed from world pose (R0, p0): ``R (K, 3, 3)`` body-to-world, ``p (K, 3)``."""
    dR = Rotation.from_rotvec(odometry[:, :3]).as_matrix()
    R, p = np.empty((len(dR) + 1, 3, 3)), np.empty((len(dR) + 1, 3))
    R[0], p[0] = R0, p0
    for k in range(len(dR)):
        p[k + 1] = p[k] + R[k] @ odometry[k, 3:]
        R[k + 1] = R[k] @ dR[k]
    return R, p


def odometry_only(log: MeasurementLog, initial_pose: Any = None) -> BaselineTrack:
    """Dead reckoning: the odometry composed from one initial world pose.

    Parameters
    ----------
    log : MeasurementLog
        Its ``odometry`` rows (K-1, 6) are composed in order.
    initial_pose : gtsam.Pose3 or ndarray of shape (4, 4), optional
        Body-to-world pose of keyframe 0. Default: the true pose when the log has truth (the
        most favourable start), else a 2-D Procrustes fit of the first ~40 m of dead reckoning
        to GPS (:func:`factorgraph.localize._initial_pose`, the start iSAM2 uses).

    Returns
    -------
    BaselineTrack
        No covariance; ``params["init"]``: ``"given"``, ``"truth"`` or ``"gps_alignment"``.
    """
    log = _check_log(log)
    if initial_pose is not None:
        init = "given"
    elif log.has_truth and "rpy" in log.truth:
        init, initial_pose = "truth", np.eye(4)
        initial_pose[:3, :3] = Rotation.from_euler("ZYX", log.truth["rpy"][0, ::-1]).as_matrix()
        initial_pose[:3, 3] = log.truth["xyz"][0]
    else:
        init, initial_pose = "gps_alignment", _initial_pose(log, LocalizeParams())
    _, p = _dead_reckon(log.odometry, *_pose_rt(initial_pose))
    return BaselineTrack("odometry_only", p, None, {"init": init})


def _vertical(log: MeasurementLog, dz, dist, psi, sd_dz, gps_bias: bool):
    """Elevation Kalman filter, state ``[z, tilt_x, tilt_y (, b_z)]``: ``(z, var)``, each (K,).

    The dead-reckoned tilt error, a random walk (``sigma_rotation`` per step and axis), makes a
    step ``d`` along heading ``psi`` climb ``d (tilt_x sin psi - tilt_y cos psi)`` too much."""
    gps, n = log.sensors.gps, 4 if gps_bias else 3
    x, P, H = np.zeros(n), np.diag([1e8, 0, 0, gps.bias_sigma_m[2] ** 2][:n]), np.r_[1, 0, 0, 1][:n]
    q = math.radians(log.sensors.odometry.sigma_rotation_deg) ** 2
    fix = dict(zip(log.gps_k.tolist(), log.gps_xyz[:, 2].tolist(), strict=True))
    z, var = np.empty(log.n_keyframes), np.empty(log.n_keyframes)
    for k in range(log.n_keyframes):
        if k > 0:
            F, Q = np.eye(n), np.diag([sd_dz[k - 1] ** 2, q, q, 0.0][:n])
            F[0, 1:3] = dist[k - 1] * math.sin(psi[k - 1]), -dist[k - 1] * math.cos(psi[k - 1])
            if gps_bias:
                phi = math.exp(-(log.t[k] - log.t[k - 1]) / gps.bias_tau_s)
                F[3, 3], Q[3, 3] = phi, gps.bias_sigma_m[2] ** 2 * (1 - phi * phi)
            x, P = F @ x, F @ P @ F.T + Q
            x[0] += dz[k - 1]
        if k in fix:
            g = P @ H / (H @ P @ H + gps.sigma_white_m[2] ** 2)
            x, P = x + g * (fix[k] - H @ x), P - np.outer(g, H @ P)
        z[k], var[k] = x[0], P[0, 0]
    return z, var


def _initial_cloud(log, initial_pose, N: int, rng, var_xy: np.ndarray):
    """Initial particle positions (N, 2) and yaws (N,), and how they were made."""
    if isinstance(initial_pose, str) and initial_pose != "cold":
        raise bad_input("initial_pose", initial_pose, "None, 'cold' or a pose", "")
    if isinstance(initial_pose, str) or (initial_pose is None and log.gps_k.size < 2):
        late = log.sensors.speed_mps * (log.t[log.gps_k[0]] - log.t[0])
        pos = log.gps_xyz[0, :2] + rng.standard_normal((N, 2)) * np.sqrt(var_xy + late**2)
        return pos, rng.uniform(-math.pi, math.pi, N), "cold"
    init, yaw_sd = "given", 0.0
    if initial_pose is None:
        init, initial_pose = "gps_alignment", _initial_pose(log, LocalizeParams())
        yaw_sd = math.radians(LocalizeParams().attitude_prior_deg[2])
    R0, p0 = _pose_rt(initial_pose)
    pos = p0[:2] + rng.standard_normal((N, 2)) * np.sqrt(var_xy) * (init != "given")
    yaw = math.atan2(R0[1, 0], R0[0, 0]) + yaw_sd * rng.standard_normal(N)
    return pos, yaw, init


def particle_filter(
    log: MeasurementLog,
    n_particles: int = 2000,
    seed: int = 0,
    *,
    gps_bias: bool = False,
    drift_hypotheses: bool = True,
    initial_pose: Any = None,
    resample_ess: float = 0.5,
    param_walk_m: float = 100.0,
) -> BaselineTrack:
    """Bootstrap particle filter over the 2-D pose (x, y, yaw) plus elevation, forward only:
    the paper's localizer (GPS fused with visual odometry).

    The odometry is dead-reckoned once in 3-D and cut into increments ``d_k`` in the heading
    (yaw-only) frame of each keyframe; particle i moves ``xy += Rz(yaw_i) (s_i d_k + e)``,
    ``yaw_i += dyaw_k + r_i |d_k| + eps`` (``e``, ``eps``: the stated odometry white noise).
    With ``drift_hypotheses`` each particle carries a scale ``s_i`` and heading-drift rate
    ``r_i`` (rad/m) drawn from the model's per-traverse laws, plus a slow artificial random
    walk (one prior sigma per ``param_walk_m`` of travel; ``inf``: constant) so that
    resampling cannot exhaust them; without, they are folded into the white noise as in
    :func:`factorgraph.localize._odometry_sigmas`. Elevation, linear-Gaussian given the
    increments, is filtered exactly by :func:`_vertical`.

    ``gps_bias=False`` is the paper's filter: a fix weights by the white-noise likelihood
    ``N(z_xy; xy_i, diag(sigma_white^2))``, the bias ignored. ``gps_bias=True`` carries the
    Gauss-Markov bias, Rao-Blackwellised (a Kalman mean per particle and one shared variance,
    which does not depend on the data). Systematic resampling when ESS < ``resample_ess N``.

    Parameters
    ----------
    log : MeasurementLog
        With at least one GPS fix.
    n_particles : int
        N >= 1.
    seed : int
        Seeds the one ``numpy.random.default_rng`` drawing everything: same seed, same bytes.
    initial_pose : gtsam.Pose3, ndarray of shape (4, 4) or "cold", optional
        A pose: every particle starts there. Default: iSAM2's start (Procrustes fit of the
        first ~40 m to GPS, :func:`factorgraph.localize._initial_pose`) spread by the GPS
        white + bias sigma and a 5 deg yaw sigma. ``"cold"`` (or a single fix): around the
        first fix, yaw uniform on the circle.

    Returns
    -------
    BaselineTrack
        Weighted mean (K, 3) and covariance (K, 3, 3) at each keyframe after its fix (the
        elevation from the Kalman filter, uncorrelated with the horizontal); ``params``: the
        settings, ``initial``, ``n_resamples``, ``min_ess``, ``run_s``.
    """
    if isinstance(n_particles, bool) or int(n_particles) != n_particles or n_particles < 1:
        raise bad_input("n_particles", n_particles, "an integer >= 1", "use e.g. 2000")
    if not (0.0 < float(resample_ess) <= 1.0 and float(param_walk_m) > 0.0):
        raise bad_input(
            "resample_ess, param_walk_m", (resample_ess, param_walk_m), "(0, 1], > 0", ""
        )
    log = _check_log(log, "particle_filter")
    t0 = time.perf_counter()
    N, K, rng = int(n_particles), log.n_keyframes, np.random.default_rng(seed)
    gps, od = log.sensors.gps, log.sensors.odometry
    # Dead-reckoned increments in the heading frame of keyframe k (shared by all particles).
    R_dr, p_dr = _dead_reckon(log.odometry, np.eye(3), np.zeros(3))
    psi = np.arctan2(R_dr[:, 1, 0], R_dr[:, 0, 0])
    dp, c, s = np.diff(p_dr, axis=0), np.cos(psi[:-1]), np.sin(psi[:-1])
    inc = np.column_stack([c * dp[:, 0] + s * dp[:, 1], c * dp[:, 1] - s * dp[:, 0]])
    dyaw = np.angle(np.exp(1j * np.diff(psi)))
    dist = np.linalg.norm(log.odometry[:, 3:], axis=1)
    rot, drift = math.radians(od.sigma_rotation_deg), math.radians(od.heading_drift_sigma_deg_per_m)
    sig_t, sig_yaw = od.sigma_translation_frac * dist, np.full(K - 1, rot)
    if not drift_hypotheses:
        sig_t = dist * math.hypot(od.sigma_translation_frac, od.scale_error_sigma)
        sig_yaw = np.hypot(rot, drift * dist)
    walk = np.sqrt(dist / param_walk_m) * float(drift_hypotheses)
    sd_dz = np.hypot(od.sigma_translation_frac * dist, od.scale_error_sigma * dp[:, 2])
    z, z_var = _vertical(log, dp[:, 2], dist, psi, sd_dz, gps_bias)
    white, b_sig2 = np.square(gps.sigma_white_m[:2]), np.square(gps.bias_sigma_m[:2])
    pos, yaw, init = _initial_cloud(log, initial_pose, N, rng, white + b_sig2)
    scale = 1.0 + od.scale_error_sigma * rng.standard_normal(N) * float(drift_hypotheses)
    rate = drift * rng.standard_normal(N) * float(drift_hypotheses)
    b_mean, b_var = np.zeros((N, 2)), b_sig2.copy()
    fix_row = dict(zip(log.gps_k.tolist(), range(log.gps_k.size), strict=True))
    logw = np.full(N, -math.log(N))
    xyz, cov = np.zeros((K, 3)), np.zeros((K, 3, 3))
    n_resamples, min_ess = 0, float(N)
    for k in range(K):
        if k > 0:
            e = rng.standard_normal((N, 5))
            step = inc[k - 1] * scale[:, None] + e[:, :2] * sig_t[k - 1]
            u = np.exp(1j * yaw) * (step[:, 0] + 1j * step[:, 1])  # rotate by yaw
            pos += np.column_stack([u.real, u.imag])
            yaw += dyaw[k - 1] + rate * dist[k - 1] + e[:, 2] * sig_yaw[k - 1]
            scale += e[:, 3] * (od.scale_error_sigma * walk[k - 1])
            rate += e[:, 4] * (drift * walk[k - 1])
            if gps_bias:
                phi = math.exp(-(log.t[k] - log.t[k - 1]) / gps.bias_tau_s)
                b_mean, b_var = phi * b_mean, phi * phi * b_var + b_sig2 * (1.0 - phi * phi)
        i = fix_row.get(k, -1)
        if i >= 0:
            nu, S = log.gps_xyz[i, :2] - pos, white
            if gps_bias:
                nu, S = nu - b_mean, b_var + white
                b_mean, b_var = b_mean + b_var / S * nu, b_var * white / S
            logw -= 0.5 * np.sum(nu * nu / S, axis=1)
            logw -= logw.max() + math.log(np.exp(logw - logw.max()).sum())
        w = np.exp(logw)
        xyz[k, :2] = w @ pos
        cov[k, :2, :2] = ((pos - xyz[k, :2]) * w[:, None]).T @ (pos - xyz[k, :2])
        min_ess = min(min_ess, ess := 1.0 / float(np.sum(w * w)))
        if i >= 0 and ess < resample_ess * N:
            j = np.minimum(np.searchsorted(np.cumsum(w), (np.arange(N) + rng.uniform()) / N), N - 1)
            pos, yaw, b_mean, scale, rate = pos[j], yaw[j], b_mean[j], scale[j], rate[j]
            logw = np.full(N, -math.log(N))
            n_resamples += 1
    xyz[:, 2], cov[:, 2, 2] = z, z_var
    info = dict(n_particles=N, seed=int(seed), gps_bias=bool(gps_bias), initial=init)
    info.update(drift_hypotheses=bool(drift_hypotheses), param_walk_m=float(param_walk_m))
    info.update(resample_ess=float(resample_ess), n_resamples=n_resamples, min_ess=min_ess)
    return BaselineTrack("particle_filter", xyz, cov, {**info, "run_s": time.perf_counter() - t0})
