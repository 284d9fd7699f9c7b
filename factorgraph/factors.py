"""Factors GTSAM does not ship: GPS with an explicit bias state, the Gauss-Markov bias
transition, and odometry with explicit drift states (scale and heading rate). All are
``gtsam.CustomFactor`` with analytic Jacobians (GTSAM's Python CustomFactor example shape)."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["biased_gps_factor", "drift_odometry_factor", "gauss_markov_factor", "gm_transition"]


def gm_transition(dt_s: float, sigma_m: np.ndarray, tau_s: float) -> tuple[float, np.ndarray]:
    """Exact discretisation of a first-order Gauss-Markov process over ``dt_s``.

    Returns ``(phi, q_sigma)``: ``b_k = phi b_{k-1} + w``, ``w ~ N(0, diag(q_sigma^2))`` with
    ``q_sigma = sigma sqrt(1 - phi^2)`` (m).
    """
    phi = math.exp(-dt_s / tau_s)
    return phi, np.asarray(sigma_m, float) * math.sqrt(max(1.0 - phi * phi, 1e-12))


def biased_gps_factor(pose_key: int, bias_key: int, measured: np.ndarray, sigma_m: np.ndarray):
    """GPS fix ``z = t(pose) + b + v``, ``v ~ N(0, diag(sigma_m^2))`` (local ENU, m).

    Error ``e = t + b - z``. Jacobians: ``de/dpose = [0_3x3, R]`` in GTSAM's Pose3 tangent
    order (rotation, translation; a translation perturbation is in the body frame), and
    ``de/db = I``.
    """
    import gtsam

    z = np.asarray(measured, float).reshape(3)
    noise = gtsam.noiseModel.Diagonal.Sigmas(np.asarray(sigma_m, float))

    def error(this, values, jacobians):
        pose = values.atPose3(this.keys()[0])
        b = values.atPoint3(this.keys()[1])
        if jacobians is not None:
            H = np.zeros((3, 6))
            H[:, 3:] = pose.rotation().matrix()
            jacobians[0] = H
            jacobians[1] = np.eye(3)
        return pose.translation() + b - z

    return gtsam.CustomFactor(noise, [pose_key, bias_key], error)


def gauss_markov_factor(prev_key: int, next_key: int, phi: float, q_sigma_m: np.ndarray):
    """Bias transition ``b_k - phi b_{k-1} ~ N(0, diag(q_sigma^2))`` between two Point3 states."""
    import gtsam

    noise = gtsam.noiseModel.Diagonal.Sigmas(np.asarray(q_sigma_m, float))
    H_prev, H_next = -phi * np.eye(3), np.eye(3)

    def error(this, values, jacobians):
        b0 = values.atPoint3(this.keys()[0])
        b1 = values.atPoint3(this.keys()[1])
        if jacobians is not None:
            jacobians[0] = H_prev
            jacobians[1] = H_next
        return b1 - phi * b0

    return gtsam.CustomFactor(noise, [prev_key, next_key], error)


def drift_odometry_factor(
    prev_key: int, next_key: int, drift_key: int, measured: np.ndarray, sigmas: np.ndarray
):
    """Odometry step with explicit drift: scale error ``s`` and heading rate ``w`` (rad / m).

    The odometer reports ``M = (R_m, t_m)`` (body frame of the earlier keyframe) with
    ``R_m = R_true Exp(n_r + [0, 0, w d])`` and ``t_m = (1 + s) t_true + n_t``, ``d = |t_m|``
    the step length (m): the drift model of :class:`factorgraph.sensors.OdometryModel`. With
    the drift state ``D = (s, w)`` (a ``Point2``) the corrected measurement is
    ``M_c = (R_m Exp([0, 0, -w d]), t_m / (1 + s))`` and the error, as in GTSAM's
    ``BetweenFactorPose3``, is ``e = Log(M_c^-1 T1^-1 T2)`` (tangent order rotation,
    translation; whitened by ``sigmas``, the white part of the odometry noise only).

    Jacobians (right perturbations, ``J = Jr^-1(e)`` = ``Pose3.LogmapDerivative``,
    ``E = M_c^-1 T1^-1 T2``, ``Ad`` the adjoint):
    ``de/dT2 = J``; ``de/dT1 = -J Ad(T2^-1 T1)``; a perturbation ``xi`` of ``M_c`` gives
    ``-J Ad(E^-1) xi``, with ``xi = (0, 0, -d, 0, 0, 0)`` per unit ``w`` and
    ``xi = (0, 0, 0, -R_c^T t_c / (1 + s))`` per unit ``s``.
    """
    import gtsam

    R_m = gtsam.Rot3.Expmap(np.asarray(measured[:3], float))
    t_m = np.asarray(measured[3:], float)
    d = float(np.linalg.norm(t_m))
    noise = gtsam.noiseModel.Diagonal.Sigmas(np.asarray(sigmas, float))

    def error(this, values, jacobians):
        T1 = values.atPose3(this.keys()[0])
        T2 = values.atPose3(this.keys()[1])
        s, w = values.atPoint2(this.keys()[2])
        R_c = R_m.compose(gtsam.Rot3.Rz(-w * d))
        t_c = t_m / (1.0 + s)
        M_c = gtsam.Pose3(R_c, t_c)
        hx = T1.between(T2)
        E = M_c.between(hx)
        e = gtsam.Pose3.Logmap(E)
        if jacobians is not None:
            J = gtsam.Pose3.LogmapDerivative(E)
            jacobians[0] = -J @ hx.inverse().AdjointMap()
            jacobians[1] = J
            xi = np.zeros((6, 2))
            xi[3:, 0] = -R_c.matrix().T @ t_c / (1.0 + s)
            xi[2, 1] = -d
            jacobians[2] = -J @ E.inverse().AdjointMap() @ xi
        return e

    return gtsam.CustomFactor(noise, [prev_key, next_key, drift_key], error)
