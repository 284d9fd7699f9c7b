"""Wrong associations out of the graph: a per-view reprojection gate at the refined estimate.

Why this exists
---------------
A feature track from images can hold a wrong association (repeated texture: one view of a
track is another surface point). The online pass triangulates a track through gates once it
has ``min_views`` views (factorgraph/track_init.py) and then adds every later view of the
landmark without a test, so a wrong view that arrives after the landmark exists enters the
graph. The Huber kernel on the projection factors bounds the *weight* of such a view only
at the point where it is linearized; in the batch refinement (factorgraph/refine.py) a view
100-400 px from its landmark still pulls with the Huber's constant force ``k sigma`` per
view, and the graph finds a lower error by bending the trajectory. Measured
(docs/vision.md, "Wrong matches"; 240 m part of the default site, sunny-snow images with
10 % of the tracks given one swapped view, seed 0): 19 wrong views left in the graph, at
81-367 px (median, p99) from their landmarks at the refined estimate, against a median of
0.33 px and p99 of 1.7 px for the correct views; the refinement took the keyframe
horizontal RMSE from 2.45 m (online smoothed estimate) to 8.67 m, and removing those 19
views by hand brought it back to 2.49 m.

The gate
--------
At a refined estimate, every projection factor's reprojection error (px) is computed at its
landmark and keyframe. A landmark with a view beyond ``gate_px`` loses its worst view, is
triangulated again from the rest at the same poses (GTSAM ``triangulatePoint3`` with its
nonlinear refinement), and is tested again, until every remaining view passes; when fewer
than ``min_views`` would remain it is removed with all its factors. The gate is a chi2(2)
test of the whitened residual against the pixel sigma at a small false-alarm probability
(:func:`view_gate_px`; ``LocalizeParams.view_gate_false_alarm``, 1e-6: 5.26 px at 1 px):
Gaussian pixel noise almost never reaches it, a wrong association (tens to hundreds of px)
always does. The triangulation gate (4 px) was tried first: on the default ideal-track run
it cut 15 of 29,998 correct views (the 4-sigma tail), which cost a second refinement
(+5 s of CPU, 12 -> 17 s) and moved every number in the 4th digit. :func:`gate_views` returns
the counts; the caller re-runs the refinement on the cleaned graph from the online estimate
(so the cut views' pull on the trajectory is gone, not only damped) and gates again, up to a
number of rounds.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = [
    "camera_poses",
    "drop_landmarks_at_cameras",
    "gate_views",
    "gated_refinement",
    "projection_views",
    "view_gate_px",
    "view_residuals_px",
]


def _zero_counts() -> dict[str, Any]:
    """What one gate pass counts, before it cuts anything."""
    return {
        "views_cut": 0,
        "landmarks_trimmed": 0,
        "landmarks_removed": 0,
        "views_removed_with_landmarks": 0,
        "removed_ids": [],
        "worst_px": 0.0,
    }


def view_gate_px(pixel_sigma_px: float, false_alarm: float) -> float:
    """The gate (px) on a view's reprojection error: the chi2 test with 2 degrees of freedom
    on ``|e|^2 / sigma^2`` at false-alarm probability ``false_alarm`` per correct view
    (pixel noise N(0, sigma^2) per axis). chi2(2)'s survival function is ``exp(-c / 2)``,
    so the gate is ``sigma sqrt(-2 ln false_alarm)`` (1e-6: 5.26 sigma). A residual at the
    optimum is smaller than the noise (the landmark is fitted to its views), so the real
    rate is lower still."""
    return float(pixel_sigma_px) * float(np.sqrt(-2.0 * np.log(false_alarm)))


def projection_views(graph) -> dict[str, np.ndarray]:
    """The projection factors of ``graph`` as arrays.

    Returns
    -------
    dict
        ``index`` (n,) factor index in ``graph``, ``pose`` (n,) and ``landmark`` (n,) keys
        (gtsam key integers), ``uv`` (n, 2) measured pixel, ``lid`` (n,) landmark ids.
    """
    import gtsam

    idx, pose, lm, uv = [], [], [], []
    for i in range(graph.size()):
        f = graph.at(i)
        if not isinstance(f, gtsam.GenericProjectionFactorCal3_S2):
            continue
        a, b = f.keys()
        xk, lk = (a, b) if chr(gtsam.Symbol(a).chr()) == "x" else (b, a)
        idx.append(i)
        pose.append(xk)
        lm.append(lk)
        uv.append(f.measured())
    return {
        "index": np.asarray(idx, dtype=np.int64),
        "pose": np.asarray(pose, dtype=np.uint64),
        "landmark": np.asarray(lm, dtype=np.uint64),
        "uv": np.asarray(uv, dtype=float).reshape(-1, 2),
        "lid": np.array([gtsam.Symbol(int(k)).index() for k in lm], dtype=np.int64),
    }


def camera_poses(estimate, pose_keys: np.ndarray, bTc) -> tuple[np.ndarray, np.ndarray]:
    """World-from-camera rotations (n, 3, 3) and camera centres (n, 3), m, of the body poses
    ``pose_keys`` (n,) (gtsam keys) in ``estimate`` with camera mounting ``bTc``
    (gtsam.Pose3)."""
    uniq, inv = np.unique(pose_keys, return_inverse=True)
    R = np.empty((uniq.size, 3, 3))
    c = np.empty((uniq.size, 3))
    for j, key in enumerate(uniq):
        wTc = estimate.atPose3(int(key)).compose(bTc)
        R[j], c[j] = wTc.rotation().matrix(), wTc.translation()
    return R[inv], c[inv]


def view_residuals_px(
    R: np.ndarray, c: np.ndarray, points: np.ndarray, uv: np.ndarray, K: np.ndarray
) -> np.ndarray:
    """Reprojection error (n,) in px of world ``points`` (n, 3) seen by pinhole cameras with
    world-from-camera rotations ``R`` (n, 3, 3) and centres ``c`` (n, 3) (camera frame: z
    along the optical axis), intrinsic matrix ``K`` (3, 3), measured pixels ``uv`` (n, 2).
    A point not in front of its camera gets ``inf``."""
    pc = np.einsum("nji,nj->ni", R, points - c)  # R^T (p - c)
    z = pc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        proj = (pc @ K.T)[:, :2] / z[:, None]
        err = np.linalg.norm(proj - uv, axis=1)
    return np.where(z > 0, err, np.inf)


def _retriangulate(R, c, uv, calibration):
    """Triangulated world point (3,) of one landmark's views, or None (GTSAM DLT + Gauss-
    Newton refinement on all given views)."""
    import gtsam

    cams = gtsam.CameraSetCal3_S2()
    meas = []
    for Ri, ci, z in zip(R, c, uv, strict=True):
        cams.append(gtsam.PinholeCameraCal3_S2(gtsam.Pose3(gtsam.Rot3(Ri), ci), calibration))
        meas.append(z)
    try:
        p = np.asarray(gtsam.triangulatePoint3(cams, meas, 1e-9, True))
    except RuntimeError:
        return None
    return p if np.all(np.isfinite(p)) else None


def gate_views(
    graph, estimate, bTc, calibration, gate_px: float, min_views: int
) -> tuple[Any, Any, dict[str, Any]]:
    """Cut the views that fail the reprojection gate at ``estimate`` (see the module docs).

    Parameters
    ----------
    graph : gtsam.NonlinearFactorGraph
        Every factor of the localization.
    estimate : gtsam.Values
        The estimate to test at (a refined one: at the online estimate correct views are off
        by up to ~12 px, measured).
    bTc : gtsam.Pose3
        Camera mounting in the body frame.
    calibration : gtsam.Cal3_S2
        Intrinsics (px).
    gate_px : float
        Largest reprojection error (px) a view may keep.
    min_views : int
        Fewest views a landmark may keep (the triangulation's ``min_views``).

    Returns
    -------
    graph : gtsam.NonlinearFactorGraph
        Without the cut views and without every factor of a removed landmark (the input
        graph itself when nothing was cut).
    estimate : gtsam.Values
        A copy with the trimmed landmarks re-triangulated and the removed ones erased (the
        input when nothing was cut).
    report : dict
        ``views_tested``; ``views_cut`` (views cut from landmarks that stay),
        ``landmarks_trimmed`` (landmarks that lost views and stay), ``landmarks_removed``
        (fewer than ``min_views`` views would remain, or no triangulation), ``views_removed
        _with_landmarks`` (every view of those), ``removed_ids`` (sorted landmark ids) and
        ``worst_px`` (largest error among the cut views, or 0.0).
    """
    import gtsam

    v = projection_views(graph)
    report: dict[str, Any] = {"views_tested": int(v["index"].size), **_zero_counts()}
    if v["index"].size == 0:
        return graph, estimate, report
    R, c = camera_poses(estimate, v["pose"], bTc)
    ulm, inv = np.unique(v["landmark"], return_inverse=True)
    pts = np.array([estimate.atPoint3(int(k)) for k in ulm]).reshape(-1, 3)
    Kmat = calibration.K()
    err = view_residuals_px(R, c, pts[inv], v["uv"], Kmat)
    failing = np.unique(inv[~(err <= gate_px)])
    if failing.size == 0:
        return graph, estimate, report
    cut_factors: set[int] = set()
    removed_keys: set[int] = set()
    new_points: dict[int, np.ndarray] = {}
    worst = 0.0
    for j in failing:
        rows = np.flatnonzero(inv == j)
        e = err[rows]
        while True:
            bad = int(np.argmax(np.where(np.isfinite(e), e, np.inf)))
            worst = max(worst, float(e[bad]) if np.isfinite(e[bad]) else worst)
            keep = np.delete(np.arange(rows.size), bad)
            p = None
            if keep.size >= min_views:
                p = _retriangulate(R[rows[keep]], c[rows[keep]], v["uv"][rows[keep]], calibration)
            if p is None:  # too few views left, or no point explains them
                removed_keys.add(int(ulm[j]))
                report["views_removed_with_landmarks"] += int((v["landmark"] == ulm[j]).sum())
                break
            cut_factors.add(int(v["index"][rows[bad]]))
            report["views_cut"] += 1
            rows = rows[keep]
            e = view_residuals_px(
                R[rows], c[rows], np.broadcast_to(p, (rows.size, 3)), v["uv"][rows], Kmat
            )
            if np.all(e <= gate_px):
                new_points[int(ulm[j])] = p
                report["landmarks_trimmed"] += 1
                break
    # views already cut from a landmark that was removed later count with the landmark
    cut_of_removed = {
        int(i) for i in v["index"][np.isin(v["landmark"], list(removed_keys))]
    } & cut_factors
    report["views_cut"] -= len(cut_of_removed)
    out = gtsam.NonlinearFactorGraph()
    for i in range(graph.size()):
        f = graph.at(i)
        if f is None or i in cut_factors or removed_keys.intersection(f.keys()):
            continue
        out.push_back(f)
    values = gtsam.Values(estimate)
    for key, p in new_points.items():
        values.update(key, p)
    for key in removed_keys:
        values.erase(key)
    report["landmarks_removed"] = len(removed_keys)
    report["removed_ids"] = sorted(int(gtsam.Symbol(k).index()) for k in removed_keys)
    report["worst_px"] = worst
    return out, values, report


def gated_refinement(graph, online, refined, refine_report, bTc, calibration, gate_px, params):
    """Gate the views at the refined estimate and refine again without the cut ones.

    Each round gates at the current refined estimate (:func:`gate_views`); when anything
    was cut, the staged refinement (:func:`factorgraph.refine.refine_estimate`) runs again
    on the cleaned graph from the *online* estimate (minus the removed landmarks), so the
    trajectory the cut views had bent is not the start. A landmark keeps at least
    ``params.min_views`` views, at most ``params.view_gate_rounds`` gate passes run and each
    refinement uses ``params.refine_max_iterations`` / ``params.refine_rtol``
    (:class:`factorgraph.localize.LocalizeParams`).

    Parameters
    ----------
    graph : gtsam.NonlinearFactorGraph
        Every factor of the localization.
    online : gtsam.Values
        The online iSAM2 estimate the first refinement started from.
    refined : gtsam.Values
        That refinement's result.
    refine_report : factorgraph.refine.RefineReport
        Its report (returned unchanged when nothing is cut).
    bTc : gtsam.Pose3
        Camera mounting in the body frame.
    calibration : gtsam.Cal3_S2
        Intrinsics (px).
    gate_px : float
        Largest reprojection error a view may keep (px; :func:`view_gate_px`).
    params : factorgraph.localize.LocalizeParams
        Rounds, ``min_views`` and refinement settings (above).

    Returns
    -------
    graph, estimate, refine_report
        The cleaned graph, its refined estimate and that refinement's report.
    summary : dict
        Summed counts of :func:`gate_views` over the rounds (``views_cut``,
        ``landmarks_trimmed``, ``landmarks_removed``, ``views_removed_with_landmarks``,
        ``removed_ids``, ``worst_px``), ``gate_px``, ``views_tested`` (first pass),
        ``rounds`` (gate passes run), ``converged`` (the last pass cut nothing),
        ``views_cut_per_round`` and ``seconds``.
    """
    import time

    import gtsam

    from .refine import refine_estimate

    t0 = time.perf_counter()
    summary: dict[str, Any] = {
        **_zero_counts(),
        "gate_px": float(gate_px),
        "views_tested": 0,
        "rounds": 0,
        "converged": False,
        "views_cut_per_round": [],
    }
    min_views = params.min_views
    for _ in range(params.view_gate_rounds):
        graph, gated, rep = gate_views(graph, refined, bTc, calibration, gate_px, min_views)
        summary["rounds"] += 1
        summary["views_tested"] = summary["views_tested"] or rep["views_tested"]
        summary["views_cut_per_round"].append(
            rep["views_cut"] + rep["views_removed_with_landmarks"]
        )
        for key in ("views_cut", "landmarks_trimmed", "landmarks_removed"):
            summary[key] += rep[key]
        summary["views_removed_with_landmarks"] += rep["views_removed_with_landmarks"]
        summary["removed_ids"] += rep["removed_ids"]
        summary["worst_px"] = max(summary["worst_px"], rep["worst_px"])
        if gated is refined:  # nothing cut
            summary["converged"] = True
            break
        start = gtsam.Values(online)
        for lid in summary["removed_ids"]:
            key = gtsam.symbol_shorthand.L(lid)
            if start.exists(key):
                start.erase(key)
        refined, refine_report = refine_estimate(
            graph, start, bTc, calibration, params.refine_max_iterations, params.refine_rtol
        )
    summary["removed_ids"] = sorted(summary["removed_ids"])
    summary["seconds"] = time.perf_counter() - t0
    return graph, refined, refine_report, summary


def drop_landmarks_at_cameras(
    graph, estimate, tracks, bTc, min_depth_m: float, max_range_m: float = np.inf
):
    """Remove the landmarks that the refinement left nearer than ``min_depth_m`` to (or
    behind), or farther than ``max_range_m`` from, a camera that sees them, with their
    factors and values (``estimate`` is changed in place); counted in
    ``tracks.dropped["depth_after_refine"]`` and taken out of ``tracks.active``
    (``factorgraph.localize._Tracks``). (Far: a wrong association ran one landmark 30 km
    away; 10 % swapped image tracks, 51 keyframes.) Near: a wrong association can pull a
    point onto a camera centre, where its information is ~1e15 and the Schur complement of
    the marginals loses positive definiteness (measured: 10 % swapped image tracks, 51
    keyframes). Returns the graph without them (the input graph when none)."""
    import gtsam

    from .rebuild import without_keys

    bad = set()
    for i in range(graph.size()):
        f = graph.at(i)
        keys = [gtsam.Symbol(key) for key in f.keys()] if f is not None else []
        if len(keys) != 2 or {chr(k.chr()) for k in keys} != {"x", "l"}:
            continue
        xk, lk = sorted(keys, key=lambda k: chr(k.chr()) == "l")
        wTc = estimate.atPose3(xk.key()).compose(bTc)
        pc = wTc.transformTo(estimate.atPoint3(lk.key()))
        if pc[2] < min_depth_m or np.linalg.norm(pc) > max_range_m:
            bad.add(int(lk.index()))
    if not bad:
        return graph
    L = gtsam.symbol_shorthand.L
    kept = without_keys(graph, {L(lid) for lid in bad})
    for lid in bad:
        estimate.erase(L(lid))
        tracks.active.discard(lid)
        tracks.dropped["depth_after_refine"] += 1
    return kept
