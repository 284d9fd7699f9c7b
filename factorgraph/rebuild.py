"""Keeping the online iSAM2 pass alive: a guard that holds back projection factors whose
linearization would break the elimination, and, as the last resort when an update still
fails, a rebuild from every other factor that drops (and counts) the landmarks the
elimination names as indeterminate, so that one degenerate landmark never ends a run.

Why the guard
-------------
The online pass never relinearizes (``LocalizeParams.relinearize``): every variable keeps
the value it was inserted with. A projection factor is linearized at the landmark's
insertion point and the keyframe's dead-reckoned guess, which can be metres from where the
triangulation (at the current estimates) put things. When the landmark lies on or behind
the guessed camera's image plane, the pinhole Jacobian ``f / z`` explodes (measured: norm
2.8e7, error 7.4e6 for one view of a landmark 3.4 m from the body, 50,000-landmark survey,
keyframe 75) and the elimination stops with an indeterminate system near that keyframe.
A failed
``ISAM2.update`` has already added the new factors and values and removed the top of the
Bayes tree when the elimination throws; whether a second update with
``removeFactorIndices`` leaves a consistent tree is not documented, so the recovery after
a failure stays a rebuild from every factor (measured on that survey: 14 s at 190,000
factors, 57 s at 240,000; the last 100 steps took 38 s after a rebuild at keyframe 1,170,
15 s with the guard). The
guard checks the depth of the landmark in each camera *at the linearization point* before
the update: a view of an existing landmark that fails is deferred to the batch refinement
(it joins the graph after the online pass, where every landmark is re-triangulated at the
refined poses, factorgraph/refine.py); a new landmark with such a view is not inserted yet
(the track stays pending, a later view or the retry at the refined poses may take it,
factorgraph/track_init.py). Both are counted (:attr:`OnlineGuard.counts`).
"""

from __future__ import annotations

from collections import Counter

import numpy as np

__all__ = ["OnlineGuard", "rebuild_isam", "value_at", "without_keys"]


class OnlineGuard:
    """Depth check of projection factors at the online linearization point.

    Parameters
    ----------
    bTc : gtsam.Pose3
        Camera mounting in the body frame.
    min_depth_m : float
        Smallest depth (m, along the optical axis) at which a view is linearized online: the
        triangulation gate's ``LocalizeParams.min_depth_m``.

    Attributes
    ----------
    deferred : gtsam.NonlinearFactorGraph
        Projection factors of existing landmarks held back from the online pass; the caller
        adds them to the whole graph after the last keyframe.
    counts : collections.Counter
        ``deferred_views`` (factors in ``deferred``), ``postponed_landmarks`` (triangulated
        tracks not inserted at this keyframe), ``rebuilds`` and ``rebuild_dropped_landmarks``
        (the last resort, :func:`rebuild_isam`).
    """

    def __init__(self, bTc, min_depth_m: float):
        import gtsam

        self.bTc = bTc
        self.min_depth_m = float(min_depth_m)
        self.deferred = gtsam.NonlinearFactorGraph()
        self.counts: Counter = Counter(
            deferred_views=0, postponed_landmarks=0, rebuilds=0, rebuild_dropped_landmarks=0
        )

    def in_front(self, body_pose, point: np.ndarray) -> bool:
        """Whether ``point`` (world, m) is at least ``min_depth_m`` in front of the camera of
        body pose ``body_pose`` (gtsam.Pose3, world frame)."""
        return bool(body_pose.compose(self.bTc).transformTo(point)[2] >= self.min_depth_m)

    def view(self, factor, body_pose, point: np.ndarray, graph) -> None:
        """Add projection ``factor`` of an existing landmark to this step's ``graph`` when its
        landmark (linearization point ``point``) is in front of the camera at ``body_pose``
        (the keyframe's linearization point); else defer it (counted)."""
        if self.in_front(body_pose, point):
            graph.add(factor)
        else:
            self.deferred.add(factor)
            self.counts["deferred_views"] += 1

    def new_landmark_ok(self, point: np.ndarray, view_poses) -> bool:
        """Whether a new landmark at ``point`` is in front of every camera at the
        linearization points ``view_poses`` (iterable of gtsam.Pose3); counts a postponement
        when not."""
        if all(self.in_front(p, point) for p in view_poses):
            return True
        self.counts["postponed_landmarks"] += 1
        return False

    def report(self) -> dict[str, int]:
        """The counts as plain ints."""
        return {k: int(v) for k, v in self.counts.items()}


def value_at(values, key: int):
    """The value of ``key`` by its symbol: Pose3 ``x``, Point2 ``d`` (drift), else Point3."""
    import gtsam

    ch = chr(gtsam.Symbol(key).chr())
    if ch == "x":
        return values.atPose3(key)
    return values.atPoint2(key) if ch == "d" else values.atPoint3(key)


def without_keys(graph, bad: set[int]):
    """Copy of ``graph`` without the factors touching any key in ``bad``."""
    import gtsam

    out = gtsam.NonlinearFactorGraph()
    for i in range(graph.size()):
        f = graph.at(i)
        if f is not None and not bad.intersection(f.keys()):
            out.push_back(f)
    return out


def _landmarks_seen_by(graph, pose_key: int) -> list[int]:
    """Landmark ids with a factor on ``pose_key`` in ``graph``."""
    import gtsam

    out = set()
    for i in range(graph.size()):
        f = graph.at(i)
        if f is None or pose_key not in f.keys():
            continue
        for key in f.keys():
            s = gtsam.Symbol(key)
            if chr(s.chr()) == "l":
                out.add(int(s.index()))
    return sorted(out)


def rebuild_isam(isam, isam_params, history, graph, values, new_lids, k, exc, max_tries=25):
    """A fresh iSAM2 from ``history`` + this step's ``graph``, without this step's new
    landmarks and without any landmark the elimination reports as indeterminate (a point
    pushed behind its cameras has no Jacobian). Returns ``(isam, history, dropped_ids)``."""
    import re

    import gtsam

    from terrain.errors import NumericalError

    L = gtsam.symbol_shorthand.L
    theta = gtsam.Values(isam.getLinearizationPoint())
    for key in values.keys():
        if not theta.exists(key):
            theta.insert(key, value_at(values, key))
    full = gtsam.NonlinearFactorGraph(history)
    full.push_back(graph)
    dropped = list(new_lids)
    bad = {L(lid) for lid in new_lids}
    message = str(exc)
    for _ in range(max_tries):
        full = without_keys(full, bad)
        for key in bad:
            if theta.exists(key):
                theta.erase(key)
        fresh = gtsam.ISAM2(isam_params)
        try:
            fresh.update(full, theta)
            return fresh, full, dropped
        except RuntimeError as again:
            message = str(again)
            hit = re.search(r"Symbol: ([lxbd])(\d+)", message)
            if hit is None:
                break
            if hit.group(1) == "l":
                dropped.append(int(hit.group(2)))
                bad = {L(dropped[-1])}
            else:  # keyframe k's pose, GPS bias or drift state: drop the landmarks its
                # pose saw (their geometry made that keyframe singular)
                X = gtsam.symbol_shorthand.X
                seen = _landmarks_seen_by(full, X(int(hit.group(2))))
                if not seen:
                    break
                dropped.extend(seen)
                bad = {L(lid) for lid in seen}
    raise NumericalError(
        f"iSAM2 failed at keyframe {k} after dropping landmarks {dropped[:10]} and "
        f"rebuilding: {message.strip().splitlines()[0]}. Fix: check the odometry and GPS "
        "noise levels in the log's sensor models"
    )
