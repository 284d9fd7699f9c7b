"""Where a camera's features lie: the flat ground under the rover seen through the camera
model (the detection region, the odometry's predicted motion of a feature between
keyframes) and the lens (detected pixels undistorted to the pinhole camera's)."""

from __future__ import annotations

from typing import Any

import numpy as np

from terrain.errors import bad_input

from ..sensors import CameraModel

__all__ = ["detection_mask", "predict_motion", "undistorter"]


def _ground_points(uv: np.ndarray, camera: CameraModel) -> tuple[np.ndarray, np.ndarray]:
    """Points (n, 3) in the body frame where the rays of ``uv`` (n, 2) meet the flat ground
    (z_body = 0), capped at twice the camera range; and the camera centre (3,)."""
    bTc = camera.body_T_camera()
    bRc, c_b = bTc[:3, :3], bTc[:3, 3]
    d_c = np.column_stack(
        [
            (uv[:, 0] - camera.cx_px) / camera.fx_px,
            (uv[:, 1] - camera.cy_px) / camera.fy_px,
            np.ones(len(uv)),
        ]
    )
    d_b = d_c @ bRc.T
    far = 2.0 * camera.range_max_m
    s = np.where(d_b[:, 2] < -1e-6, -c_b[2] / np.minimum(d_b[:, 2], -1e-6), np.inf)
    s = np.minimum(s, far / np.linalg.norm(d_b, axis=1))
    return c_b + s[:, None] * d_b, c_b


def detection_mask(camera: CameraModel, max_ground_range_m: float | None) -> np.ndarray | None:
    """uint8 mask (H, W): 255 where the flat ground is nearer than ``max_ground_range_m``."""
    if max_ground_range_m is None:
        return None
    u, v = np.meshgrid(np.arange(camera.width_px), np.arange(camera.height_px))
    X, c = _ground_points(np.column_stack([u.ravel(), v.ravel()]).astype(float), camera)
    rng = np.linalg.norm(X[:, :2] - c[:2], axis=1)
    return np.where(rng <= max_ground_range_m, 255, 0).astype(np.uint8).reshape(u.shape)


def predict_motion(uv: np.ndarray, camera: CameraModel, step: np.ndarray) -> np.ndarray:
    """Predicted pixels (n, 2) in the next keyframe of features at ``uv`` (n, 2), for the
    odometry ``step`` (6,) (rotation vector rad, translation m: pose of k+1 in body k), with
    every feature on the flat ground plane under the rover (z_body = 0) or, above the
    horizon, at twice the camera range."""
    from scipy.spatial.transform import Rotation

    X_b, c_b = _ground_points(uv, camera)
    bRc = camera.body_R_camera()
    R = Rotation.from_rotvec(step[:3]).as_matrix()
    X_b1 = (X_b - step[3:]) @ R  # R^T (X - t)
    X_c1 = (X_b1 - c_b) @ bRc
    z = np.maximum(X_c1[:, 2], 1e-3)
    return np.column_stack(
        [camera.fx_px * X_c1[:, 0] / z + camera.cx_px, camera.fy_px * X_c1[:, 1] / z + camera.cy_px]
    ), X_c1[:, 2] > 0.1


def undistorter(camera: CameraModel, distortion: Any, detector: str = "sift"):
    """Detected pixels (n, 2) -> the pinhole camera's (identity without ``distortion``)."""
    if distortion is None:
        return lambda pts: pts
    dist = np.asarray(distortion, float).ravel()
    if dist.size not in (4, 5, 8, 12, 14) or not np.all(np.isfinite(dist)):
        raise bad_input("distortion", dist.tolist(), "4, 5, 8, 12 or 14 finite coefficients", "")
    if detector == "klt":
        raise bad_input(
            "distortion",
            "with detector='klt'",
            "a descriptor detector (sift, orb, akaze): KLT follows pixels in the recorded image",
            "undistort the frames first (cv2.undistort), or use detector='sift'",
        )
    from ..field.intrinsics import undistort  # cv2.undistortPoints, pinhole pixels out

    return lambda pts: undistort(pts, camera, dist).astype(np.float32) if len(pts) else pts
