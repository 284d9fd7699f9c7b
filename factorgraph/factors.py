"""Factors GTSAM does not ship: GPS with an explicit bias state, and the Gauss-Markov bias
transition. Both are ``gtsam.CustomFactor`` with analytic Jacobians (GTSAM's Python
CustomFactor example shape)."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["biased_gps_factor", "gauss_markov_factor", "gm_transition"]


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
