"""Simulated ground control for a simulated traverse: the rover stops on surveyed points (the
``control_id`` keyframe column) and, optionally, the camera tracks marked targets.

The traverse itself is not changed (same seed, same bytes): the control draws come from
their own stream, child 1 of the seed's ``numpy.random.SeedSequence``.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np

from terrain.errors import bad_input

from .control import ControlPoints
from .log import MeasurementLog

__all__ = ["nearest_keyframes", "path_corners", "simulate_control", "simulate_targets"]


def nearest_keyframes(log: MeasurementLog, xy: np.ndarray) -> np.ndarray:
    """Keyframe (n,) whose true position is nearest each projected point ``xy`` (n, 2)."""
    if not log.has_truth:
        raise bad_input("log", "no truth", "a simulated log", "use simulate_traverse()")
    path = log.truth["xyz"][:, :2] + log.origin
    pts = np.asarray(xy, float).reshape(-1, 2)
    return np.array([int(np.argmin(np.linalg.norm(path - p, axis=1))) for p in pts], int)


def path_corners(log: MeasurementLog) -> np.ndarray:
    """Keyframes (4,) nearest to the corners of the true path's bounding box (SW, SE, NE, NW):
    on a lawnmower, the survey's four corners, where the swaths turn."""
    if not log.has_truth:
        raise bad_input("log", "no truth", "a simulated log", "use simulate_traverse()")
    xy = log.truth["xyz"][:, :2] + log.origin
    (w, s), (e, n) = xy.min(0), xy.max(0)
    return nearest_keyframes(log, np.array([[w, s], [e, s], [e, n], [w, n]]))


def simulate_control(
    log: MeasurementLog,
    keyframes: Any = None,
    sigma_m: float | tuple[float, float, float] = 0.02,
    centring_sigma_m: float = 0.02,
    seed: int | None = None,
    names: Any = None,
) -> tuple[MeasurementLog, ControlPoints, np.ndarray]:
    """Stop the rover on control points at ``keyframes`` and survey them.

    The mark lies where the rover's body origin truly was at the stop keyframe, off by the
    centring error ``N(0, centring_sigma_m^2)`` per axis; the surveyed coordinates add the
    survey error ``N(0, sigma_m^2)`` per axis.

    Parameters
    ----------
    log : MeasurementLog
        A simulated log (with truth).
    keyframes : sequence of int, optional
        Stop keyframes, one per control point; default :func:`path_corners` (4 corners).
    sigma_m : float or 3 floats
        1-sigma of the survey (m, E N U); the stated sigma of the returned points.
    centring_sigma_m : float
        1-sigma of the rover over the mark (m, per axis).
    seed : int, optional
        Default the log's seed.
    names : sequence of str, optional
        Point ids; default ``GCP1..GCPn``.

    Returns
    -------
    log : MeasurementLog
        The same log with ``control_id`` naming the points at their stop keyframes.
    control : ControlPoints
        Surveyed points in the log's CRS (projected easting, northing, elevation).
    true_xyz : ndarray of shape (n, 3)
        True mark positions, projected CRS.
    """
    ks = path_corners(log) if keyframes is None else np.asarray(keyframes, int).reshape(-1)
    if ks.size == 0 or ks.min() < 0 or ks.max() >= log.n_keyframes:
        raise bad_input("keyframes", ks.tolist(), f"indices in [0, {log.n_keyframes})", "")
    n = ks.size
    ids = np.array([f"GCP{i + 1}" for i in range(n)] if names is None else list(names), str)
    seed = int(log.seed or 0) if seed is None else int(seed)
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(1,)))
    sigma = np.broadcast_to(np.asarray(sigma_m, float), (n, 3))
    true = log.truth["xyz"][ks] + rng.normal(0.0, 1.0, (n, 3)) * centring_sigma_m
    true[:, :2] += log.origin
    surveyed = true + rng.normal(0.0, 1.0, (n, 3)) * sigma
    control_id = np.full(log.n_keyframes, "", dtype=object)
    if log.control_id is not None:
        control_id[:] = log.control_id
    taken = [int(k) for k in ks if control_id[k] != ""]
    if taken or len(set(ks.tolist())) < n:
        raise bad_input("keyframes", ks.tolist(), "one new stop per keyframe", "pick others")
    control_id[ks] = ids
    ctrl = ControlPoints(ids, surveyed, sigma, log.crs, None, centring_sigma_m, "simulated")
    if not math.isfinite(float(surveyed.sum())):
        raise bad_input("log.truth", "non-finite", "finite true positions", "")
    return replace(log, control_id=control_id.astype(str)), ctrl, true


