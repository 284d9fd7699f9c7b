"""Simulate a traverse: a rover drives waypoints over a true DEM and records GPS, odometry and
camera features (ground truth kept beside every measurement)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy.interpolate import RegularGridInterpolator
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from terrain.errors import bad_input
from terrain.grid import Grid, north_up

from .log import MeasurementLog
from .sensors import SensorSuite

__all__ = ["Surface", "densify_path", "simulate_traverse"]


class Surface:
    """Bilinear elevation and slope of a DEM ``DataArray`` in the local frame (m).

    ``origin`` (E, N) is subtracted from the DEM's projected coordinates.
    """

    def __init__(self, dem, origin: np.ndarray):
        dem = north_up(dem)  # values paired with the grid's rows (north first) below
        grid = Grid.from_dataarray(dem)
        x, y = grid.x - origin[0], grid.y - origin[1]
        self.bounds = (x[0], y[-1], x[-1], y[0])  # cell-centre hull: west, south, east, north
        self._f = RegularGridInterpolator(
            (y[::-1], x), np.asarray(dem.values, float)[::-1], bounds_error=False
        )
        self.step = float(min(grid.resolution))

    def inside(self, xy: np.ndarray, margin: float = 0.0) -> np.ndarray:
        w, s, e, n = self.bounds
        return (
            (xy[..., 0] >= w + margin)
            & (xy[..., 0] <= e - margin)
            & (xy[..., 1] >= s + margin)
            & (xy[..., 1] <= n - margin)
        )

    def z(self, xy: np.ndarray) -> np.ndarray:
        """Elevation (m) at local ``xy`` (..., 2); NaN outside the DEM."""
        xy = np.asarray(xy, float)
        return self._f(xy.reshape(-1, 2)[:, ::-1]).reshape(xy.shape[:-1])

    def normal(self, xy: np.ndarray) -> np.ndarray:
        """Unit upward surface normal (n, 3) from central differences over one cell."""
        h = self.step
        dx = (self.z(xy + [h, 0]) - self.z(xy - [h, 0])) / (2 * h)
        dy = (self.z(xy + [0, h]) - self.z(xy - [0, h])) / (2 * h)
        n = np.column_stack([-dx, -dy, np.ones_like(dx)])
        return n / np.linalg.norm(n, axis=1, keepdims=True)


def densify_path(waypoints: np.ndarray, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Points every ``spacing`` m along the polyline, and the unit direction there.

    Returns ``(xy (K, 2), direction (K, 2))``.
    """
    seg = np.diff(waypoints, axis=0)
    length = np.linalg.norm(seg, axis=1)
    keep = length > 1e-9
    seg, length, start = seg[keep], length[keep], waypoints[:-1][keep]
    if seg.size == 0:
        raise bad_input(
            "waypoints",
            waypoints.tolist()[:3],
            "a path of non-zero length",
            "give at least two distinct waypoints",
        )
    cum = np.concatenate([[0.0], np.cumsum(length)])
    s = np.arange(0.0, cum[-1] + 1e-9, spacing)
    i = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(seg) - 1)
    frac = (s - cum[i]) / length[i]
    xy = start[i] + frac[:, None] * seg[i]
    # heading: smoothed over +-2 m so that corners turn over a few keyframes, not one
    half = max(1, int(round(2.0 / spacing)))
    ahead = xy[np.minimum(np.arange(len(xy)) + half, len(xy) - 1)]
    back = xy[np.maximum(np.arange(len(xy)) - half, 0)]
    d = ahead - back
    norm = np.linalg.norm(d, axis=1, keepdims=True)
    d = np.where(norm > 1e-9, d / np.maximum(norm, 1e-12), seg[i] / length[i, None])
    return xy, d


