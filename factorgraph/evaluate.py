"""Scores for localization tracks: horizontal RMSE, NEES, and the GPS-bias accuracy floor.

The floor: a consumer GPS carries a first-order Gauss-Markov bias ``b(t)`` (per axis,
stationary standard deviation ``sigma_b``, correlation time ``tau``; see
:class:`factorgraph.sensors.GPSModel`). Odometry and vision measure only relative motion, so
no fusion of them with that GPS can tell a bias that is constant over the traverse from a
shift of the whole trajectory: the traverse mean of the bias stays in every estimate. Its
standard deviation is the floor below which no estimator's absolute error can go on average.

:func:`bias_floor` / :func:`horizontal_floor` give that floor as the standard deviation of the
continuous time average of ``b`` (the issue's definition). :func:`offset_floor` is the exact
floor for the sampled problem: the standard deviation of the best linear unbiased (generalised
least squares) estimate of a constant position offset from the GPS fixes actually received,
white noise and dropouts included. The two differ: the time average is not the best weighting
of a Gauss-Markov record, and the white noise adds ``sigma_white^2 / n``.
"""

from __future__ import annotations

import math

import numpy as np

from terrain.errors import bad_input

from .sensors import GPSModel

__all__ = [
    "bias_floor",
    "frame_floor",
    "gls_offset_sd",
    "horizontal_floor",
    "horizontal_rmse",
    "nees",
    "offset_floor",
]


def _check_noise_params(params) -> None:
    """Raise the one error for a non-finite or out-of-range noise parameter.

    ``params``: ``(name, value, zero_ok)`` triples; ``zero_ok`` allows 0, else value > 0.
    """
    for name, v, zero_ok in params:
        try:
            ok = math.isfinite(float(v)) and (float(v) >= 0 if zero_ok else float(v) > 0)
        except (TypeError, ValueError):
            ok = False
        if not ok:
            want = "a finite number >= 0" if zero_ok else "a finite number > 0"
            raise bad_input(name, v, want, "pass the GPS model's value in m or s")


def horizontal_rmse(xyz_est: np.ndarray, xyz_true: np.ndarray) -> float:
    """Root mean square of the horizontal error norm (m).

    Parameters
    ----------
    xyz_est, xyz_true : ndarray of shape (K, 2) or (K, 3)
        Estimated and true positions, local ENU (m); only east and north are used.

    Returns
    -------
    float
        ``sqrt(mean_k (de_k^2 + dn_k^2))`` in metres.
    """
    a, b = np.asarray(xyz_est, float), np.asarray(xyz_true, float)
    if a.ndim != 2 or a.shape[1] < 2 or a.shape != b.shape or a.shape[0] == 0:
        raise bad_input(
            "xyz_est", (a.shape, b.shape), "two equal (K >= 1, 2 or 3) arrays", "align tracks"
        )
    d = a[:, :2] - b[:, :2]
    return float(math.sqrt(np.mean(np.sum(d * d, axis=1))))


def bias_floor(sigma_b: float, tau_s: float, duration_s: float) -> float:
    """Standard deviation (m) of the time average of a stationary Gauss-Markov process.

    For ``b`` with autocovariance ``sigma_b^2 exp(-|s|/tau)``, the average
    ``(1/T) int_0^T b(t) dt`` has variance

    ``2 sigma_b^2 (tau/T) [1 - (tau/T)(1 - exp(-T/tau))]``,

    which tends to ``sigma_b^2 2 tau/T`` for ``T >> tau`` and to ``sigma_b^2`` for ``T << tau``.

    Parameters
    ----------
    sigma_b : float
        Stationary 1-sigma of the bias on one axis (m), >= 0.
    tau_s : float
        Correlation time (s), > 0.
    duration_s : float
        Averaging time ``T`` (s), > 0: the traverse duration.

    Returns
    -------
    float
        The floor on one axis (m).
    """
    _check_noise_params(
        (("sigma_b", sigma_b, True), ("tau_s", tau_s, False), ("duration_s", duration_s, False))
    )
    r = float(tau_s) / float(duration_s)
    # -expm1(-1/r) = 1 - exp(-T/tau) without cancellation for T << tau
    var_frac = 2.0 * r * (1.0 - r * -math.expm1(-1.0 / r))
    return float(sigma_b) * math.sqrt(max(var_frac, 0.0))


