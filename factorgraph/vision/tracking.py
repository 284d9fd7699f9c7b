"""Feature tracking front-end: images -> the ``k, landmark_id, u_px, v_px`` observations the
localizer reads (:mod:`factorgraph.log`).

Per frame: optional CLAHE, detection (SIFT, ORB, AKAZE or GFTT corners), bucketing into a
grid of cells, association with the previous frame (descriptors: ratio test plus a mutual
forward-backward check; KLT: pyramidal Lucas-Kanade forward, then backward, kept when the
round trip closes within ``fb_max_px``), geometric verification by RANSAC on the essential
matrix (the camera's intrinsics), and track management (a track ends after
``max_track_length`` views or when its feature is lost; empty cells are re-detected). Every
rejected association and every dropped track is counted by reason.

Tracks are contiguous (a track never skips a keyframe), which is what the localizer's
pending-track bookkeeping expects.
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Iterable
from dataclasses import asdict, dataclass, field
from typing import Any, Literal

import numpy as np

from terrain.errors import bad_input

from ..sensors import CameraModel
from .frame_geometry import detection_mask, predict_motion, undistorter
from .matching import match_descriptors

__all__ = ["FeatureTracks", "TrackParams", "track_features"]

DETECTORS = ("sift", "orb", "akaze", "klt")


@dataclass(frozen=True)
class TrackParams:
    """Front-end settings (pixels unless stated)."""

    detector: Literal["sift", "orb", "akaze", "klt"] = "sift"
    # contrast-limited histogram equalisation before detection. Off by default for SIFT:
    # measured (15 keyframes at 2 m, sunny snow) 24 vs 29 views per keyframe, median error
    # 0.65 vs 0.56 px with / without (benchmarks/vision.py has every scene and detector)
    clahe: bool = False
    clahe_clip: float = 3.0
    clahe_tiles: int = 8  # tiles per image side
    # at most max_features / (grid cells) per cell. 4000, not 2000: the detection region
    # (ground within max_ground_range_m) covers ~60 % of the cells, so 2000 capped SIFT at
    # ~1,100 features; measured (20 keyframes at 2 m heading E / N / S / W, sunny snow):
    # views per keyframe in >= 3-view tracks 35 / 17 / 28 / 37 -> 52 / 40 / 52 / 47, median
    # error 0.33-0.38 -> 0.34-0.40 px, > 4 px 0.7-2.8 % -> 0.6-2.0 % (docs/vision.md)
    max_features: int = 4000
    sift_contrast: float = 0.01  # SIFT contrastThreshold (OpenCV default 0.04: too few on snow)
    grid: tuple[int, int] = (8, 6)  # cells across, down (bucketing, re-detection)
    ratio: float = 0.85  # Lowe's ratio test, among the candidates inside the search window
    ransac_px: float = 1.0  # essential-matrix RANSAC threshold
    fb_max_px: float = 0.5  # KLT forward-backward closure
    max_track_length: int = 40  # views; a longer track is ended (and a new one starts)
    min_track_length: int = 3  # shorter tracks are not written (the localizer needs 3)
    # detect only where the flat ground under the rover is nearer than this (m): in the far
    # field, features slide along foreshortened sastrugi (measured: > 20 m, median 2.3 px
    # drift and 37 % of views off by > 4 px; 3-10 m: 0.4 px). None: everywhere.
    max_ground_range_m: float | None = 18.0
    # guided matching (when odometry is given): a feature's position in the next frame is
    # predicted from the odometry step and a flat ground under the rover; candidates farther
    # than search_px + search_frac * (predicted motion) from it are not considered
    search_px: float = 24.0
    search_frac: float = 0.15

    def __post_init__(self) -> None:
        if self.detector not in DETECTORS:
            raise bad_input("params.detector", self.detector, f"one of {DETECTORS}", "")
        for name in ("clahe_clip", "ransac_px", "fb_max_px"):
            if not getattr(self, name) > 0:
                raise bad_input(f"params.{name}", getattr(self, name), "a value > 0", "")
        if not 0 < self.ratio <= 1:
            raise bad_input("params.ratio", self.ratio, "a value in (0, 1]", "")
        if int(self.max_features) < 8 or int(self.min_track_length) < 2:
            raise bad_input("params", asdict(self), "max_features >= 8, min_track_length >= 2", "")
        if int(self.max_track_length) < int(self.min_track_length):
            raise bad_input("params.max_track_length", self.max_track_length, ">= min", "")


@dataclass
class FeatureTracks:
    """Tracks of one image sequence.

    Attributes
    ----------
    k, landmark_id : ndarray of shape (M,), int
        Keyframe and track id of each observation (tracks of >= ``min_track_length`` views).
    uv : ndarray of shape (M, 2)
        Pixel coordinates (u right, v down).
    counts : Counter
        Rejections and drops by reason (``ratio_test``, ``not_mutual``, ``fb_check``,
        ``ransac_outlier``, ``track_too_short``, ``max_track_length``, ``frame_missing``,
        ``frame_wrong_size``, ``frame_without_features``, ...).
    per_frame : list of dict
        Per frame: ``k, features, matches, inliers, tracked, new, ms``.
    params : TrackParams
    source : str
        ``tracked`` (with why stored tracks were not used, when a folder was given) or
        ``reused <folder>/tracks.npz (inputs sha256 ...)`` (:mod:`.track_cache`).
    """

    k: np.ndarray
    landmark_id: np.ndarray
    uv: np.ndarray
    counts: Counter
    per_frame: list[dict[str, Any]]
    params: TrackParams = field(default_factory=TrackParams)
    source: str = "tracked"

    def table(self) -> dict[str, np.ndarray]:
        """The observations table (``k, landmark_id, u_px, v_px``)."""
        return {
            "k": self.k,
            "landmark_id": self.landmark_id,
            "u_px": self.uv[:, 0],
            "v_px": self.uv[:, 1],
        }

    @property
    def n_tracks(self) -> int:
        return int(np.unique(self.landmark_id).size)


def _detector(params: TrackParams):
    import cv2

    n = int(params.max_features) * 2  # bucketing keeps the best per cell afterwards
    if params.detector == "sift":
        return cv2.SIFT_create(nfeatures=n, contrastThreshold=params.sift_contrast)
    if params.detector == "orb":
        return cv2.ORB_create(nfeatures=n, fastThreshold=5)
    if params.detector == "akaze":
        make = getattr(cv2, "AKAZE_create", None) or cv2.xfeatures2d.AKAZE_create  # OpenCV 5
        return make(threshold=1e-4)
    return None


def _bucket(pts: np.ndarray, score: np.ndarray, shape, params: TrackParams) -> np.ndarray:
    """Indices of the best points, at most ``max_features / cells`` per grid cell."""
    gx, gy = params.grid
    h, w = shape
    cell = np.clip((pts[:, 0] * gx / w).astype(int), 0, gx - 1)
    cell += gx * np.clip((pts[:, 1] * gy / h).astype(int), 0, gy - 1)
    per = max(1, int(params.max_features) // (gx * gy))
    order = np.lexsort((-score, cell))
    rank = np.arange(order.size) - np.searchsorted(cell[order], cell[order])
    keep = order[rank < per]
    return np.sort(keep)


class _Frame:
    __slots__ = ("pts", "desc", "ids", "img")

    def __init__(self, pts, desc, ids, img):
        self.pts, self.desc, self.ids, self.img = pts, desc, ids, img


def _detect(img, det, params, mask=None):
    import cv2

    if det is None:  # GFTT corners for KLT
        c = cv2.goodFeaturesToTrack(img, int(params.max_features), 0.01, 7, mask=mask, blockSize=7)
        pts = np.zeros((0, 2), np.float32) if c is None else c.reshape(-1, 2)
        return pts, np.arange(len(pts), 0, -1, dtype=float), None
    r0 = 0
    if mask is not None:  # detect in the rows the mask opens only (SIFT cost ~ pixels)
        rows = np.flatnonzero(mask.any(1))
        if rows.size == 0:
            return np.zeros((0, 2), np.float32), np.zeros(0), None
        r0 = max(0, int(rows[0]) - 8)
        img, mask = img[r0:], mask[r0:]
    kps, desc = det.detectAndCompute(img, mask)
    if not kps or desc is None:
        return np.zeros((0, 2), np.float32), np.zeros(0), None
    pts = np.array([kp.pt for kp in kps], np.float32) + np.float32([0.0, r0])
    return pts, np.array([kp.response for kp in kps]), desc


def _verify(p0, p1, Kmat, params, counts) -> np.ndarray:
    """RANSAC on the essential matrix; boolean inlier mask."""
    import cv2

    if len(p0) < 8:
        counts["too_few_matches_for_ransac"] += len(p0)
        return np.zeros(len(p0), bool)
    E, mask = cv2.findEssentialMat(
        p0.astype(np.float64),
        p1.astype(np.float64),
        Kmat,
        method=cv2.RANSAC,
        prob=0.999,
        threshold=params.ransac_px,
    )
    if E is None or mask is None:
        counts["ransac_failed"] += len(p0)
        return np.zeros(len(p0), bool)
    ok = mask.ravel().astype(bool)
    counts["ransac_outlier"] += int((~ok).sum())
    return ok


def _iter_frames(images) -> Iterable[tuple[int, Any]]:
    for i, item in enumerate(images):
        if isinstance(item, tuple) and len(item) == 2:
            yield int(item[0]), item[1]
        else:
            yield i, item


def track_features(
    images: Iterable,
    camera: CameraModel,
    params: TrackParams | None = None,
    odometry: np.ndarray | None = None,
    reuse: bool = True,
    distortion: np.ndarray | None = None,
) -> FeatureTracks:
    """Track features through an image sequence.

    Parameters
    ----------
    images : iterable
        Grayscale frames (H, W) uint8, or ``(k, frame)`` pairs (keyframe index, frame or
        ``None`` for a missing frame), e.g. :func:`factorgraph.vision.read_frames` or the
        iterator of :func:`factorgraph.vision.render_frames`. Colour frames are converted.
    camera : CameraModel
        Intrinsics (pixels); frames of another size are skipped and counted.
    params : TrackParams, optional
    odometry : ndarray of shape (K-1, 6), optional
        The log's odometry (``MeasurementLog.odometry``): with it, matching is guided by the
        predicted motion of the ground (:func:`predict_motion`); without it, every feature
        competes with every other.
    reuse : bool
        When ``images`` is a folder (:func:`factorgraph.vision.read_frames`) holding tracks
        stored by :func:`factorgraph.vision.track_cache.save_tracks` from the same frame
        bytes, camera, parameters and odometry, return those (``source`` says so) instead
        of tracking again; any other folder is tracked.
    distortion : ndarray, optional
        The lens's OpenCV distortion coefficients (k1 k2 p1 p2 [k3 ...]) for ``camera``'s
        intrinsics: features are detected in the recorded frames and undistorted at once
        (``cv2.undistortPoints``), so guided matching, the essential-matrix RANSAC and the
        returned pixels are the ideal pinhole camera's. Descriptor detectors only (KLT
        follows pixels in the recorded image: undistort such frames first).

    Returns
    -------
    FeatureTracks
        Observations (``.table()``: ``k, landmark_id, u_px, v_px``), counts by reason and
        per-frame statistics.
    """
    import cv2

    params = params or TrackParams()
    if not isinstance(camera, CameraModel):
        raise bad_input("camera", type(camera).__name__, "a CameraModel", "")
    undistort = undistorter(camera, distortion, params.detector)
    source = "tracked"
    if reuse and hasattr(images, "folder") and hasattr(images, "files"):  # an ImageFolder
        from .track_cache import load_tracks

        stored, why = load_tracks(images, camera, params, odometry, distortion)
        if stored is not None:
            return stored
        source = f"tracked (stored tracks: {why})"
    det = _detector(params)
    binary = params.detector == "orb"
    clahe = cv2.createCLAHE(params.clahe_clip, (params.clahe_tiles, params.clahe_tiles))
    Kmat = np.array([[camera.fx_px, 0, camera.cx_px], [0, camera.fy_px, camera.cy_px], [0, 0, 1.0]])
    shape = (camera.height_px, camera.width_px)
    region = detection_mask(camera, params.max_ground_range_m)
    counts: Counter = Counter()
    per_frame: list[dict[str, Any]] = []
    obs_k, obs_id, obs_uv = [], [], []
    length: dict[int, int] = {}
    next_id = 0
    prev: _Frame | None = None
    last_k = prev_k = None
    for k, img in _iter_frames(images):
        t0 = time.perf_counter()
        if last_k is not None and k <= last_k:
            raise bad_input("images", f"keyframe {k} after {last_k}", "increasing k", "sort")
        if last_k is not None and k > last_k + 1:
            counts["frame_missing"] += k - last_k - 1
            prev = None  # a gap ends every track (tracks stay contiguous)
        last_k = k
        if img is None:
            counts["frame_missing"] += 1
            prev = None
            continue
        img = np.asarray(img)
        if img.ndim == 3:
            img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
        if img.shape != shape:
            counts["frame_wrong_size"] += 1
            prev = None
            continue
        if img.dtype != np.uint8:
            img = np.clip(img, 0, 255).astype(np.uint8)
        work = clahe.apply(img) if params.clahe else img
        stats = {"k": k, "features": 0, "matches": 0, "inliers": 0, "tracked": 0, "new": 0}
        ids_prev_kept = np.zeros(0, int)
        if det is not None:
            pts, score, desc = _detect(work, det, params, region)
            keep = _bucket(pts, score, shape, params) if len(pts) else np.zeros(0, int)
            pts, desc = undistort(pts[keep]), None if desc is None else desc[keep]
            ids = np.full(len(pts), -1)
            if prev is not None and len(pts):
                pred = None
                if odometry is not None and prev_k == k - 1 and k - 1 < len(odometry):
                    pred = predict_motion(prev.pts, camera, np.asarray(odometry[k - 1], float))
                ii, jj = match_descriptors(prev, pts, desc, params, counts, binary, pred)
                stats["matches"] = int(ii.size)
                ok = _verify(prev.pts[ii], pts[jj], Kmat, params, counts)
                ids[jj[ok]] = prev.ids[ii[ok]]
                ids_prev_kept = prev.ids[ii[ok]]
        else:  # KLT
            pts_t = np.zeros((0, 2), np.float32)
            ids = np.zeros(0, int)
            if prev is not None and len(prev.pts):
                p0 = prev.pts.reshape(-1, 1, 2)
                flags, guess = 0, None
                if odometry is not None and prev_k == k - 1 and k - 1 < len(odometry):
                    g, _ = predict_motion(prev.pts, camera, np.asarray(odometry[k - 1], float))
                    flags, guess = cv2.OPTFLOW_USE_INITIAL_FLOW, g.reshape(-1, 1, 2)
                    guess = guess.astype(np.float32)
                p1, st, _ = cv2.calcOpticalFlowPyrLK(
                    prev.img, work, p0, guess, winSize=(21, 21), flags=flags
                )
                pb, stb, _ = cv2.calcOpticalFlowPyrLK(work, prev.img, p1, None, winSize=(21, 21))
                fb = np.linalg.norm((pb - p0).reshape(-1, 2), axis=1)
                good = (st.ravel() == 1) & (stb.ravel() == 1) & (fb < params.fb_max_px)
                p1 = p1.reshape(-1, 2)
                inside = (p1[:, 0] >= 0) & (p1[:, 0] < shape[1] - 1)
                inside &= (p1[:, 1] >= 0) & (p1[:, 1] < shape[0] - 1)
                counts["fb_check"] += int((~good).sum())
                counts["left_image"] += int((good & ~inside).sum())
                good &= inside
                stats["matches"] = int(good.sum())
                ok = _verify(prev.pts[good], p1[good], Kmat, params, counts)
                pts_t, ids = p1[good][ok], prev.ids[good][ok]
                ids_prev_kept = ids
            mask = np.full(shape, 255, np.uint8) if region is None else region.copy()
            for x, y in pts_t.astype(int):
                cv2.circle(mask, (int(x), int(y)), 7, 0, -1)
            need = max(0, int(params.max_features) - len(pts_t))
            new_pts = np.zeros((0, 2), np.float32)
            if need:
                cand, score, _ = _detect(work, None, params, mask)
                keep = _bucket(cand, score, shape, params) if len(cand) else np.zeros(0, int)
                new_pts = cand[keep][:need]
            pts = np.concatenate([pts_t, new_pts]).astype(np.float32)
            ids = np.concatenate([ids, np.full(len(new_pts), -1)])
            desc = None
        stats["features"] = int(len(pts))
        stats["inliers"] = int(ids_prev_kept.size)
        if prev is not None:  # tracks of the previous frame not continued here end now
            counts["lost"] += int(len(prev.ids) - ids_prev_kept.size)
        if len(pts) == 0:
            counts["frame_without_features"] += 1
        cont = ids >= 0
        for j in np.flatnonzero(cont):
            if length[ids[j]] >= params.max_track_length:
                counts["max_track_length"] += 1
                ids[j] = -1
        new = ids < 0
        ids[new] = np.arange(next_id, next_id + int(new.sum()))
        next_id += int(new.sum())
        for lid in ids:
            length[int(lid)] = length.get(int(lid), 0) + 1
        stats["tracked"] = int((~new).sum())
        stats["new"] = int(new.sum())
        obs_k.append(np.full(len(ids), k))
        obs_id.append(ids.copy())
        obs_uv.append(pts.astype(float))
        prev, prev_k = _Frame(pts, desc, ids, work), k
        stats["ms"] = 1e3 * (time.perf_counter() - t0)
        per_frame.append(stats)
    k_all = np.concatenate(obs_k) if obs_k else np.zeros(0, int)
    id_all = np.concatenate(obs_id) if obs_id else np.zeros(0, int)
    uv_all = np.concatenate(obs_uv) if obs_uv else np.zeros((0, 2))
    if per_frame == []:
        skipped = dict(getattr(images, "skipped", {}) or {})
        raise bad_input(
            "images",
            f"no usable frame (skipped: {skipped or 'none'})",
            f"readable frames of the camera's size ({camera.width_px:g} x {camera.height_px:g} px)",
            "check the files, or the camera's image_width / image_height",
        )
    lens = np.array([length.get(int(i), 0) for i in id_all])
    short = lens < params.min_track_length
    counts["track_too_short"] += int(np.unique(id_all[short]).size)
    keep = ~short
    # renumber the kept tracks 0..n-1 in order of first appearance
    _, first = np.unique(id_all[keep], return_index=True)
    uniq = id_all[keep][np.sort(first)]
    remap = {int(old): new for new, old in enumerate(uniq)}
    ids = np.array([remap[int(i)] for i in id_all[keep]], int)
    return FeatureTracks(k_all[keep], ids, uv_all[keep], counts, per_frame, params, source)
