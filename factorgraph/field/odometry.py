"""Rover-clock tables of a field folder: odometry (the keyframe backbone), tilt, feature tracks.

``odometry.csv``
    ``t_s, rx, ry, rz, tx, ty, tz``: one row per keyframe, rover clock (s, strictly
    increasing); the pose of this keyframe in the body frame of the previous row (rotation
    vector rad, translation m; the first row's increment is ignored, write zeros).
``tilt.csv`` (optional)
    ``t_s, up_x, up_y, up_z``: gravity "up" in the body frame (unit vector), matched to the
    keyframe nearest in time within the sync tolerance.
``tracks.csv``
    ``k`` or ``t_s``, ``landmark_id, u_px, v_px``: a tracked feature in a keyframe (pixels of
    the image as recorded; undistorted with the camera's distortion coefficients on ingest).
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np

from terrain.errors import bad_input

from .table import csv_dialect

__all__ = ["ODOMETRY_COLUMNS", "nearest_keyframe", "read_odometry", "read_tilt", "read_tracks"]

ODOMETRY_COLUMNS = ("t_s", "rx", "ry", "rz", "tx", "ty", "tz")


def _table(path: Path, required: tuple[str, ...], alternatives: tuple[str, ...] = ()):
    import pandas as pd

    try:
        df = pd.read_csv(path, float_precision="round_trip", **csv_dialect(path))
    except (ValueError, OSError) as exc:  # pandas parser errors are ValueErrors
        raise bad_input(path.name, str(exc)[:120], "a readable CSV table", "repair it") from exc
    df.columns = [str(c).strip() for c in df.columns]
    missing = [c for c in required if c not in df.columns]
    if alternatives and not any(c in df.columns for c in alternatives):
        missing.append(" or ".join(alternatives))
    if missing:
        raise bad_input(
            path.name, sorted(df.columns), f"columns {missing} too", "see docs/field-format.md"
        )
    return df


def read_odometry(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Keyframe times ``t (K,)`` (rover clock, s) and increments ``(K-1, 6)`` (rad, m).

    The odometry is the chain every keyframe hangs on: a missing, non-finite or out-of-order
    row cannot be skipped without breaking it, so each is an InputError naming the row.
    """
    path = Path(path)
    df = _table(path, ODOMETRY_COLUMNS)
    a = df[list(ODOMETRY_COLUMNS)].to_numpy(float)
    if len(a) < 2:
        raise bad_input(path.name, f"{len(a)} rows", "at least 2 keyframes", "log a traverse")
    bad = ~np.isfinite(a[1:]).all(axis=1)
    if bad.any() or not np.isfinite(a[0, 0]):
        i = int(np.argmax(np.r_[not np.isfinite(a[0, 0]), bad]))
        raise bad_input(
            f"{path.name} row {i + 2}", a[i].tolist(), "finite numbers", "repair the odometry"
        )
    dt = np.diff(a[:, 0])
    if (dt <= 0).any():
        i = int(np.argmax(dt <= 0))
        raise bad_input(
            f"{path.name} t_s",
            f"row {i + 3}: {a[i + 1, 0]:g} after {a[i, 0]:g}",
            "strictly increasing rover-clock times",
            "sort the odometry by time and merge repeated keyframes",
        )
    return a[:, 0], a[1:, 1:]


def nearest_keyframe(t_kf: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index of the keyframe nearest to each time ``t`` and the signed gap ``t - t_kf[k]``."""
    i = np.clip(np.searchsorted(t_kf, t), 1, len(t_kf) - 1)
    k = np.where(np.abs(t - t_kf[i - 1]) <= np.abs(t - t_kf[i]), i - 1, i)
    return k, t - t_kf[k]


def read_tilt(path: str | Path, t_kf: np.ndarray, tol_s: float) -> tuple[np.ndarray | None, str]:
    """Gravity direction per keyframe ``(K, 3)``, or None with the reason it is not used
    (a keyframe without a reading within ``tol_s``: the factor graph needs it at all or
    none; rows with a non-finite value do not count as readings)."""
    path = Path(path)
    df = _table(path, ("t_s", "up_x", "up_y", "up_z"))
    a = df[["t_s", "up_x", "up_y", "up_z"]].to_numpy(float)
    a = a[np.isfinite(a).all(axis=1)]
    if not len(a):
        return None, f"not used: {path.name} has no finite reading"
    a = a[np.argsort(a[:, 0], kind="stable")]
    if len(a) > 1:
        i, gap = nearest_keyframe(a[:, 0], t_kf)
    else:
        i, gap = np.zeros(len(t_kf), int), t_kf - a[0, 0]
    missing = int((np.abs(gap) > tol_s).sum())
    if missing:
        return None, f"not used: {missing} keyframes without a reading within {tol_s:g} s"
    return a[i, 1:], "used"  # MeasurementLog checks and normalises


def read_tracks(
    path: str | Path, t_kf: np.ndarray, tol_s: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, Counter]:
    """Feature observations ``(k, landmark_id, uv (M, 2))`` and the rows skipped, by reason:
    ``nan_observation``, ``keyframe_out_of_range`` (``k``) or ``off_keyframe`` (a ``t_s``
    farther than ``tol_s`` from every keyframe)."""
    path = Path(path)
    df = _table(path, ("landmark_id", "u_px", "v_px"), ("k", "t_s"))
    skipped: Counter = Counter()
    uv = df[["u_px", "v_px"]].to_numpy(float)
    lid = df["landmark_id"].to_numpy(float)
    ok = np.isfinite(uv).all(axis=1) & np.isfinite(lid)
    skipped["nan_observation"] += int((~ok).sum())
    if "k" in df.columns:
        k = df["k"].to_numpy(float)
        inside = np.isfinite(k) & (k >= 0) & (k < len(t_kf))
        skipped["keyframe_out_of_range"] += int((ok & ~inside).sum())
        ok &= inside
        k = np.where(ok, k, 0).astype(int)
    else:
        ts = df["t_s"].to_numpy(float)
        k, gap = nearest_keyframe(t_kf, np.where(np.isfinite(ts), ts, np.inf))
        near = np.abs(gap) <= tol_s
        skipped["off_keyframe"] += int((ok & ~near).sum())
        ok &= near
    order = np.argsort(k[ok], kind="stable")
    skipped = Counter({r: n for r, n in skipped.items() if n})
    return k[ok][order], lid[ok].astype(int)[order], uv[ok][order], skipped
