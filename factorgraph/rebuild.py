"""Recovery when an iSAM2 update fails: rebuild from every other factor, dropping (and
counting) the landmarks the elimination names as indeterminate, so that one degenerate
landmark never ends a localization run."""

from __future__ import annotations

__all__ = ["rebuild_isam", "value_at", "without_keys"]


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
