"""The online guard (factorgraph/rebuild.py: OnlineGuard): projection factors whose landmark
lies on the guessed camera's image plane break the iSAM2 elimination; the guard defers them
instead of letting the update fail (which costs a rebuild from every factor)."""

from __future__ import annotations

import numpy as np
import pytest

gtsam = pytest.importorskip("gtsam")

from factorgraph.rebuild import OnlineGuard  # noqa: E402

X, L = gtsam.symbol_shorthand.X, gtsam.symbol_shorthand.L
K = gtsam.Cal3_S2(600.0, 600.0, 0.0, 320.0, 240.0)
PIX = gtsam.noiseModel.Robust.Create(
    gtsam.noiseModel.mEstimator.Huber.Create(1.345), gtsam.noiseModel.Isotropic.Sigma(2, 1.0)
)
POSE_NOISE = gtsam.noiseModel.Isotropic.Sigma(6, 0.1)
POINT = np.array([1.5, 0.3, 8.0])  # world; the cameras look along +z (identity rotation)


def _isam_with_landmark():
    """iSAM2 with 3 keyframes 1 m apart that see landmark 0 at 8 m depth."""
    isam = gtsam.ISAM2()
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for i in range(3):
        pose = gtsam.Pose3(gtsam.Rot3(), np.array([float(i), 0.0, 0.0]))
        graph.add(gtsam.PriorFactorPose3(X(i), pose, POSE_NOISE))
        values.insert(X(i), pose)
        uv = gtsam.PinholeCameraCal3_S2(pose, K).project(POINT)
        graph.add(gtsam.GenericProjectionFactorCal3_S2(uv, PIX, X(i), L(0), K))
    values.insert(L(0), POINT)
    isam.update(graph, values)
    return isam


def _step(depth_m: float):
    """Keyframe 3 guessed with landmark 0 ``depth_m`` in front of its camera, and its view."""
    pose = gtsam.Pose3(gtsam.Rot3(), POINT - [0.0, 0.0, depth_m])
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    graph.add(gtsam.PriorFactorPose3(X(3), pose, POSE_NOISE))
    values.insert(X(3), pose)
    view = gtsam.GenericProjectionFactorCal3_S2(np.array([330.0, 250.0]), PIX, X(3), L(0), K)
    return pose, graph, values, view


def test_in_front_is_the_depth_along_the_optical_axis():
    """Depth = z in the camera frame (body = camera here): 5 m ahead passes, 0.2 m (below
    the 0.5 m gate) and behind do not; 10 m to the side at 1 m depth passes (not range)."""
    guard = OnlineGuard(gtsam.Pose3(), min_depth_m=0.5)
    body = gtsam.Pose3()
    assert guard.in_front(body, np.array([0.0, 0.0, 5.0]))
    assert not guard.in_front(body, np.array([0.0, 0.0, 0.2]))
    assert not guard.in_front(body, np.array([0.0, 0.0, -5.0]))
    assert guard.in_front(body, np.array([10.0, 0.0, 1.0]))
    # the mounting counts: a camera turned 180 deg about the body's y axis looks along -z
    back = OnlineGuard(gtsam.Pose3(gtsam.Rot3.Ry(np.pi), np.zeros(3)), min_depth_m=0.5)
    assert back.in_front(body, np.array([0.0, 0.0, -5.0]))
    assert not back.in_front(body, np.array([0.0, 0.0, 5.0]))


def test_a_view_on_the_image_plane_breaks_isam2_without_the_guard():
    """The failure the guard exists for (measured on the 50,000-landmark survey: a view of
    an existing landmark at ~0 depth from the guessed keyframe, Jacobian norm 2.8e7)."""
    isam = _isam_with_landmark()
    _, graph, values, view = _step(1e-3)
    graph.add(view)
    with pytest.raises(RuntimeError, match="Indeterminate"):
        isam.update(graph, values)


def test_the_guard_defers_that_view_and_the_update_succeeds():
    isam = _isam_with_landmark()
    guard = OnlineGuard(gtsam.Pose3(), min_depth_m=0.5)
    pose, graph, values, view = _step(1e-3)
    lin = isam.getLinearizationPoint()
    guard.view(view, pose, lin.atPoint3(L(0)), graph)
    isam.update(graph, values)
    assert guard.counts["deferred_views"] == 1 and guard.deferred.size() == 1
    assert graph.size() == 1  # only the pose prior went online
    est = isam.calculateEstimate()
    np.testing.assert_allclose(est.atPoint3(L(0)), POINT, atol=1e-6)  # priors exact


def test_the_guard_keeps_a_view_in_front():
    isam = _isam_with_landmark()
    guard = OnlineGuard(gtsam.Pose3(), min_depth_m=0.5)
    pose, graph, values, view = _step(6.0)
    guard.view(view, pose, isam.getLinearizationPoint().atPoint3(L(0)), graph)
    isam.update(graph, values)
    assert guard.counts["deferred_views"] == 0 and graph.size() == 2


def test_new_landmark_postponed_when_any_view_is_behind_its_linearization_point():
    guard = OnlineGuard(gtsam.Pose3(), min_depth_m=0.5)
    ahead = [gtsam.Pose3(gtsam.Rot3(), np.array([float(i), 0.0, 0.0])) for i in range(3)]
    assert guard.new_landmark_ok(POINT, ahead)
    past = [*ahead, gtsam.Pose3(gtsam.Rot3(), POINT + [0.0, 0.0, 1.0])]
    assert not guard.new_landmark_ok(POINT, past)
    assert guard.report() == {
        "deferred_views": 0,
        "postponed_landmarks": 1,
        "rebuilds": 0,
        "rebuild_dropped_landmarks": 0,
    }


def test_rebuild_is_the_last_resort_and_drops_the_named_landmark():
    """When an update fails anyway, rebuild_isam starts a fresh iSAM2 from every other factor
    without the landmarks the elimination names (here the view at 1 mm depth, unguarded)."""
    from factorgraph.rebuild import rebuild_isam

    isam = _isam_with_landmark()
    history = gtsam.NonlinearFactorGraph(isam.getFactorsUnsafe())
    _, graph, values, view = _step(1e-3)
    step = gtsam.NonlinearFactorGraph(graph)
    step.add(view)
    with pytest.raises(RuntimeError) as failed:
        isam.update(step, values)
    fresh, kept, dropped = rebuild_isam(
        isam, gtsam.ISAM2Params(), history, step, values, [], 3, failed.value
    )
    assert dropped == [0]
    est = fresh.calculateEstimate()
    assert not est.exists(L(0)) and est.exists(X(3))
    assert all(L(0) not in kept.at(i).keys() for i in range(kept.size()))
