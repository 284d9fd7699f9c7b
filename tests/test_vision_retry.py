"""Tracks that failed the online triangulation gates are tried again at the refined poses
(factorgraph/track_init.py): recovered ones enter the graph with their factors and leave
the never-initialised counts; the others stay counted by reason."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest

gtsam = pytest.importorskip("gtsam")

from test_vision_view_gate import _pinned  # noqa: E402  (tests/ is on sys.path)

from factorgraph import SensorSuite, simulate_traverse  # noqa: E402
from factorgraph.localize import LocalizeParams, _Tracks, localize  # noqa: E402
from factorgraph.track_init import retry_failed_tracks, triangulate_track  # noqa: E402
from factorgraph.vision import vision_sensors  # noqa: E402


def _setup():
    """Three keyframes 2 m apart along x, pinned by tight priors; the vision camera."""
    camera, K, bTc, graph, values, poses = _pinned(3)
    noise = gtsam.noiseModel.Isotropic.Sigma(2, camera.pixel_sigma_px)
    return camera, K, bTc, graph, values, poses, noise


def _views(point, poses, K, bTc, offsets=None):
    out = []
    for k, pose in poses.items():
        uv = gtsam.PinholeCameraCal3_S2(pose.compose(bTc), K).project(point)
        out.append((k, np.asarray(uv) + (0 if offsets is None else offsets[k])))
    return out


def test_retry_recovers_a_consistent_track_and_keeps_counting_a_bad_one():
    camera, K, bTc, graph, values, poses, noise = _setup()
    params = LocalizeParams()
    good_point = np.array([12.0, 1.0, 0.0])  # 12 m ahead on the ground, 1 m left
    tracks = _Tracks()
    tracks.failed[5] = _views(good_point, poses, K, bTc)
    tracks.failed_reason[5] = ["triangulation_failed"]
    # a wrong association: the middle view 30 px off (no point explains all three views)
    bad = _views(np.array([10.0, -1.0, 0.0]), poses, K, bTc, {0: 0, 1: np.array([30.0, 0]), 2: 0})
    tracks.failed[9], tracks.failed_reason[9] = bad, ["reprojection_gate"]
    tracks.dropped = Counter({"triangulation_failed": 1, "reprojection_gate": 1})
    n_before = graph.size()
    g2, est, rep = retry_failed_tracks(graph, values, tracks, camera, bTc, K, noise, params)
    L = gtsam.symbol_shorthand.L
    assert rep["retry_tried"] == 2 and rep["retry_recovered"] == 1
    assert est.exists(L(5)) and not est.exists(L(9))
    np.testing.assert_allclose(est.atPoint3(L(5)), good_point, atol=1e-6)  # exact views
    assert g2.size() == n_before + 3  # one projection factor per view
    assert tracks.active == {5} and 5 not in tracks.failed and 9 in tracks.failed
    # the recovered track leaves the never-initialised counts, the bad one stays there
    assert tracks.dropped == Counter({"reprojection_gate": 1})
    assert sum(rep["retry_still_failed"].values()) == 1
    assert tracks.init_distance[5] == pytest.approx(np.linalg.norm(good_point - [4.0, 0, 0]))


def test_retried_track_first_seen_distance_is_taken_at_its_min_views_th_view():
    """The distance the 5 m selection rule reads (``first_seen_distance_m``) is measured, as
    online, from the pose where the track could first be initialised: its ``min_views``-th
    view. Before, the retry took its last view, the nearest for a forward-looking camera: on
    the default survey 11 of 18 retried landmarks fell under the 5 m rule that way."""
    camera, K, bTc, graph, values, poses = _pinned(5)  # keyframes at x = 0, 2, 4, 6, 8 m
    noise = gtsam.noiseModel.Isotropic.Sigma(2, camera.pixel_sigma_px)
    point = np.array([14.0, 1.0, 0.0])  # 6 m ahead of the last keyframe
    tracks = _Tracks()
    tracks.failed[3], tracks.failed_reason[3] = _views(point, poses, K, bTc), ["reprojection_gate"]
    tracks.dropped = Counter({"reprojection_gate": 1})
    params = LocalizeParams()
    retry_failed_tracks(graph, values, tracks, camera, bTc, K, noise, params)
    third = np.array([2.0 * (params.min_views - 1), 0.0, 0.0])  # hand computation: x = 4 m
    assert tracks.init_distance[3] == pytest.approx(np.linalg.norm(point - third), abs=1e-6)
    assert tracks.init_distance[3] > np.linalg.norm(point - [8.0, 0.0, 0.0]) + 3.9


def test_triangulate_track_gates():
    camera, K, bTc, _, _, poses, _ = _setup()
    params = LocalizeParams()
    pt, why = triangulate_track(
        _views(np.array([12.0, 1.0, 0.0]), poses, K, bTc), poses, camera, bTc, K, params
    )
    assert why == "ok" and np.allclose(pt, [12.0, 1.0, 0.0], atol=1e-6)
    # 2 px on one view passes a 4 px gate, 6 px does not
    off = {0: 0, 1: np.array([0.0, 2.0]), 2: 0}
    assert (
        triangulate_track(
            _views(np.array([12.0, 1.0, 0.0]), poses, K, bTc, off), poses, camera, bTc, K, params
        )[1]
        == "ok"
    )
    off = {0: 0, 1: np.array([0.0, 12.0]), 2: 0}
    _, why = triangulate_track(
        _views(np.array([12.0, 1.0, 0.0]), poses, K, bTc, off), poses, camera, bTc, K, params
    )
    assert why in ("reprojection_gate", "triangulation_failed")


def test_localize_counts_every_track_once_with_and_without_retry():
    """On a short ideal-track traverse with a tight 1.5 px gate (many online failures):
    landmarks + never-initialised tracks are the same total either way, and the retry
    recovers tracks (the refined poses are better than the online ones)."""
    from terrain.synthetic import default_site

    dem = default_site(4.0)
    x, y = dem.x.values, dem.y.values
    wp = np.array([[x[20], y[70]], [x[20] + 80.0, y[70] + 6.0]])
    sensors = vision_sensors(SensorSuite(keyframe_dt_s=2.0))
    log = simulate_traverse(dem, wp, sensors, seed=3)
    out = {}
    for retry in (False, True):
        loc = localize(log, LocalizeParams(max_reprojection_px=1.5, retry_failed_tracks=retry))
        out[retry] = loc
    n_tracks = np.unique(log.obs_id).size
    for loc in out.values():
        assert loc.n_landmarks + sum(loc.dropped.values()) == n_tracks
    rep = out[True].refine
    assert rep["retry_recovered"] > 0
    assert out[True].n_landmarks > out[False].n_landmarks
    assert rep["retry_tried"] == sum(
        v for key, v in out[False].dropped.items() if key not in ("too_few_views",)
    ) - sum(
        out[False].dropped.get(why, 0)
        for why in ("degenerate_in_graph", "depth_after_refine", "gate_after_refine")
    )


def test_landmark_seen_in_two_segments():
    """A simulated landmark can be seen on two swaths: a track that failed in both segments
    is tried once with all its views and leaves both counts; one already in the graph from
    another segment is skipped (its failed segment stays counted)."""
    camera, K, bTc, graph, values, poses, noise = _setup()
    params = LocalizeParams()
    p = np.array([12.0, 1.0, 0.0])
    v = _views(p, poses, K, bTc)
    tracks = _Tracks()
    tracks.failed[3] = list(v)
    tracks.failed_reason[3] = ["triangulation_failed", "reprojection_gate"]
    tracks.failed[4], tracks.failed_reason[4] = list(v), ["triangulation_failed"]
    tracks.active.add(4)  # initialised online from another segment
    tracks.dropped = Counter({"triangulation_failed": 2, "reprojection_gate": 1})
    _, est, rep = retry_failed_tracks(graph, values, tracks, camera, bTc, K, noise, params)
    assert rep["retry_recovered"] == 1 and rep["retry_skipped_in_graph"] == 1
    assert tracks.dropped == Counter({"triangulation_failed": 1})
    assert 3 not in tracks.failed and 4 in tracks.failed
    assert not est.exists(gtsam.symbol_shorthand.L(4))


def test_recovered_landmarks_are_gated_again_at_the_optimum():
    """_fail_gates_again flags a landmark that ran away (far beyond the range) or whose
    views no longer agree with its point, and keeps a consistent one."""
    from factorgraph.track_init import _fail_gates_again

    camera, K, bTc, _, values, poses, _ = _setup()
    L = gtsam.symbol_shorthand.L
    p = np.array([12.0, 1.0, 0.0])
    v = _views(p, poses, K, bTc)
    values.insert(L(1), p)  # consistent
    values.insert(L(2), np.array([1200.0, 100.0, 0.0]))  # ran away along the view
    values.insert(L(3), p + [0.0, 0.5, 0.0])  # 0.5 m aside: tens of px off
    bad = _fail_gates_again(values, {1: v, 2: v, 3: v}, camera, bTc, K, LocalizeParams())
    assert bad == [2, 3]