def horizontal_floor(gps_model: GPSModel, duration_s: float) -> float:
    """Horizontal bias floor (m): ``sqrt(floor_e^2 + floor_n^2)`` of :func:`bias_floor`.

    Parameters
    ----------
    gps_model : GPSModel
        Its ``bias_sigma_m`` (east, north) and ``bias_tau_s`` are used.
    duration_s : float
        Traverse duration (s).
    """
    if not isinstance(gps_model, GPSModel):
        raise bad_input("gps_model", type(gps_model).__name__, "a GPSModel", "")
    e, n = (bias_floor(s, gps_model.bias_tau_s, duration_s) for s in gps_model.bias_sigma_m[:2])
    return math.hypot(e, n)


def nees(err: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Normalised estimation error squared ``e_k^T P_k^-1 e_k`` per row.

    Parameters
    ----------
    err : ndarray of shape (n, d)
        Estimate minus truth (m).
    cov : ndarray of shape (n, d, d)
        The estimator's stated covariance of each row (m^2), symmetric positive definite.

    Returns
    -------
    ndarray of shape (n,)
        Chi-square distributed with ``d`` degrees of freedom for a consistent estimator
        (mean ``d``). Computed by a linear solve, never an explicit inverse.
    """
    e, P = np.asarray(err, float), np.asarray(cov, float)
    if e.ndim != 2 or P.shape != (e.shape[0], e.shape[1], e.shape[1]):
        raise bad_input("cov", (e.shape, P.shape), "err (n, d) with cov (n, d, d)", "")
    try:
        x = np.linalg.solve(P, e[:, :, None])[:, :, 0]
    except np.linalg.LinAlgError as exc:
        raise bad_input("cov", "a singular matrix", "positive definite covariances", "") from exc
    return np.einsum("nd,nd->n", e, x)


def gls_offset_sd(
    fix_times_s: np.ndarray, sigma_b: float, tau_s: float, sigma_white: float
) -> float:
    """Standard deviation (m) of the GLS estimate of a constant offset on one axis.

    Observations ``y_i = p0 + b(t_i) + v_i`` at times ``t_i``: ``b`` a stationary first-order
    Gauss-Markov process (covariance ``sigma_b^2 exp(-|t_i - t_j| / tau)``), ``v`` white
    (``sigma_white^2``). With ``C = C_b + sigma_white^2 I`` the best linear unbiased estimate of
    ``p0`` (the MAP under a flat prior, the data being Gaussian) has variance

    ``1 / (1^T C^-1 1)``,

    accumulated in O(n) time and memory by a Kalman filter (:func:`_gm_information`; the
    tests check it against a dense Cholesky solve and a state-augmented Kalman filter).

    Parameters
    ----------
    fix_times_s : array_like of shape (n,)
        Times of the fixes received (s), n >= 1, any order; gaps (dropouts) simply have none.
    sigma_b : float
        Stationary 1-sigma of the bias (m), >= 0.
    tau_s : float
        Bias correlation time (s), > 0.
    sigma_white : float
        White-noise 1-sigma (m), >= 0.

    Returns
    -------
    float
        The standard deviation (m); 0.0 when both noise levels are 0.
    """
    t = np.asarray(fix_times_s, float)
    if t.ndim != 1 or t.size == 0 or not np.isfinite(t).all():
        raise bad_input(
            "fix_times_s", t.shape, "a 1-D array of >= 1 finite times (s)", "pass log.t[log.gps_k]"
        )
    _check_noise_params(
        (("sigma_b", sigma_b, True), ("tau_s", tau_s, False), ("sigma_white", sigma_white, True))
    )
    sb2, sv2 = float(sigma_b) ** 2, float(sigma_white) ** 2
    if sb2 == 0.0 and sv2 == 0.0:
        return 0.0
    if sb2 == 0.0:  # white noise only: the plain mean, no matrix needed
        return math.sqrt(sv2 / t.size)
    info = _gm_information(t, np.ones((t.size, 1)), sigma_b, tau_s, sigma_white)
    return 1.0 / math.sqrt(float(info[0, 0]))


def offset_floor(gps_model: GPSModel, fix_times_s: np.ndarray, axes: bool = False):
    """Exact horizontal accuracy floor (m) of a constant position offset from GPS fixes.

    The standard deviation of the best (GLS) estimate of a constant offset ``p0`` from fixes
    ``y_i = p0 + b(t_i) + v_i`` at the fix times actually received (:func:`gls_offset_sd` per
    axis, with the model's ``bias_sigma_m``, ``bias_tau_s`` and ``sigma_white_m``). It is what an
    estimator that knew the relative path perfectly (no odometry or vision error) would reach;
    one that must also estimate the path's shape, scale or heading cannot do better on
    average. Dropouts count because only the fixes received enter. Unlike
    :func:`horizontal_floor` (time average of the bias alone), it includes the white noise and
    the optimal weighting of a Gauss-Markov record, which lies below the plain time average:
    without white noise it is the smaller of the two.

    Parameters
    ----------
    gps_model : GPSModel
        Noise model of the fixes.
    fix_times_s : array_like of shape (n,)
        Times of the fixes received (s), e.g. ``log.t[log.gps_k]``.
    axes : bool
        Return the per-axis values instead.

    Returns
    -------
    float or ndarray of shape (3,)
        ``sqrt(var_e + var_n)`` in metres; with ``axes=True`` the three per-axis standard
        deviations (east, north, up; m).
    """
    if not isinstance(gps_model, GPSModel):
        raise bad_input("gps_model", type(gps_model).__name__, "a GPSModel", "")
    cache: dict[tuple[float, float], float] = {}
    sd = []
    n_axes = 3 if axes else 2  # the vertical costs a factorisation only when asked for
    for sb, sv in zip(gps_model.bias_sigma_m[:n_axes], gps_model.sigma_white_m, strict=False):
        if (sb, sv) not in cache:
            cache[sb, sv] = gls_offset_sd(fix_times_s, sb, gps_model.bias_tau_s, sv)
        sd.append(cache[sb, sv])
    if axes:
        return np.array(sd)
    return math.hypot(sd[0], sd[1])


def _gm_information(
    t: np.ndarray, jac: np.ndarray, sigma_b: float, tau_s: float, sigma_white: float
) -> np.ndarray:
    """``J^T C^-1 J`` for ``C = sigma_b^2 exp(-|t_i - t_j| / tau) + sigma_white^2 I``, O(n p^2).

    The prediction-error decomposition: a scalar Kalman filter for the noise ``b + v`` (``b``
    the Gauss-Markov bias, ``v`` white), run on the columns of ``J`` as if they were data,
    turns them into innovations ``e_i`` of variance ``S_i`` with ``J^T C^-1 J = sum_i e_i e_i^T /
    S_i``. Same result as a dense Cholesky solve (tested to 1e-10), without the n x n matrix: an
    8-hour log at 1 Hz (28,800 fixes) would need 6.6 GB for it.
    """
    order = np.argsort(t, kind="stable")
    sb2, sv2 = float(sigma_b) ** 2, float(sigma_white) ** 2
    m, var = np.zeros(jac.shape[1]), sb2  # filtered bias "estimate" per column, its variance
    info = np.zeros((jac.shape[1], jac.shape[1]))
    prev = None
    for ti, ji in zip(t[order], jac[order], strict=True):
        if prev is not None:  # propagate the bias over the gap: b' = phi b + w
            phi = math.exp(-(ti - prev) / float(tau_s))
            m, var = phi * m, phi * phi * var + sb2 * (1.0 - phi * phi)
        prev = ti
        e, s_var = ji - m, var + sv2  # innovation and its variance
        info += np.outer(e, e) / s_var
        gain = var / s_var
        m, var = m + gain * e, var - gain * var
    return info


def _frame_jacobians(d: np.ndarray, n_params: int) -> tuple[np.ndarray, np.ndarray]:
    """East and north rows of d(position)/d(offset e, offset n, yaw, scale) at offsets ``d``.

    A small yaw ``w`` and scale error ``s`` about the centre move ``d`` by ``w (-d_n, d_e) +
    s (d_e, d_n)``; the columns beyond ``n_params`` are dropped.
    """
    one, zero = np.ones(len(d)), np.zeros(len(d))
    je = np.stack([one, zero, -d[:, 1], d[:, 0]], axis=1)[:, :n_params]
    jn = np.stack([zero, one, d[:, 0], d[:, 1]], axis=1)[:, :n_params]
    return je, jn


def frame_floor(
    gps_model: GPSModel,
    fix_times_s: np.ndarray,
    fix_xy: np.ndarray,
    path_xy: np.ndarray | None = None,
    heading: bool = True,
    scale_sigma: float = 0.0,
) -> float:
    """Horizontal floor (m) of a traverse whose shape is known but whose frame is not.

    Odometry and vision measure the path only up to a rigid motion: neither sees the absolute
    position nor the absolute heading, and wheel odometry's scale is known only to its
    calibration (``OdometryModel.scale_error_sigma``). An estimator given the *exact* relative
    path must still fit these frame parameters ``theta`` = (east offset, north offset[, yaw][,
    scale]) to the biased fixes, ``y_i = p_i + J_i theta + b(t_i) + v_i``. The best linear
    unbiased (GLS) fit has covariance

    ``P = (sum_axes J_a^T C_a^-1 J_a + prior)^-1``,  ``C_a`` as in :func:`gls_offset_sd`,

    (accumulated in O(n) by a Kalman filter, :func:`_gm_information`; a path without extent
    leaves yaw and scale unobservable and harmless, hence a pseudo-inverse), and this returns
    ``sqrt(mean_k trace(J_k P J_k^T))`` over the evaluation path: the RMSE
    that estimator reaches on average. With ``heading=False`` and ``scale_sigma=0`` it equals
    :func:`offset_floor`; each added parameter can only raise it. Every real estimator, which
    must also estimate the path's shape, lies above it.

    Parameters
    ----------
    gps_model : GPSModel
        Noise model of the fixes (east and north axes).
    fix_times_s : array_like of shape (n,)
        Times of the fixes received (s).
    fix_xy : array_like of shape (n, 2) or (n, 3)
        True positions at those fixes, local ENU (m); only east and north are used.
    path_xy : array_like of shape (K, 2) or (K, 3), optional
        Positions at which the error is averaged (m), e.g. every keyframe; default ``fix_xy``.
    heading : bool
        Estimate a yaw rotation of the whole path (no absolute heading sensor).
    scale_sigma : float
        Prior 1-sigma of the path's scale error (fraction, >= 0): 0 treats the scale as known,
        ``math.inf`` as unknown.

    Returns
    -------
    float
        The floor in metres.
    """
    t = np.asarray(fix_times_s, float)
    p = np.asarray(fix_xy, float)
    q = p if path_xy is None else np.asarray(path_xy, float)
    if t.ndim != 1 or p.ndim != 2 or p.shape[0] != t.size or p.shape[1] < 2 or t.size == 0:
        raise bad_input(
            "fix_xy", (t.shape, p.shape), "fix_times_s (n,) with fix_xy (n, 2 or 3)", "align them"
        )
    if not (np.isfinite(t).all() and np.isfinite(p[:, :2]).all()):
        raise bad_input("fix_xy", "NaN or inf", "finite fix times and positions", "drop them")
    if q.ndim != 2 or q.shape[1] < 2 or q.shape[0] == 0:
        raise bad_input("path_xy", q.shape, "an array (K >= 1, 2 or 3)", "pass keyframe xyz")
    try:
        s_ok = float(scale_sigma) >= 0
    except (TypeError, ValueError):
        s_ok = False
    if not s_ok:
        raise bad_input("scale_sigma", scale_sigma, "a fraction >= 0 (inf: unknown)", "")
    from scipy.linalg import pinvh

    n_params = 2 + int(bool(heading)) + int(float(scale_sigma) > 0)
    centre = p[:, :2].mean(axis=0)
    jac = _frame_jacobians(p[:, :2] - centre, n_params)
    tau = gps_model.bias_tau_s
    noise = [(gps_model.bias_sigma_m[a], gps_model.sigma_white_m[a]) for a in (0, 1)]
    if noise[0] == noise[1]:  # same gains on both axes: one filter pass over both
        both = _gm_information(t, np.hstack(jac), noise[0][0], tau, noise[0][1])
        info = both[:n_params, :n_params] + both[n_params:, n_params:]
    else:
        info = sum(
            _gm_information(t, j, sb, tau, sv) for (sb, sv), j in zip(noise, jac, strict=True)
        )
    if n_params == 4 and math.isfinite(float(scale_sigma)):
        info[3, 3] += float(scale_sigma) ** -2  # the calibration prior on the scale
    cov = pinvh(info)
    var = sum(
        np.einsum("ki,ij,kj->k", j, cov, j) for j in _frame_jacobians(q[:, :2] - centre, n_params)
    )
    return float(math.sqrt(np.mean(var)))
