"""Landmark initialisation from feature tracks: the gated triangulation the online pass runs
when a track has enough views, and a second try for the tracks that failed it, at the
refined (smoothed) poses.

Why the second try
------------------
The online pass triangulates a track with the online poses of its views, once it has
``min_views`` views and again at each later view. Those poses are the iSAM2 linear solution at
the insertion points (docs/architecture.md §5; factorgraph/refine.py): their relative errors
can push a correct track past the reprojection gate. Image tracks are short (3.2 views at
2 m keyframe spacing) and are usually tried once or twice. Measured on the default survey in
sun (benchmarks/vision.py, docs/vision.md): most tracks that failed online pass the same gate
at the refined poses. Ideal 1 px tracks on a dense graph (50,000 landmarks) fail online too
(the linear online solution is worse with more landmarks) and are recovered the same way.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from .rebuild import without_keys

__all__ = ["retry_failed_tracks", "triangulate_track"]


def triangulate_track(views, poses, camera, bTc, K, params) -> tuple[np.ndarray | None, str]:
    """Gated triangulation of one track; returns ``(point or None, reason)``.

    Parameters
    ----------
    views : list of (int, ndarray of shape (2,))
        Keyframe index and measured pixel (u, v) of each view.
    poses : mapping int -> gtsam.Pose3
        Body poses (world frame) of at least the keyframes in ``views``.
    camera : factorgraph.sensors.CameraModel
        Range limits (m).
    bTc : gtsam.Pose3
        Camera mounting in the body frame.
    K : gtsam.Cal3_S2
        Intrinsics (px).
    params : factorgraph.localize.LocalizeParams
        ``max_reprojection_px``, ``min_parallax_deg``, ``min_depth_m``.

    Returns
    -------
    point : ndarray of shape (3,) or None
        World point (m) when every gate passes.
    reason : str
        ``ok`` or why the track was rejected (``triangulation_failed`` / ``_degenerate``,
        ``low_parallax``, ``depth_out_of_bounds``, ``reprojection_gate``).
    """
    import gtsam

    cams = gtsam.CameraSetCal3_S2()
    meas = []
    centres = []
    for k, uv in views:
        wTc = poses[k].compose(bTc)
        cams.append(gtsam.PinholeCameraCal3_S2(wTc, K))
        meas.append(uv)
        centres.append(wTc.translation())
    tp = gtsam.TriangulationParameters(
        1e-9, False, camera.range_max_m * 2.0, params.max_reprojection_px
    )
    res = gtsam.triangulateSafe(cams, meas, tp)
    if not res.valid():
        return None, "triangulation_degenerate" if res.degenerate() else "triangulation_failed"
    pt = np.asarray(res.get())
    rays = pt - np.asarray(centres)
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    cosines = np.clip(rays @ rays.T, -1.0, 1.0)
    if math.degrees(math.acos(cosines.min())) < params.min_parallax_deg:
        return None, "low_parallax"
    for cam, uv in zip(cams, meas, strict=False):
        pc = cam.pose().transformTo(pt)
        if pc[2] < params.min_depth_m or np.linalg.norm(pc) > camera.range_max_m * 1.5:
            return None, "depth_out_of_bounds"
        if np.linalg.norm(cam.project(pt) - uv) > params.max_reprojection_px:
            return None, "reprojection_gate"
    return pt, "ok"


def retry_failed_tracks(
    graph, estimate, tracks, camera, bTc, K, pix_noise, params
) -> tuple[Any, Any, dict[str, Any]]:
    """Triangulate again, at the poses of ``estimate``, every track the online pass rejected;
    add the ones that pass the same gates and re-optimise the whole graph.

    Parameters
    ----------
    graph : gtsam.NonlinearFactorGraph
        Every factor of the localization.
    estimate : gtsam.Values
        The refined estimate (poses ``x``, landmarks ``l``, ...).
    tracks : factorgraph.localize._Tracks
        Its ``failed`` tracks (id -> views) are tried, except those already in the graph
        (``active``, from another segment of the same landmark) or ``banned``; a recovered
        track leaves ``failed``, its online reason counts in ``dropped`` (one per failed
        segment) are lowered and it joins ``active``.
    camera, bTc, K, params
        As :func:`triangulate_track`; ``params.refine_max_iterations`` and
        ``params.refine_rtol`` bound the Levenberg-Marquardt pass.
    pix_noise : gtsam.noiseModel.Base
        Noise model of the projection factors (the online one, Huber included).

    Returns
    -------
    graph, estimate : gtsam.NonlinearFactorGraph, gtsam.Values
        With the recovered landmarks; ``estimate`` re-optimised when any was added.
    report : dict
        ``retry_tried``, ``retry_recovered`` (kept in the end), ``retry_still_failed`` (by
        reason), ``retry_skipped_in_graph``, ``retry_rejected_after_refine`` (recovered, then
        failing the gates at the optimum: removed, counted ``gate_after_retry`` in
        ``tracks.dropped``),
        ``retry_iterations``, ``retry_error_start`` / ``retry_error_final`` and
        ``retry_seconds``; when a landmark was added also ``error_final`` (the error of the
        returned graph at the returned estimate, replacing the refinement's).
    """
    import gtsam

    from .refine import levenberg_marquardt

    t0 = time.perf_counter()
    X, L = gtsam.symbol_shorthand.X, gtsam.symbol_shorthand.L
    cache: dict[int, Any] = {}

    def pose(k: int):
        if k not in cache:
            cache[k] = estimate.atPose3(X(k))
        return cache[k]

    class _Poses:
        def __getitem__(self, k: int):
            return pose(k)

    still: dict[str, int] = {}
    new_graph = gtsam.NonlinearFactorGraph(graph)
    new_values = gtsam.Values(estimate)
    recovered = in_graph = 0
    recovered_views: dict[int, list] = {}
    for lid, views in sorted(tracks.failed.items()):
        if lid in tracks.active or lid in tracks.banned:  # initialised (or banned) from
            in_graph += 1  # another segment of the same landmark: leave it as it is
            continue
        views = sorted(views, key=lambda v: v[0])
        pt, why = triangulate_track(views, _Poses(), camera, bTc, K, params)
        if pt is None:
            still[why] = still.get(why, 0) + 1
            continue
        new_values.insert(L(lid), pt)
        for kv, uv in views:
            new_graph.add(
                gtsam.GenericProjectionFactorCal3_S2(uv, pix_noise, X(kv), L(lid), K, bTc)
            )
        tracks.active.add(lid)
        recovered_views[lid] = views
        tracks.first_k[lid] = views[0][0]
        # The distance online initialisation would have recorded had the track passed at its
        # first chance: from the pose of its min_views-th view (localize.py measures from the
        # pose of the view that completes the track). The last view of a forward-looking
        # camera is its nearest, which put retried tracks under the 5 m rule (select.py).
        k_init = views[min(params.min_views, len(views)) - 1][0]
        tracks.init_distance[lid] = float(np.linalg.norm(pt - pose(k_init).translation()))
        for online_reason in tracks.failed_reason.pop(lid):
            tracks.dropped[online_reason] -= 1
            if tracks.dropped[online_reason] == 0:
                del tracks.dropped[online_reason]
        del tracks.failed[lid]
        recovered += 1
    report: dict[str, Any] = {
        "retry_tried": recovered + sum(still.values()),
        "retry_skipped_in_graph": in_graph,
        "retry_recovered": recovered,
        "retry_still_failed": dict(sorted(still.items())),
        "retry_iterations": 0,
    }
    report["retry_rejected_after_refine"] = 0
    if recovered:
        report["retry_error_start"] = new_graph.error(new_values)
        new_values, report["retry_iterations"], hist = levenberg_marquardt(
            new_graph, new_values, params.refine_max_iterations, params.refine_rtol
        )
        # A wrong association can pass the gates at the start and then run away in the joint
        # optimisation (measured: 10 % swapped image tracks, 51 keyframes, one landmark
        # 1 km off). The recovered landmarks must pass the gates again at the optimum.
        bad = _fail_gates_again(new_values, recovered_views, camera, bTc, K, params)
        if bad:
            new_graph = _without_landmarks(new_graph, bad)
            for lid in bad:
                new_values.erase(L(lid))
                tracks.active.discard(lid)
                tracks.dropped["gate_after_retry"] += 1
            report["retry_rejected_after_refine"] = len(bad)
            report["retry_recovered"] = recovered - len(bad)
            new_values, more, hist = levenberg_marquardt(
                new_graph, new_values, params.refine_max_iterations, params.refine_rtol
            )
            report["retry_iterations"] += more
        # the final graph now holds the recovered landmarks: its error is the final one
        report["retry_error_final"] = report["error_final"] = hist[-1]
        graph, estimate = new_graph, new_values
    report["retry_seconds"] = time.perf_counter() - t0
    return graph, estimate, report


def _fail_gates_again(values, views_by_lid, camera, bTc, K, params) -> list[int]:
    """Ids of the landmarks in ``views_by_lid`` whose point in ``values`` is nearer than
    ``min_depth_m`` to, behind or beyond 1.5 x the range of a camera that sees it, or
    reprojects farther than ``max_reprojection_px`` from one of its views."""
    import gtsam

    X, L = gtsam.symbol_shorthand.X, gtsam.symbol_shorthand.L
    bad = []
    for lid, views in views_by_lid.items():
        pt = values.atPoint3(L(lid))
        for k, uv in views:
            cam = gtsam.PinholeCameraCal3_S2(values.atPose3(X(k)).compose(bTc), K)
            pc = cam.pose().transformTo(pt)
            if pc[2] < params.min_depth_m or np.linalg.norm(pc) > camera.range_max_m * 1.5:
                bad.append(lid)
                break
            if np.linalg.norm(cam.project(pt) - uv) > params.max_reprojection_px:
                bad.append(lid)
                break
    return bad


def _without_landmarks(graph, lids: list[int]):
    """Copy of ``graph`` without the factors that touch landmarks ``lids``."""
    import gtsam

    return without_keys(graph, {gtsam.symbol_shorthand.L(lid) for lid in lids})
