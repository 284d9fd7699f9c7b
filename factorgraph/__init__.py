"""Localization: sensors, traverse simulation, the GTSAM iSAM2 factor graph, landmark
selection, ground control and the rover's field formats.

``factorgraph`` depends on :mod:`terrain` only (docs: the package layout ``toolkit ->
{survey, factorgraph} -> terrain``). The names below are the public contract; GTSAM is
imported when a function needs it, not here.

* Sensors and logs: :class:`SensorSuite` (:class:`GPSModel`, :class:`OdometryModel`,
  :class:`CameraModel`, :class:`TiltModel`), :class:`MeasurementLog` with its strict folder
  format :func:`read_log` / :func:`write_log` (``glacimap-log/1``), and a rover's own files
  :func:`read_field_log` / :func:`write_field_log` (NMEA / GPX / RTKLIB GPS, odometry CSV,
  OpenCV camera YAML; docs/field-format.md) with their :class:`IngestReport`.
* Simulation: :func:`simulate_traverse`, :func:`simulate_control`.
* Estimation: :func:`localize` (:class:`LocalizeParams`) -> :class:`LocalizationResult`;
  ground control :func:`read_control` (:class:`ControlPoints`); :func:`select_landmarks` ->
  :class:`LandmarkSelection` (the terrain samples).
* Evaluation: :func:`horizontal_rmse`, :func:`nees`, :func:`bias_floor`,
  :func:`horizontal_floor`, :func:`frame_floor`; baselines :func:`gps_only`,
  :func:`odometry_only`, :func:`particle_filter`.
* Camera images: :func:`render` (:func:`factorgraph.vision.render_frames`) and
  :func:`track_features` (images -> the ``k, landmark_id, u_px, v_px`` observations).
"""

# sensors and logs
from .sensors import CameraModel, GPSModel, OdometryModel, SensorSuite, TiltModel  # noqa: I001
from .log import MeasurementLog, read_log, write_log
from .field import IngestReport, read_field_log, write_field_log

# simulation
from .simulate import simulate_traverse
from .control_sim import simulate_control

# estimation
from .localize import LocalizeParams, localize
from .result import LocalizationResult
from .control import ControlPoints, check_in_area, check_independent
from .control_io import read_control
from .select import LandmarkSelection, select_landmarks

# evaluation
from .evaluate import bias_floor, frame_floor, horizontal_floor, horizontal_rmse, nees
from .baselines import BaselineTrack, gps_only, odometry_only, particle_filter

# camera images (render, track, feed the graph; docs/vision.md)
from .vision import render_frames as render
from .vision import track_features

__all__ = [
    # sensors and logs
    "CameraModel",
    "GPSModel",
    "IngestReport",
    "MeasurementLog",
    "OdometryModel",
    "SensorSuite",
    "TiltModel",
    "read_field_log",
    "read_log",
    "write_field_log",
    "write_log",
    # simulation
    "simulate_control",
    "simulate_traverse",
    # estimation
    "ControlPoints",
    "LandmarkSelection",
    "LocalizationResult",
    "LocalizeParams",
    "check_in_area",
    "check_independent",
    "localize",
    "read_control",
    "select_landmarks",
    # evaluation
    "BaselineTrack",
    "bias_floor",
    "frame_floor",
    "gps_only",
    "horizontal_floor",
    "horizontal_rmse",
    "nees",
    "odometry_only",
    "particle_filter",
    # camera images
    "render",
    "track_features",
]
