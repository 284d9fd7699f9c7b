"""What localization returns: poses, landmarks with their marginals, counts and timings."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .log import MeasurementLog

__all__ = ["LocalizationResult"]


@dataclass
class LocalizationResult:
    """The fused estimate of one traverse (local ENU frame of ``log.origin``, metres).

    Attributes
    ----------
    keyframe_xyz : ndarray of shape (K, 3)
        Final (smoothed) keyframe positions.
    keyframe_R : ndarray of shape (K, 3, 3)
        Final body-to-world rotations.
    online_xyz : ndarray of shape (K, 3)
        Each keyframe's position as estimated when it arrived (the filter answer).
    pose_cov_xyz : ndarray of shape (K, 3, 3)
        Marginal covariance of each keyframe position at the final estimate (m^2).
    gps_bias : ndarray of shape (K, 3) or None
        Estimated GPS bias (bias model only).
    odometry_drift : ndarray of shape (K, 2) or None
        Estimated odometry drift per keyframe: scale error (fraction) and heading rate (rad / m)
        (``LocalizeParams.odometry_drift`` only).
    landmark_id : ndarray of shape (L,)
        Track ids of the landmarks kept in the graph.
    landmark_xyz : ndarray of shape (L, 3)
        Landmark positions.
    landmark_cov, landmark_cov_relative : ndarray of shape (L, 3, 3)
        Full marginal covariance, and the covariance with the map-wide shared offset removed.
    shared_offset_cov : ndarray of shape (3, 3)
        Covariance of the rigid offset every landmark shares (from the mean GPS bias).
    n_views : ndarray of shape (L,)
        Observations of each landmark in the graph.
    first_seen_distance_m : ndarray of shape (L,)
        Rover-to-landmark distance when the landmark was initialised (m).
    dropped : dict
        Tracks never initialised, by reason (``too_few_views``, ``low_parallax``, ...).
    step_s : ndarray of shape (K,)
        Wall time of each iSAM2 step (s).
    marginal_s : float
        Wall time of all landmark marginals (s).
    """

    log: MeasurementLog
    params: Any
    keyframe_xyz: np.ndarray
    keyframe_R: np.ndarray
    online_xyz: np.ndarray
    pose_cov_xyz: np.ndarray
    gps_bias: np.ndarray | None
    odometry_drift: np.ndarray | None
    landmark_id: np.ndarray
    landmark_xyz: np.ndarray
    landmark_cov: np.ndarray
    landmark_cov_relative: np.ndarray
    shared_offset_cov: np.ndarray
    n_views: np.ndarray
    first_seen_distance_m: np.ndarray
    dropped: dict[str, int]
    step_s: np.ndarray
    marginal_s: float
    bandwidth: int = 0
    n_rebuilds: int = 0  # iSAM2 rebuilds after a failed update (new landmarks dropped)
    refine: dict = field(default_factory=dict)  # factorgraph.refine.RefineReport.as_dict()
    control: dict = field(default_factory=dict)  # factorgraph.control.control_report(); {} if none
    graph: Any = field(default=None, repr=False)
    estimate: Any = field(default=None, repr=False)

    @classmethod
    def build(
        cls,
        *,
        log,
        params,
        estimate,
        graph,
        marginals,
        tracks,
        online_xyz,
        step_s,
        marginal_s,
        n_rebuilds=0,
        refine=None,
    ) -> LocalizationResult:
        import gtsam

        X, B, L = (gtsam.symbol_shorthand.X, gtsam.symbol_shorthand.B, gtsam.symbol_shorthand.L)
        K = log.n_keyframes
        poses = [estimate.atPose3(X(k)) for k in range(K)]
        ids = np.array(sorted(tracks.active), dtype=int)
        bias = drift = None
        if params.gps_model == "bias":
            bias = np.array([estimate.atPoint3(B(k)) for k in range(K)])
        if params.odometry_drift:
            Dk = gtsam.symbol_shorthand.D
            drift = np.array([estimate.atPoint2(Dk(k)) for k in range(K)])
        views = np.bincount(
            np.searchsorted(ids, log.obs_id[np.isin(log.obs_id, ids)]), minlength=ids.size
        )
        return cls(
            log=log,
            params=params,
            keyframe_xyz=np.array([p.translation() for p in poses]),
            keyframe_R=np.array([p.rotation().matrix() for p in poses]),
            online_xyz=online_xyz,
            pose_cov_xyz=marginals.pose_cov_xyz,
            gps_bias=bias,
            odometry_drift=drift,
            landmark_id=ids,
            landmark_xyz=np.array([estimate.atPoint3(L(i)) for i in ids]).reshape(-1, 3),
            landmark_cov=marginals.landmark_cov,
            landmark_cov_relative=marginals.landmark_cov_relative,
            shared_offset_cov=marginals.shared_cov,
            n_views=views,
            first_seen_distance_m=np.array([tracks.init_distance[i] for i in ids]),
            dropped=dict(sorted(tracks.dropped.items())),
            step_s=step_s,
            marginal_s=marginal_s,
            bandwidth=marginals.bandwidth,
            n_rebuilds=n_rebuilds,
            refine=dict(refine or {}),
            graph=graph,
            estimate=estimate,
        )

    @property
    def n_landmarks(self) -> int:
        return int(self.landmark_id.size)

    def landmark_time_s(self) -> np.ndarray:
        """Mean observation time of each landmark (L,), s on the log's clock.

        The average of the keyframe times ``log.t[k]`` of every observation of the landmark in
        the log (the times its triangulation leans on). The rover's trajectory error is
        correlated in time (the GPS bias wanders with its time constant), so landmarks seen
        in the same minute share an error: :mod:`terrain.along_track` needs this time.
        """
        ids = self.landmark_id
        if ids.size == 0:
            return np.zeros(0)
        log = self.log
        seen = np.isin(log.obs_id, ids)
        pos = np.searchsorted(ids, log.obs_id[seen])
        t = np.asarray(log.t, float)[log.obs_k[seen]]
        n = np.bincount(pos, minlength=ids.size)
        total = np.bincount(pos, weights=t, minlength=ids.size)
        # a landmark in the graph has >= 2 observations; guard the division anyway
        return np.where(n > 0, total / np.maximum(n, 1), np.nan)

    def true_landmarks(self) -> np.ndarray:
        """True positions (L, 3) of the landmarks, from the log's truth (simulation only).

        A landmark the truth does not hold gets a NaN row: an image track whose reference ray
        met the sky has no ground point (:func:`factorgraph.vision.chain.attach_tracks` drops
        it). Matching by id, not by position: a missing id took the next landmark's truth,
        or failed past the last one (bei's 240 m window: ``IndexError``).
        """
        tr = self.log.truth
        ids = np.asarray(tr["landmark_id"])
        order = np.argsort(ids, kind="stable")
        pos = np.clip(np.searchsorted(ids[order], self.landmark_id), 0, max(ids.size - 1, 0))
        out = np.full((self.landmark_id.size, 3), np.nan)
        if ids.size:
            hit = ids[order][pos] == self.landmark_id
            out[hit] = np.asarray(tr["landmark_xyz"], float)[order[pos[hit]]]
        return out

    def to_projected(self, xyz: np.ndarray) -> np.ndarray:
        """Local ENU (n, 3) -> projected easting, northing, elevation (n, 3) in ``log.crs``."""
        out = np.array(xyz, float, copy=True)
        out[:, :2] += self.log.origin
        return out