def _body_rotations(direction: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Body-to-world rotations (K, 3, 3): z along the surface normal, x along the heading."""
    fwd = np.column_stack([direction, np.zeros(len(direction))])
    x = fwd - (fwd * normal).sum(1, keepdims=True) * normal
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    y = np.cross(normal, x)
    return np.stack([x, y, normal], axis=2)


def _gauss_markov(rng, n: int, dt: np.ndarray, sigma: np.ndarray, tau: float) -> np.ndarray:
    """First-order Gauss-Markov sequence (n, 3), stationary start, exact discretisation."""
    b = np.empty((n, 3))
    b[0] = rng.normal(0.0, 1.0, 3) * sigma
    for i in range(1, n):
        phi = math.exp(-dt[i - 1] / tau)
        b[i] = phi * b[i - 1] + rng.normal(0.0, 1.0, 3) * sigma * math.sqrt(1 - phi * phi)
    return b


def _observe(surface, cam_T, points, tree, camera, rng) -> tuple[np.ndarray, np.ndarray]:
    """Features of ``points`` (L, 3) seen by a camera at world pose ``cam_T`` (4, 4).

    Returns ``(ids (m,), uv (m, 2))``; occlusion by the terrain is honoured by marching the
    ray from the camera to the point over the DEM.
    """
    c = cam_T[:3, 3]
    ids = np.asarray(tree.query_ball_point(c[:2], camera.range_max_m), dtype=int)
    if ids.size == 0:
        return ids, np.empty((0, 2))
    ids.sort()
    pc = (points[ids] - c) @ cam_T[:3, :3]  # world -> camera frame
    rng_m = np.linalg.norm(pc, axis=1)
    ok = (pc[:, 2] > 0.1) & (rng_m >= camera.range_min_m) & (rng_m <= camera.range_max_m)
    u = camera.fx_px * pc[:, 0] / np.where(ok, pc[:, 2], 1.0) + camera.cx_px
    v = camera.fy_px * pc[:, 1] / np.where(ok, pc[:, 2], 1.0) + camera.cy_px
    ok &= (u >= 0) & (u < camera.width_px) & (v >= 0) & (v < camera.height_px)
    ids, u, v = ids[ok], u[ok], v[ok]
    if ids.size:
        frac = np.linspace(0.05, 0.95, 19)
        ray = c + frac[None, :, None] * (points[ids][:, None, :] - c)
        ground = surface.z(ray[..., :2])
        seen = ~np.any(ground > ray[..., 2] + 0.02, axis=1)
        ids, u, v = ids[seen], u[seen], v[seen]
    uv = np.column_stack([u, v]) + rng.normal(0.0, camera.pixel_sigma_px, (ids.size, 2))
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < camera.width_px)
    inside &= (uv[:, 1] >= 0) & (uv[:, 1] < camera.height_px)
    return ids[inside], uv[inside]


def simulate_traverse(
    terrain: Any,
    waypoints: Any,
    sensors: SensorSuite | None = None,
    seed: int = 0,
    crs: str | None = None,
) -> MeasurementLog:
    """Drive ``waypoints`` over the true DEM ``terrain`` and record every sensor.

    Parameters
    ----------
    terrain : xarray.DataArray
        True elevation (m) on dims (y, x) in a projected CRS (``terrain.Grid`` convention).
    waypoints : ndarray of shape (k, 2) or survey plan
        Path vertices, projected easting/northing (m). An object with a ``waypoints``
        attribute (``survey.SurveyPlan``) is accepted.
    sensors : SensorSuite, optional
        Sensor models and rover speed; defaults documented in :mod:`factorgraph.sensors`.
    seed : int
        Seed of the one ``numpy.random.Generator`` that draws every noise term.
    crs : str, optional
        CRS of the waypoints; default the DEM's.

    Returns
    -------
    MeasurementLog
        With ground truth (poses, GPS bias, landmark positions) in ``truth``.
    """
    sensors = sensors or SensorSuite()
    if not isinstance(sensors, SensorSuite):
        raise bad_input("sensors", type(sensors).__name__, "a SensorSuite", "")
    wp = getattr(waypoints, "waypoints", waypoints)
    wp = np.asarray(wp, float) if wp is not None else np.empty((0, 2))
    if wp.ndim != 2 or wp.shape[1] != 2 or len(wp) < 2:
        raise bad_input(
            "waypoints",
            wp.shape,
            "an array of shape (k >= 2, 2)",
            "plan a survey with at least two waypoints",
        )
    if not np.isfinite(wp).all():
        raise bad_input("waypoints", "NaN/inf", "finite coordinates", "repair the plan")
    grid = Grid.from_dataarray(terrain)
    rng = np.random.default_rng(seed)
    origin = wp[0].copy()
    surface = Surface(terrain, origin)
    cam = sensors.camera
    step = sensors.speed_mps * sensors.keyframe_dt_s
    xy, heading = densify_path(wp - origin, step)
    if not surface.inside(xy, margin=surface.step).all():
        bad = xy[~surface.inside(xy, margin=surface.step)][0] + origin
        raise bad_input(
            "waypoints",
            bad.tolist(),
            "a path inside the DEM (one cell in)",
            "clip the plan to the terrain extent",
        )
    K = len(xy)
    t = np.arange(K) * sensors.keyframe_dt_s
    R = _body_rotations(heading, surface.normal(xy))
    p = np.column_stack([xy, surface.z(xy)])

    # Odometry k -> k+1: true relative pose, corrupted by scale, heading drift and noise.
    od_cfg = sensors.odometry
    scale = 1.0 + rng.normal(0.0, od_cfg.scale_error_sigma)
    drift = math.radians(rng.normal(0.0, od_cfg.heading_drift_sigma_deg_per_m))  # rad / m
    rel_R = np.einsum("kji,kjl->kil", R[:-1], R[1:])  # R_k^T R_{k+1}
    rel_t = np.einsum("kji,kj->ki", R[:-1], p[1:] - p[:-1])
    dist = np.linalg.norm(rel_t, axis=1)
    noise_rot = rng.normal(0.0, math.radians(od_cfg.sigma_rotation_deg), (K - 1, 3))
    noise_rot[:, 2] += drift * dist
    meas_R = Rotation.from_matrix(rel_R) * Rotation.from_rotvec(noise_rot)
    meas_t = rel_t * scale + rng.normal(0.0, 1.0, (K - 1, 3)) * (
        od_cfg.sigma_translation_frac * dist[:, None]
    )
    odometry = np.column_stack([meas_R.as_rotvec(), meas_t])

    # GPS: fixes every 1/rate s on keyframes, Gauss-Markov bias + white noise, dropouts.
    gps_cfg = sensors.gps
    every = max(1, int(round(1.0 / (gps_cfg.rate_hz * sensors.keyframe_dt_s))))
    gk = np.arange(0, K, every)
    for a, b in gps_cfg.dropouts:
        gk = gk[(t[gk] < a) | (t[gk] >= b)]
    bias_all = _gauss_markov(rng, K, np.diff(t), np.array(gps_cfg.bias_sigma_m), gps_cfg.bias_tau_s)
    white = rng.normal(0.0, 1.0, (gk.size, 3)) * np.array(gps_cfg.sigma_white_m)
    gps_xyz = p[gk] + bias_all[gk] + white

    # Texture points on the snow around the path, then what the camera sees of them.
    lo = np.maximum(xy.min(0) - cam.range_max_m, [surface.bounds[0], surface.bounds[1]])
    hi = np.minimum(xy.max(0) + cam.range_max_m, [surface.bounds[2], surface.bounds[3]])
    n_pts = int(rng.poisson(cam.texture_density_per_m2 * float(np.prod(hi - lo))))
    pts_xy = rng.uniform(lo, hi, (n_pts, 2))
    pts = np.column_stack([pts_xy, surface.z(pts_xy)])
    tree = cKDTree(pts_xy)
    bTc = cam.body_T_camera()
    obs_k, obs_id, obs_uv = [], [], []
    for k in range(K):
        wTb = np.eye(4)
        wTb[:3, :3], wTb[:3, 3] = R[k], p[k]
        ids, uv = _observe(surface, wTb @ bTc, pts, tree, cam, rng)
        obs_k.append(np.full(ids.size, k))
        obs_id.append(ids)
        obs_uv.append(uv)
    obs_k = np.concatenate(obs_k)
    obs_id = np.concatenate(obs_id)
    obs_uv = np.concatenate(obs_uv)
    seen = np.unique(obs_id)
    tilt_up = None
    if sensors.tilt.enabled:  # measured "up" in the body frame, drawn last (streams above fixed)
        tilt_noise = np.zeros((K, 3))
        tilt_noise[:, :2] = rng.normal(0.0, math.radians(sensors.tilt.sigma_deg), (K, 2))
        up_true = R[:, 2, :]  # R_k^T e_z: world up seen in the body frame
        tilt_up = Rotation.from_rotvec(tilt_noise).apply(up_true)
    rpy = Rotation.from_matrix(R).as_euler("ZYX")[:, ::-1]  # roll, pitch, yaw
    truth = {
        "xyz": p,
        "rpy": rpy,
        "gps_bias": bias_all[gk],
        "landmark_id": seen,
        "landmark_xyz": pts[seen],
        "odometry_drift": np.array([scale - 1.0, drift]),  # scale error, heading rate (rad / m)
    }
    return MeasurementLog(
        t=t,
        odometry=odometry,
        gps_k=gk,
        gps_xyz=gps_xyz,
        obs_k=obs_k,
        obs_id=obs_id,
        obs_uv=obs_uv,
        tilt_up=tilt_up,
        sensors=sensors,
        origin=origin,
        crs=crs or grid.crs.to_string(),
        truth=truth,
        seed=seed,
    )
