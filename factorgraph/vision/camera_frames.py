"""Frames on disk: a folder of PNG files plus a timestamps table (format-neutral: any
camera's images, renamed or not, enter through the table).

Layout (the log folder's ``images/``)
-------------------------------------
``timestamps.csv``
    ``t_s, file`` (s, name relative to the folder); optional ``k`` (keyframe index).
``*.png``
    8-bit grayscale (colour is converted; 16-bit frames are scaled by their data's bit
    depth, e.g. a 12-bit camera's by 1/16), the camera model's width x height.

:func:`read_frames` matches each row to the log's keyframes by time (nearest keyframe within
``tolerance_s``). Missing, unreadable and wrong-size files, rows that match no keyframe and
keyframes without a frame are counted by reason (``ImageFolder.skipped``), never fatal; the
tracker ends its tracks at such a gap.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np

from terrain.atomic import atomic_path, ensure_writable_dir
from terrain.errors import bad_input

from ..sensors import CameraModel

__all__ = ["TIMESTAMPS", "ImageFolder", "read_frames", "write_frames"]

TIMESTAMPS = "timestamps.csv"


def write_frames(
    folder: str | Path, frames: Iterable[tuple[int, np.ndarray]], t: np.ndarray
) -> Iterator[tuple[int, np.ndarray]]:
    """Write each ``(k, frame)`` of ``frames`` as ``frame_{k:06d}.png`` (atomically) while
    passing it on (a generator: render, store and track in one pass); the timestamps table
    (``k, t_s, file``; ``t`` (K,) keyframe times, s) is written when the stream ends."""
    import cv2
    import pandas as pd

    out = ensure_writable_dir(folder)
    rows = []
    for k, img in frames:
        name = f"frame_{k:06d}.png"
        ok, png = cv2.imencode(".png", img)
        if not ok:
            raise bad_input("frame", k, "an 8-bit image OpenCV can encode", "")
        with atomic_path(out / name) as tmp:
            tmp.write_bytes(png.tobytes())
        rows.append((k, float(t[k]), name))
        yield k, img
    with atomic_path(out / TIMESTAMPS) as tmp:
        pd.DataFrame(rows, columns=["k", "t_s", "file"]).to_csv(tmp, index=False)


class ImageFolder:
    """Iterable of ``(k, frame or None)`` over a log's keyframes, read lazily from disk.

    Attributes
    ----------
    files : dict
        Keyframe index -> path of its frame.
    folder : Path or None
        The folder (its ``tracks.npz``, when stored, may be reused: :mod:`.track_cache`).
    skipped : Counter
        ``no_matching_keyframe``, ``duplicate_keyframe``, ``missing_file``, ``unreadable``,
        ``wrong_size``, ``keyframe_without_frame`` (the last three counted while iterating).
    """

    def __init__(
        self,
        files: dict[int, Path],
        n_keyframes: int,
        camera: CameraModel | None,
        skipped: Counter,
        folder: Path | None = None,
    ):
        self.files, self.n_keyframes = files, n_keyframes
        self.camera, self.skipped, self.folder = camera, skipped, folder
        self.bits = 8  # the data bits of 16-bit frames seen so far (10, 12, 14 or 16)
        self.progress = None  # optional progress(k + 1, n_keyframes) after each keyframe

    def __len__(self) -> int:
        return self.n_keyframes

    def _to_8bit(self, img: np.ndarray) -> np.ndarray | None:
        """A 16-bit frame as 8 bits by its data's bit depth: a 12-bit camera's frames
        (0-4095 in a 16-bit PNG) are divided by 16, not 256 (OpenCV's own conversion, which
        left them black). The depth is the smallest of 10, 12, 14, 16 bits holding every
        frame so far: it only grows, so a dark frame is not brightened against its
        neighbours. Not 8- or 16-bit unsigned: unreadable (None)."""
        if img.dtype != np.uint16:
            return None
        top = int(img.max())
        self.bits = max(self.bits, next(b for b in (10, 12, 14, 16) if top < 1 << b))
        return (img >> (self.bits - 8)).astype(np.uint8)

    def __iter__(self) -> Iterator[tuple[int, np.ndarray | None]]:
        for k, img in self._frames():
            yield k, img
            if self.progress is not None:
                self.progress(k + 1, self.n_keyframes)

    def _frames(self) -> Iterator[tuple[int, np.ndarray | None]]:
        import cv2

        for k in range(self.n_keyframes):
            path = self.files.get(k)
            if path is None:
                self.skipped["keyframe_without_frame"] += 1
                yield k, None
                continue
            if not path.is_file():
                self.skipped["missing_file"] += 1
                yield k, None
                continue
            img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE | cv2.IMREAD_ANYDEPTH)
            if img is not None and img.dtype != np.uint8:
                img = self._to_8bit(img)
            if img is None:
                self.skipped["unreadable"] += 1
                yield k, None
                continue
            cam = self.camera
            if cam is not None and img.shape != (cam.height_px, cam.width_px):
                self.skipped["wrong_size"] += 1
                yield k, None
                continue
            yield k, img


def read_frames(
    folder: str | Path,
    keyframe_t: np.ndarray,
    camera: CameraModel | None = None,
    tolerance_s: float | None = None,
) -> ImageFolder:
    """Frames of ``folder`` matched to keyframe times ``keyframe_t`` (K,) (s).

    Parameters
    ----------
    folder : path
        Holds ``timestamps.csv`` (``t_s, file``) and the images.
    keyframe_t : ndarray of shape (K,)
        The log's keyframe times (s).
    camera : CameraModel, optional
        Frames of another size are skipped (counted).
    tolerance_s : float, optional
        Largest |frame time - keyframe time|; default a quarter of the smallest keyframe
        interval. Of several frames within it (a video-rate camera), the nearest in time
        is the keyframe's view; the others count as ``duplicate_keyframe``.
    """
    import pandas as pd

    folder = Path(folder)
    table = folder / TIMESTAMPS
    if not table.is_file():
        raise bad_input(
            "images",
            str(folder),
            f"a folder with {TIMESTAMPS} (t_s, file)",
            "write the frame times beside the images (factorgraph/vision/camera_frames.py)",
        )
    try:
        df = pd.read_csv(table)
    except Exception as exc:  # pandas parser errors
        raise bad_input(TIMESTAMPS, str(exc)[:120], "a CSV table t_s, file", "repair it") from exc
    missing = [c for c in ("t_s", "file") if c not in df.columns]
    if missing:
        raise bad_input(TIMESTAMPS, sorted(df.columns), f"columns {missing} too", "")
    t = np.asarray(keyframe_t, float)
    ts = pd.to_numeric(df["t_s"], errors="coerce").to_numpy(float)
    tol = tolerance_s if tolerance_s is not None else 0.25 * float(np.min(np.diff(t)))
    skipped: Counter = Counter()
    skipped["bad_timestamp"] += int((~np.isfinite(ts)).sum())
    files: dict[int, Path] = {}
    j = np.clip(np.searchsorted(t, ts), 1, len(t) - 1)
    near = np.where(np.abs(ts - t[j - 1]) <= np.abs(ts - t[j]), j - 1, j)
    dt = np.abs(ts - t[near])
    names = df["file"].astype(str).to_numpy()
    # the frame nearest in time to its keyframe is its view (a 10 Hz camera gives several
    # within the tolerance; the others are counted as duplicates); ties: the first row
    for i in sorted(np.flatnonzero(np.isfinite(ts)), key=lambda i: (dt[i], i)):
        k = int(near[i])
        if dt[i] > tol:
            skipped["no_matching_keyframe"] += 1
        elif k in files:
            skipped["duplicate_keyframe"] += 1
        else:
            files[k] = folder / names[i]
    if not files and np.isfinite(ts).any():  # e.g. frame times in UTC, keyframes on the rover clock
        raise bad_input(
            f"{TIMESTAMPS} t_s",
            f"{int(np.isfinite(ts).sum())} frames at {np.nanmin(ts):.3f}-{np.nanmax(ts):.3f} s",
            f"times within {tol:.3f} s of the keyframes ({t[0]:.3f}-{t[-1]:.3f} s, the log's "
            "clock)",
            "write t_s on the clock of the keyframes (a field folder: odometry.csv's rover clock), "
            "e.g. shift UTC times by survey.json clock_offset_s",
        )
    return ImageFolder(files, len(t), camera, skipped, folder)
