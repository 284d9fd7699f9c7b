"""Camera intrinsics as an OpenCV calibration file (YAML or JSON, ``cv2.FileStorage``).

Keys (what ``opencv calibrate`` / ROS ``camera_calibration`` write): ``image_width``,
``image_height``, ``camera_matrix`` (3 x 3, px) and optional ``distortion_coefficients``
(OpenCV order k1 k2 p1 p2 [k3 ...]). glacimap's own optional keys: ``mount_pitch_deg``,
``mount_height_m`` (the camera's mounting on the rover), ``pixel_sigma_px``. Tracks are
undistorted on ingest with ``cv2.undistortPoints`` back to the pinhole model of
``camera_matrix``, which is what the factor graph projects with.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from terrain.atomic import atomic_path
from terrain.errors import bad_input

from ..sensors import CameraModel

__all__ = ["read_camera", "undistort", "write_camera"]

_EXTRA = {
    "mount_pitch_deg": "pitch_deg",
    "mount_height_m": "height_m",
    "pixel_sigma_px": "pixel_sigma_px",
}


def _matrix(node, name: str, key: str) -> np.ndarray | None:
    """A matrix node of OpenCV's ``!!opencv-matrix`` form, or ROS ``camera_info`` YAML's
    ``{rows, cols, data}`` map (what ``camera_calibration`` writes); None when absent."""
    if node.empty():
        return None
    try:
        m = node.mat()
    except Exception:  # cv2.error: a map without OpenCV's ``dt`` (the ROS layout)
        m = None
    if m is None and node.isMap():
        rows, cols, data = (node.getNode(k) for k in ("rows", "cols", "data"))
        if not (rows.empty() or cols.empty() or data.empty()) and data.isSeq():
            vals = [data.at(i).real() for i in range(data.size())]
            shape = (int(rows.real()), int(cols.real()))
            if len(vals) == shape[0] * shape[1]:
                m = np.asarray(vals, float).reshape(shape)
    if m is None:
        raise bad_input(
            f"{name} {key}",
            "not a matrix",
            "an OpenCV !!opencv-matrix or a {rows, cols, data} map",
            "see docs/field-format.md (camera.yaml)",
        )
    return np.asarray(m, float)


def read_camera(path: str | Path, base: CameraModel) -> tuple[CameraModel, np.ndarray | None]:
    """``(camera, distortion or None)`` from an OpenCV calibration file; keys it lacks keep
    the values of ``base`` (the survey's stated camera)."""
    import cv2

    path = Path(path)
    if not path.is_file():
        raise bad_input(
            "camera", str(path), "an OpenCV calibration YAML/JSON", "check the file name"
        )
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except cv2.error as exc:
        raise bad_input(path.name, str(exc)[:120], "an OpenCV YAML/JSON file", "") from exc
    try:
        K = _matrix(fs.getNode("camera_matrix"), path.name, "camera_matrix")
        if K is None or np.shape(K) != (3, 3) or not np.isfinite(K).all():
            raise bad_input(
                f"{path.name} camera_matrix", None if K is None else np.shape(K), "a 3x3 matrix", ""
            )
        kw = {"fx_px": K[0, 0], "fy_px": K[1, 1], "cx_px": K[0, 2], "cy_px": K[1, 2]}
        for key, name in (("image_width", "width_px"), ("image_height", "height_px")):
            node = fs.getNode(key)
            if not node.empty():
                kw[name] = int(node.real())
        for key, name in _EXTRA.items():
            node = fs.getNode(key)
            if not node.empty():
                kw[name] = float(node.real())
        d = _matrix(fs.getNode("distortion_coefficients"), path.name, "distortion_coefficients")
        dist = None if d is None else np.asarray(d, float).ravel()
        model = fs.getNode("distortion_model")
        model = "" if model.empty() else str(model.string())
        if model and model not in ("plumb_bob", "rational_polynomial"):
            raise bad_input(
                f"{path.name} distortion_model",
                model,
                "plumb_bob or rational_polynomial (OpenCV's k1 k2 p1 p2 [k3 ...] model)",
                "undistort the tracks beforehand (e.g. cv2.fisheye.undistortPoints) and give "
                "the pinhole camera_matrix with zero distortion",
            )
    finally:
        fs.release()
    if dist is not None and not np.any(dist):
        dist = None
    return replace(base, **{k: float(v) if k.endswith("_px") else v for k, v in kw.items()}), dist


def write_camera(path: str | Path, camera: CameraModel) -> Path:
    """Write ``camera`` as an OpenCV YAML calibration file (atomically)."""
    import cv2

    path = Path(path)
    K = np.array(
        [[camera.fx_px, 0.0, camera.cx_px], [0.0, camera.fy_px, camera.cy_px], [0.0, 0.0, 1.0]]
    )
    with atomic_path(path) as tmp:
        flags = cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_FORMAT_YAML
        fs = cv2.FileStorage(str(tmp), flags)
        fs.write("image_width", int(camera.width_px))
        fs.write("image_height", int(camera.height_px))
        fs.write("camera_matrix", K)
        fs.write("distortion_coefficients", np.zeros((1, 5)))
        for key, name in _EXTRA.items():
            fs.write(key, float(getattr(camera, name)))
        fs.release()
    return path


def undistort(uv: np.ndarray, camera: CameraModel, dist: np.ndarray | None) -> np.ndarray:
    """Pixel coordinates (M, 2) of the ideal pinhole camera (``cv2.undistortPoints``)."""
    if dist is None or not len(uv):
        return np.asarray(uv, float)
    import cv2

    K = np.array(
        [[camera.fx_px, 0.0, camera.cx_px], [0.0, camera.fy_px, camera.cy_px], [0.0, 0.0, 1.0]]
    )
    pts = np.asarray(uv, np.float64).reshape(-1, 1, 2)
    return cv2.undistortPoints(pts, K, dist, P=K).reshape(-1, 2)
