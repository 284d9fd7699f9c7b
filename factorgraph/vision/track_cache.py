"""Tracks stored beside the frames they came from, reused only for the same inputs.

``glacimap simulate --camera images`` renders and tracks every keyframe; ``glacimap
localize`` on that log ran the same front-end on the same frames again (the largest cost
of the CLI image chain, docs/vision.md). :func:`save_tracks` writes the front-end's output
into the images folder (``tracks.npz``) with a SHA-256 of everything that determines it:

* the frames as the localizer reads them: for every keyframe, the file it is matched to
  (:func:`factorgraph.vision.read_frames`) and that file's bytes (PNG is lossless: same
  bytes, same pixels);
* the camera model, the front-end parameters (:class:`TrackParams`) and the odometry that
  guides the matching, as the log stores it (9 significant digits,
  :func:`factorgraph.log.write_log`);
* the front-end itself: the source of ``tracking.py`` and the OpenCV version.

:func:`load_tracks` recomputes the digest from the folder and returns the stored tracks only
when it is the same; otherwise (or when the file is absent or unreadable) the caller tracks
the frames again, and the reason is returned. Not covered: a change of the front-end's
behaviour outside ``tracking.py`` and OpenCV (e.g. numpy).

The odometry enters at 9 significant digits because ``simulate`` tracks with the values in
memory and ``localize`` reads them back from the CSV: both give the same digits, while the
values differ by < 5e-10 relative (a guided-matching window moves by < 1e-6 px).
"""

from __future__ import annotations

import hashlib
import json
from collections import Counter
from dataclasses import asdict
from pathlib import Path

import numpy as np

from terrain.atomic import atomic_path

from ..sensors import CameraModel
from .camera_frames import ImageFolder
from .tracking import FeatureTracks, TrackParams

__all__ = ["TRACKS_FILE", "inputs_digest", "load_tracks", "save_tracks"]

TRACKS_FILE = "tracks.npz"
_FORMAT = "glacimap-tracks/1"
#: Frame skips an :class:`ImageFolder` counts only while its frames are read. Reused tracks
#: read no frame, so they carry the counts of the run that stored them (the digest covers
#: every file and its bytes, so those counts are this folder's).
_READ_SKIPS = ("missing_file", "unreadable", "wrong_size", "keyframe_without_frame")


#: The modules whose source decides the tracks (their bytes are part of the digest).
_FRONTEND_SOURCES = ("tracking.py", "frame_geometry.py", "camera_frames.py")


def _frontend_version() -> str:
    import cv2

    here = Path(__file__).parent  # the front-end, its geometry and how frames are read
    src = b"".join((here / f).read_bytes() for f in _FRONTEND_SOURCES)
    return hashlib.sha256(src).hexdigest() + " opencv " + cv2.__version__


def inputs_digest(
    frames: ImageFolder,
    camera: CameraModel,
    params: TrackParams,
    odometry: np.ndarray | None,
    distortion: np.ndarray | None = None,
) -> str:
    """SHA-256 (hex) of the front-end's inputs: ``frames`` (keyframe -> file name and bytes;
    a missing file hashes as missing), ``camera`` (its numbers at 12 significant digits),
    ``params``, ``odometry`` (K-1, 6) at 9 significant digits (or none), the lens
    ``distortion`` coefficients (when given) and the front-end's version."""
    h = hashlib.sha256()
    h.update(_FORMAT.encode())
    h.update(_frontend_version().encode())
    # numbers as floats at 12 digits: a camera read back from camera.yaml (640.0) is the
    # camera the frames were tracked with (640)
    cam = {
        k: (f"{float(v):.12g}" if isinstance(v, int | float) else v)
        for k, v in asdict(camera).items()
    }
    h.update(json.dumps(cam, sort_keys=True).encode())
    h.update(json.dumps(asdict(params), sort_keys=True).encode())
    if odometry is None:
        h.update(b"no odometry")
    else:
        odo = np.asarray(odometry, float)
        h.update(repr(odo.shape).encode())
        h.update(" ".join(f"{v:.9g}" for v in odo.ravel()).encode())
    if distortion is not None:  # the lens model the pixels were undistorted with
        h.update(("distortion " + " ".join(f"{v:.12g}" for v in np.ravel(distortion))).encode())
    h.update(f"keyframes {frames.n_keyframes}".encode())
    for k in sorted(frames.files):
        path = frames.files[k]
        h.update(f"\nk {k} {path.name} ".encode())
        h.update(hashlib.sha256(path.read_bytes()).digest() if path.is_file() else b"missing")
    return h.hexdigest()


def save_tracks(
    folder: str | Path,
    tracks: FeatureTracks,
    frames: ImageFolder,
    camera: CameraModel,
    odometry: np.ndarray | None,
    distortion: np.ndarray | None = None,
) -> str:
    """Write ``tracks`` (made by ``tracks.params`` from ``frames`` with ``camera``,
    ``odometry`` and ``distortion``) into ``folder/tracks.npz`` (atomically) with the inputs'
    digest; returns the digest."""
    digest = inputs_digest(frames, camera, tracks.params, odometry, distortion)
    meta = {
        "format": _FORMAT,
        "digest": digest,
        "params": asdict(tracks.params),
        "counts": dict(tracks.counts),
        "per_frame": tracks.per_frame,
        "frames_skipped": {r: int(frames.skipped[r]) for r in _READ_SKIPS if frames.skipped[r]},
    }
    with atomic_path(Path(folder) / TRACKS_FILE) as tmp:
        with open(tmp, "wb") as fh:  # np.savez would append .npz to the temporary name
            np.savez_compressed(
                fh,
                k=tracks.k,
                landmark_id=tracks.landmark_id,
                uv=tracks.uv,
                meta=np.array(json.dumps(meta, default=int)),
            )
    return digest


def load_tracks(
    frames: ImageFolder,
    camera: CameraModel,
    params: TrackParams,
    odometry: np.ndarray | None,
    distortion: np.ndarray | None = None,
) -> tuple[FeatureTracks | None, str]:
    """The tracks stored in ``frames``'s folder when they were made from the same inputs
    (:func:`inputs_digest`), else ``None``; and why (``reused``, ``no stored tracks``,
    ``unreadable``, ``inputs differ``)."""
    folder = getattr(frames, "folder", None)
    path = None if folder is None else Path(folder) / TRACKS_FILE
    if path is None or not path.is_file():
        return None, "no stored tracks"
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            k, lid, uv = z["k"], z["landmark_id"], z["uv"]
    except Exception:  # a truncated or foreign file: track again
        return None, "unreadable"
    if meta.get("format") != _FORMAT or meta.get("digest") != inputs_digest(
        frames, camera, params, odometry, distortion
    ):
        return None, "inputs differ"
    for reason, n in meta.get("frames_skipped", {}).items():  # as if read (see _READ_SKIPS)
        frames.skipped[reason] = int(n)
    source = f"reused {path} (inputs sha256 {meta['digest'][:12]})"
    counts = Counter(meta["counts"])
    ids, per_frame = lid.astype(int), meta["per_frame"]
    tracks = FeatureTracks(k.astype(int), ids, uv.astype(float), counts, per_frame, params, source)
    return tracks, "reused"