def simulate_targets(
    log: MeasurementLog,
    terrain: Any,
    xy: Any = None,
    sigma_m: float | tuple[float, float, float] = 0.02,
    outward_m: float = 6.0,
    seed: int | None = None,
) -> tuple[MeasurementLog, ControlPoints, np.ndarray]:
    """Marked targets on the snow that the camera tracks, surveyed as control points.

    Parameters
    ----------
    log : MeasurementLog
        A simulated log (with truth); its camera model observes the targets.
    terrain : xarray.DataArray
        The true DEM the log was simulated on (targets sit on it; occlusion).
    xy : ndarray of shape (n, 2), optional
        Target positions, projected CRS. Default: the path's 4 corners (:func:`path_corners`)
        moved ``outward_m`` along each axis away from the path's centre, so that the rover
        sees them from the side (a target straight ahead gives no parallax).
    sigma_m : float or 3 floats
        1-sigma of the survey (m).
    seed : int, optional
        Default the log's seed; the draws are child 2 of its ``SeedSequence``.

    Returns
    -------
    log : MeasurementLog
        With the targets' observations appended (track ids above every other track id).
    control : ControlPoints
        Surveyed targets with ``target_id`` (ids ``T1..Tn``).
    true_xyz : ndarray of shape (n, 3)
        True target positions, projected CRS.
    """
    from scipy.spatial import cKDTree
    from scipy.spatial.transform import Rotation

    from .simulate import Surface, _observe

    if not log.has_truth:
        raise bad_input("log", "no truth", "a simulated log", "use simulate_traverse()")
    path = log.truth["xyz"]
    if xy is None:
        centre = path[:, :2].mean(0)
        corners = path[path_corners(log), :2]
        xy = corners + np.sign(corners - centre) * outward_m + log.origin
    xy_local = np.asarray(xy, float).reshape(-1, 2) - log.origin
    n = len(xy_local)
    seed = int(log.seed or 0) if seed is None else int(seed)
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(2,)))
    surface = Surface(terrain, log.origin)
    pts = np.column_stack([xy_local, surface.z(xy_local)])
    if not np.isfinite(pts).all():
        raise bad_input("xy", np.asarray(xy).tolist(), "targets on the DEM", "move them inside")
    R = Rotation.from_euler("ZYX", log.truth["rpy"][:, ::-1]).as_matrix()
    cam, tree = log.sensors.camera, cKDTree(xy_local)
    first = int(max(log.obs_id.max(initial=-1), log.truth.get("landmark_id", [-1]).max()) + 1)
    ks, ids, uvs = [log.obs_k], [log.obs_id], [log.obs_uv]
    for k in range(log.n_keyframes):
        wTb = np.eye(4)
        wTb[:3, :3], wTb[:3, 3] = R[k], path[k]
        j, uv = _observe(surface, wTb @ cam.body_T_camera(), pts, tree, cam, rng)
        ks.append(np.full(j.size, k))
        ids.append(j + first)
        uvs.append(uv)
    sigma = np.broadcast_to(np.asarray(sigma_m, float), (n, 3))
    true = pts + np.r_[log.origin, 0.0]
    surveyed = true + rng.normal(0.0, 1.0, (n, 3)) * sigma
    names = [f"T{i + 1}" for i in range(n)]
    ctrl = ControlPoints(names, surveyed, sigma, log.crs, np.arange(n) + first, 0.0, "simulated")
    obs = {"obs_k": np.concatenate(ks), "obs_id": np.concatenate(ids)}
    truth = dict(log.truth)  # the targets are landmarks too (ids above the others: sorted)
    truth["landmark_id"] = np.r_[truth.get("landmark_id", np.zeros(0, int)), np.arange(n) + first]
    truth["landmark_xyz"] = np.r_[truth.get("landmark_xyz", np.zeros((0, 3))), pts]
    return replace(log, **obs, obs_uv=np.concatenate(uvs), truth=truth), ctrl, true
