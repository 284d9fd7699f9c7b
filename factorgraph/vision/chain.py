"""Images into the factor graph: render a simulated traverse, track it, and swap the tracks
into its measurement log (ground truth of each track from the renderer)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from terrain.errors import bad_input

from ..log import MeasurementLog
from ..sensors import CameraModel, SensorSuite
from ..simulate import simulate_traverse
from .camera_frames import read_frames, write_frames
from .render import VISION_CAMERA, Renderer, Scene, render_frames
from .track_cache import save_tracks
from .tracking import FeatureTracks, TrackParams, track_features

__all__ = [
    "ImageRun",
    "attach_tracks",
    "simulate_images",
    "track_log_frames",
    "track_truth",
    "vision_sensors",
]

#: Camera fields the vision preset sets (the rest, e.g. texture density, stay the caller's).
_GEOMETRY = (
    "width_px",
    "height_px",
    "fx_px",
    "fy_px",
    "cx_px",
    "cy_px",
    "pitch_deg",
    "height_m",
    "range_max_m",
    "range_min_m",
)


def vision_sensors(sensors: SensorSuite | None = None, camera: CameraModel = VISION_CAMERA):
    """``sensors`` with the camera geometry of ``camera`` (default :data:`VISION_CAMERA`);
    noise and texture density stay as they were."""
    sensors = sensors or SensorSuite()
    geo = {f.name: getattr(camera, f.name) for f in fields(camera) if f.name in _GEOMETRY}
    return replace(sensors, camera=replace(sensors.camera, **geo))


def attach_tracks(
    log: MeasurementLog, tracks: FeatureTracks, landmark_xyz: np.ndarray | None = None
) -> MeasurementLog:
    """A copy of ``log`` whose observations are ``tracks``; its landmark truth becomes
    ``landmark_xyz`` (one row per track id 0..n-1, NaN rows dropped) or is removed."""
    truth = {k: v for k, v in log.truth.items() if k not in ("landmark_id", "landmark_xyz")}
    if landmark_xyz is not None:
        ok = np.isfinite(landmark_xyz).all(1)
        truth["landmark_id"] = np.flatnonzero(ok)
        truth["landmark_xyz"] = landmark_xyz[ok]
    return replace(log, obs_k=tracks.k, obs_id=tracks.landmark_id, obs_uv=tracks.uv, truth=truth)


def track_log_frames(
    log: MeasurementLog,
    folder: str | Path,
    params: TrackParams | None = None,
    distortion: np.ndarray | None = None,
    progress: Any = None,
) -> tuple[MeasurementLog, dict[str, Any]]:
    """Run the front-end on a log's frames and put its tracks in the log.

    Parameters
    ----------
    log : MeasurementLog
        Keyframe times ``t`` (s, the clock of ``folder/timestamps.csv``), camera and odometry.
    folder : path
        Frames and ``timestamps.csv`` (:func:`read_frames`; missing, unreadable or wrongly
        sized frames are skipped and counted).
    params : TrackParams, optional
        Front-end settings.
    distortion : ndarray, optional
        The lens's OpenCV distortion coefficients (a field folder's ``camera.yaml``): the
        tracks come out in the pinhole camera's pixels (:func:`track_features`).
    progress : callable, optional
        ``progress(k, K)`` after each keyframe's frame is tracked (not called when the
        stored tracks are reused).

    Returns
    -------
    (MeasurementLog, dict)
        ``log`` with its observations from :func:`track_features`: landmark truth kept only
        when the tracks are those the log already held (same keyframes, ids and pixels),
        else removed; and what the front-end did: ``folder`` (its name), ``source`` (reused
        the stored tracks, or tracked and why), ``tracks``, ``views_per_keyframe``,
        ``frames_skipped`` and ``rejected`` (by reason), ``same_as_log`` (bool).
    """
    frames = read_frames(folder, log.t, log.sensors.camera)
    frames.progress = progress
    tr = track_features(
        frames, log.sensors.camera, params, odometry=log.odometry, distortion=distortion
    )
    same = (
        tr.k.size == log.obs_k.size
        and np.array_equal(tr.k, log.obs_k)
        and np.array_equal(tr.landmark_id, log.obs_id)
        and np.allclose(tr.uv, log.obs_uv, atol=1e-6)
    )
    truth_xyz = None
    if same and "landmark_xyz" in log.truth:
        truth_xyz = np.full((tr.n_tracks, 3), np.nan)
        truth_xyz[log.truth["landmark_id"]] = log.truth["landmark_xyz"]
    name = Path(folder).name  # products record the folder by name: the same bytes anywhere
    record = {
        "folder": name,
        "source": str(tr.source).replace(str(Path(folder)), name),
        "tracks": int(tr.n_tracks),
        "views_per_keyframe": float(len(tr.k) / max(log.n_keyframes, 1)),
        "frames_skipped": {k: int(v) for k, v in frames.skipped.items() if v},
        "rejected": {k: int(v) for k, v in sorted(tr.counts.items())},
        "same_as_log": bool(same),
    }
    return attach_tracks(log, tr, truth_xyz), record


def track_truth(renderer: Renderer, tracks: FeatureTracks, poses) -> tuple[np.ndarray, np.ndarray]:
    """Ground truth of each track: the surface point (n_tracks, 3) under its last (nearest)
    view, and the pixel error (M,) of every observation against that point's projection
    (0 at the reference view; NaN where the reference ray hits the sky)."""
    Rs, cs = poses
    cam = renderer.camera
    n = tracks.n_tracks
    order = np.lexsort((tracks.k, tracks.landmark_id))
    lid = tracks.landmark_id[order]
    last = np.r_[np.flatnonzero(np.diff(lid)), len(lid) - 1] if len(lid) else np.zeros(0, int)
    xyz = np.full((n, 3), np.nan)
    for k in np.unique(tracks.k[order[last]]):
        sel = order[last][tracks.k[order[last]] == k]
        xyz[tracks.landmark_id[sel]] = renderer.ground_points(Rs[k], cs[k], tracks.uv[sel])
    P = xyz[tracks.landmark_id]
    pc = np.einsum("mji,mj->mi", Rs[tracks.k], P - cs[tracks.k])
    with np.errstate(invalid="ignore", divide="ignore"):
        u = cam.fx_px * pc[:, 0] / pc[:, 2] + cam.cx_px
        v = cam.fy_px * pc[:, 1] / pc[:, 2] + cam.cy_px
        uv = np.column_stack([u, v])
    return xyz, np.linalg.norm(uv - tracks.uv, axis=1)


@dataclass
class ImageRun:
    """A simulated traverse seen through rendered images.

    Attributes
    ----------
    log : MeasurementLog
        Observations from :func:`track_features`; landmark truth from the renderer.
    ideal : MeasurementLog
        The same traverse (same GPS, odometry, tilt) with ideal simulated tracks.
    tracks : FeatureTracks
    reprojection_px : ndarray of shape (M,)
        Ground-truth pixel error of each observation (:func:`track_truth`).
    renderer : Renderer
        The renderer (its ``poses``: camera rotations and centres per keyframe).
    timings : dict
        ``render_s``, ``track_s`` (seconds, render and front-end interleaved).
    """

    log: MeasurementLog
    ideal: MeasurementLog
    tracks: FeatureTracks
    reprojection_px: np.ndarray
    renderer: Renderer
    timings: dict[str, float] = field(default_factory=dict)


class _Timed:
    """Iterator wrapper that adds the time spent inside ``next`` to ``self.s`` and reports
    ``progress(frames done, n)`` after each item."""

    def __init__(self, it, n: int = 0, progress=None):
        self.it, self.s, self.n, self.done, self.progress = iter(it), 0.0, n, 0, progress

    def __iter__(self):
        return self

    def __next__(self):
        t0 = time.perf_counter()
        try:
            item = next(self.it)
        finally:
            self.s += time.perf_counter() - t0
        self.done += 1
        if self.progress is not None:
            self.progress(self.done, self.n)
        return item


def simulate_images(
    terrain: Any,
    waypoints: Any,
    sensors: SensorSuite | None = None,
    seed: int = 0,
    scene: Scene | None = None,
    params: TrackParams | None = None,
    images_dir: str | Path | None = None,
    crs: str | None = None,
    progress: Any = None,
) -> ImageRun:
    """Simulate a traverse, render its frames, track them and build the image-based log.

    Parameters
    ----------
    terrain, waypoints, sensors, seed, crs
        As :func:`factorgraph.simulate_traverse` (``sensors`` default: the vision camera
        preset, :func:`vision_sensors`).
    scene : Scene, optional
        Illumination and surface (:data:`factorgraph.vision.SCENES`).
    params : TrackParams, optional
        Front-end settings.
    images_dir : path, optional
        Also write the frames there (PNG + ``timestamps.csv``) and the tracks with the
        digest of their inputs (``tracks.npz``: :mod:`.track_cache`), which
        :func:`track_features` reuses on the same frames, camera, parameters and odometry.
    progress : callable, optional
        ``progress(k, K)`` after each frame is rendered (``K`` keyframes).
    """
    sensors = sensors if sensors is not None else vision_sensors()
    if not isinstance(sensors, SensorSuite):
        raise bad_input("sensors", type(sensors).__name__, "a SensorSuite", "")
    ideal = simulate_traverse(terrain, waypoints, sensors, seed=seed, crs=crs)
    t0 = time.perf_counter()
    renderer, frames = render_frames(ideal, terrain, scene, seed=seed)
    setup_s = time.perf_counter() - t0
    timed = _Timed(frames, ideal.n_keyframes, progress)
    stream = write_frames(images_dir, timed, ideal.t) if images_dir is not None else timed
    t0 = time.perf_counter()
    tracks = track_features(stream, sensors.camera, params, odometry=ideal.odometry)
    total = time.perf_counter() - t0
    timings = {"render_setup_s": setup_s, "render_s": timed.s, "track_s": total - timed.s}
    if images_dir is not None:  # beside the frames: localize reuses them (track_cache.py)
        t0 = time.perf_counter()
        folder = read_frames(images_dir, ideal.t, sensors.camera)
        save_tracks(images_dir, tracks, folder, sensors.camera, ideal.odometry)
        timings["save_tracks_s"] = time.perf_counter() - t0
    xyz, err = track_truth(renderer, tracks, renderer.poses)
    run_log = attach_tracks(ideal, tracks, xyz)
    return ImageRun(run_log, ideal, tracks, err, renderer, timings)
