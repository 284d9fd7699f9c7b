"""Camera images to landmarks: a ray-cast glacier renderer (:mod:`.render`, :mod:`.albedo`),
frames on disk (:mod:`.camera_frames`), the OpenCV feature front-end (:mod:`.tracking`) and
the chain that feeds its tracks to the factor graph (:mod:`.chain`). See docs/vision.md."""

from .albedo import AlbedoParams, GlacierAlbedo
from .camera_frames import ImageFolder, read_frames, write_frames
from .chain import (
    ImageRun,
    attach_tracks,
    simulate_images,
    track_log_frames,
    track_truth,
    vision_sensors,
)
from .render import SCENES, VISION_CAMERA, Renderer, Scene, camera_poses, render_frames
from .tracking import FeatureTracks, TrackParams, predict_motion, track_features

__all__ = [
    "SCENES",
    "VISION_CAMERA",
    "AlbedoParams",
    "FeatureTracks",
    "GlacierAlbedo",
    "ImageFolder",
    "ImageRun",
    "Renderer",
    "Scene",
    "TrackParams",
    "attach_tracks",
    "camera_poses",
    "predict_motion",
    "read_frames",
    "render_frames",
    "simulate_images",
    "track_features",
    "track_log_frames",
    "track_truth",
    "vision_sensors",
    "write_frames",
]
