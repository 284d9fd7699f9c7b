"""iSAM2 localization: Pose3 keyframes, odometry between-factors, GPS with explicit
Gauss-Markov bias states (or, as a negative control, plain white-noise GPS factors), and
``GenericProjectionFactorCal3_S2`` with a Huber kernel on explicit ``Point3`` landmarks,
initialised by gated triangulation.

After the online pass: the staged batch refinement (:mod:`factorgraph.refine`), the
per-view reprojection gate that takes wrong associations out of the graph and refines
again (:mod:`factorgraph.view_gate`), and the retry of the tracks that failed the gates
online (:mod:`factorgraph.track_init`).

Each step asks iSAM2 only for the current pose (docs/architecture.md §5: a whole-graph
``calculateEstimate`` per step costs ~0.6 s at 600 steps). Landmark marginals are computed
once at the final estimate by :mod:`factorgraph.marginals`.
"""

from __future__ import annotations

import math
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from terrain.errors import bad_input

from .control import ControlPoints, add_control_factors, control_report, plan_control
from .factors import biased_gps_factor, drift_odometry_factor, gauss_markov_factor, gm_transition
from .field.gate import gate_log
from .isam2 import isam2_params
from .log import MeasurementLog
from .rebuild import OnlineGuard, rebuild_isam
from .result import LocalizationResult
from .track_init import retry_failed_tracks
from .track_init import triangulate_track as _triangulate
from .view_gate import drop_landmarks_at_cameras as _drop_landmarks_at_cameras
from .view_gate import gated_refinement, view_gate_px

__all__ = ["LocalizeParams", "localize"]


@dataclass(frozen=True)
class LocalizeParams:
    """Estimator settings. Noise levels default to those stated in the log's sensor models."""

    gps_model: Literal["bias", "white"] = "bias"  # "white": the negative control
    use_landmarks: bool = True
    use_tilt: bool = True  # attitude factors from the log's gravity direction, when it has one
    # Odometry drift as states D(k) = (scale error, heading rate in rad / m), a slow random
    # walk from a prior set by the odometry model's drift sigmas (factors.drift_odometry_factor).
    # Off, the drift is folded into the white per-step noise: optimistic over long spans (a
    # 1 % scale error is coherent along a whole leg). Measured (benchmarks/localization.py,
    # 5 seeds, 620 m traverse): biased GPS 2.70 -> 1.80 m horizontal RMSE, landmark NEES
    # 6.7 -> 3.5; white GPS 0.52 -> 0.25 m, NEES 9.9 -> 3.0.
    odometry_drift: bool = True
    drift_walk_per_km: float = 0.1  # random-walk 1-sigma over 1 km, in prior sigmas
    huber_k: float = 1.345  # Huber threshold on whitened reprojection error (sigmas)
    min_views: int = 3  # views before a track may be triangulated
    # widest angle between two viewing rays (deg). 1 deg, not 3: the extra tracks (+6 % landmarks)
    # hold the heading between frames better; biased10 posterior bound 1.252x -> 1.237x the floor
    # (10 seeds), landmark NEES unchanged (benchmarks/localization.py; docs/localization.md)
    min_parallax_deg: float = 1.0
    min_depth_m: float = 0.5  # in front of every camera, within the range limit
    max_reprojection_px: float = 4.0  # gate on the triangulated point's worst residual
    # optional weak prior at the triangulated point (m); off by default: summed over
    # thousands of landmarks even sigma = 10 m anchors the map to the online estimate
    landmark_prior_sigma_m: float | None = None
    attitude_prior_deg: tuple[float, float, float] = (5.0, 5.0, 5.0)  # roll, pitch, yaw at k=0
    align_distance_m: float = 40.0  # path used to align dead reckoning to GPS at start
    # relinearize a variable when its tangent delta exceeds: pose (rot rad x3, trans m x3),
    # GPS bias (m), landmark (m); translations barely change the Jacobians, rotations do
    relinearize_pose: tuple[float, ...] = (0.05, 0.05, 0.05, 2.0, 2.0, 2.0)
    relinearize_bias_m: float = 2.0
    relinearize_landmark_m: float = 0.5
    relinearize_drift: tuple[float, float] = (0.005, 1e-4)  # scale, heading rate (rad / m)
    relinearize_skip: int = 10
    # Online relinearization (fluid, thresholds above). Off by default: on a full lawnmower the
    # GPS keeps shifting the whole trajectory, relinearization then re-eliminates most of the
    # tree (step times grew to seconds). The online pass then stays linear at the insertion
    # points and the batch refinement (factorgraph.refine) takes the final estimate to the MAP.
    relinearize: bool = False
    # iSAM2's wildfire threshold (tangent units, rad or m) for the back-substitution that
    # reads the newest pose each step: 0.1, not GTSAM's 1e-3, which took 22 of the default
    # run's 45 s localize; the poses read are exact at any threshold (factorgraph/isam2.py)
    wildfire_threshold: float = 0.1
    refine: bool = True  # staged batch refinement after the last keyframe
    # triangulate the tracks that failed the gates online again at the refined poses
    # (factorgraph/track_init.py; measured in docs/vision.md)
    retry_failed_tracks: bool = True
    # Wrong associations: cut the views whose reprojection error at the refined estimate
    # fails a chi2(2) test against the pixel sigma and refine again without them, at most
    # this many gate passes (0: off); the test's false-alarm probability per correct view
    # (1e-6: 5.26 sigma; ~0.03 of the default run's 30,000 correct views)
    # (factorgraph/view_gate.py; measured in docs/vision.md, "Wrong matches")
    view_gate_rounds: int = 3
    view_gate_false_alarm: float = 1e-6
    refine_max_iterations: int = 20  # Levenberg-Marquardt steps (each stage)
    refine_rtol: float = 1e-4  # stop when a step lowers the graph error by less (relative)

    def __post_init__(self) -> None:
        if self.gps_model not in ("bias", "white"):
            raise bad_input("params.gps_model", self.gps_model, "'bias' or 'white'", "")
        if int(self.view_gate_rounds) < 0:
            raise bad_input("params.view_gate_rounds", self.view_gate_rounds, "an integer >= 0", "")
        if not 0 < self.view_gate_false_alarm < 1:
            raise bad_input(
                "params.view_gate_false_alarm", self.view_gate_false_alarm, "a value in (0, 1)", ""
            )
        if int(self.min_views) < 2:
            raise bad_input("params.min_views", self.min_views, "an integer >= 2", "")
        if not self.wildfire_threshold >= 0:
            raise bad_input(
                "params.wildfire_threshold",
                self.wildfire_threshold,
                "a value >= 0 (tangent units, rad or m)",
                "0 re-solves the whole tree every step (GTSAM exact); the default is 0.1",
            )
        for name in ("huber_k", "min_parallax_deg", "max_reprojection_px", "drift_walk_per_km"):
            if not getattr(self, name) > 0:
                raise bad_input(f"params.{name}", getattr(self, name), "a value > 0", "")


def _keys():
    import gtsam

    return gtsam.symbol_shorthand.X, gtsam.symbol_shorthand.B, gtsam.symbol_shorthand.L


def _pose(rotvec_t: np.ndarray):
    import gtsam

    return gtsam.Pose3(gtsam.Rot3.Expmap(rotvec_t[:3]), rotvec_t[3:])


def _initial_pose(log: MeasurementLog, params: LocalizeParams):
    """World pose of keyframe 0 from a 2-D Procrustes fit of dead reckoning to GPS.

    The GPS bias is nearly constant over the first tens of metres, so it cancels in the
    heading and leaves the white noise averaged over the fixes used.
    """
    import gtsam

    dr = [gtsam.Pose3()]
    for row in log.odometry:
        dr.append(dr[-1].compose(_pose(row)))
    p = np.array([q.translation() for q in dr])
    travelled = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
    use = log.gps_k[
        travelled[log.gps_k] <= max(params.align_distance_m, travelled[log.gps_k[:2]].max())
    ]
    if use.size < 2:
        use = log.gps_k[:2]
    if use.size < 2:
        raise bad_input("gps", log.gps_k.size, "at least 2 GPS fixes", "log GPS")
    src = p[use, :2] - p[use, :2].mean(0)
    dst = log.gps_xyz[np.searchsorted(log.gps_k, use), :2]
    dst_c = dst - dst.mean(0)
    h = (src * dst_c).sum()
    cross = (src[:, 0] * dst_c[:, 1] - src[:, 1] * dst_c[:, 0]).sum()
    yaw = math.atan2(cross, h) if np.ptp(src, axis=0).max() > 1.0 else 0.0
    Rz = np.array([[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]])
    t_xy = dst.mean(0) - Rz @ p[use, :2].mean(0)
    t_z = float(np.mean(log.gps_xyz[np.searchsorted(log.gps_k, use), 2] - p[use, 2]))
    return gtsam.Pose3(gtsam.Rot3.Yaw(yaw), np.array([t_xy[0], t_xy[1], t_z]))


def _odometry_sigmas(log: MeasurementLog, step: np.ndarray, fold_drift: bool) -> np.ndarray:
    """Between-factor 1-sigmas (6,) for one odometry step: the white noise, and with
    ``fold_drift`` the per-traverse scale and heading drift folded in as if white (what the
    estimator does without drift states: optimistic over spans of many steps)."""
    od = log.sensors.odometry
    d = float(np.linalg.norm(step[3:]))
    rot = math.radians(od.sigma_rotation_deg)
    yaw, frac = rot, od.sigma_translation_frac
    if fold_drift:
        yaw = math.hypot(rot, math.radians(od.heading_drift_sigma_deg_per_m) * d)
        frac = math.hypot(frac, od.scale_error_sigma)
    trans = max(d * frac, 1e-3)
    return np.array([rot, rot, yaw, trans, trans, trans])


def _drift_sigmas(log: MeasurementLog) -> np.ndarray:
    """Prior 1-sigmas (2,) of the drift state: scale error (fraction), heading rate (rad / m)."""
    od = log.sensors.odometry
    sig = np.array([od.scale_error_sigma, math.radians(od.heading_drift_sigma_deg_per_m)])
    return np.maximum(sig, 1e-7)  # a drift-free odometer: the state is pinned at zero


@dataclass
class _Tracks:
    """Feature tracks waiting for enough parallax, and what became of each."""

    pending: dict[int, list[tuple[int, np.ndarray]]] = field(default_factory=dict)
    last_try: dict[int, str] = field(default_factory=dict)
    active: set[int] = field(default_factory=set)
    banned: set[int] = field(default_factory=set)
    dropped: Counter = field(default_factory=Counter)
    first_k: dict[int, int] = field(default_factory=dict)
    init_distance: dict[int, float] = field(default_factory=dict)
    # tracks with >= min_views views that failed the gates online: views and reasons (a
    # simulated landmark seen again on a later swath fails or succeeds once per segment)
    failed: dict[int, list[tuple[int, np.ndarray]]] = field(default_factory=dict)
    failed_reason: dict[int, list[str]] = field(default_factory=dict)

    def drop(self, lid: int) -> None:
        """Count pending track ``lid`` as never initialised; keep it for a retry when it
        failed a gate (track_init.retry_failed_tracks)."""
        why = self.last_try.pop(lid, "too_few_views")
        self.dropped[why] += 1
        if why != "too_few_views":
            self.failed.setdefault(lid, []).extend(self.pending[lid])
            self.failed_reason.setdefault(lid, []).append(why)
        del self.pending[lid]


def localize(
    log: MeasurementLog,
    params: LocalizeParams | None = None,
    progress: Callable[[int, int], None] | None = None,
    control: ControlPoints | None = None,
) -> LocalizationResult:
    """Fuse the log in iSAM2 and return poses, landmarks and their final marginals.

    Parameters
    ----------
    log : MeasurementLog
        Keyframes, odometry, GPS and feature tracks (see :mod:`factorgraph.log`).
    params : LocalizeParams, optional
        Estimator settings; noise levels come from ``log.sensors``.
    progress : callable, optional
        Called as ``progress(k + 1, K)`` after each keyframe (for a progress bar).
    control : ControlPoints, optional
        Ground control (any CRS): stops named in the log's ``control_id`` and marked targets
        enter the graph after the online pass (:mod:`factorgraph.control`); the result's
        ``control`` states which points were used and their residuals.

    Returns
    -------
    LocalizationResult
        Final (smoothed) and online poses, landmarks with full 3x3 marginal covariances at the
        final estimate, the shared GPS-offset covariance, per-step timings and drop counts.
        ``refine["isam2_recovery"]`` (with the refinement on) counts what kept the online
        pass alive by kind (:class:`factorgraph.rebuild.OnlineGuard`): views deferred to the
        batch refinement, landmarks postponed, rebuilds and the landmarks they dropped.
        ``refine["view_gate"]`` (with the refinement on and ``view_gate_rounds`` > 0) counts
        the views that failed the chi2 gate at the refined estimate and the
        landmarks removed with them (:func:`factorgraph.view_gate.gated_refinement`; those
        landmarks count as ``gate_after_refine`` in ``dropped``).
    """
    import gtsam

    from .marginals import landmark_marginals
    from .refine import refine_estimate

    params = params or LocalizeParams()
    if not isinstance(log, MeasurementLog):
        raise bad_input("log", type(log).__name__, "a MeasurementLog", "use read_log()")
    log = gate_log(log)  # gross GPS outliers out, counted in log.ingest (field/gate.py)
    ctrl_plan = plan_control(log, control) if control is not None else None  # fail fast
    X, B, L = _keys()
    Dk = gtsam.symbol_shorthand.D
    drift_model = params.odometry_drift
    drift_sigma = _drift_sigmas(log)
    gps = log.sensors.gps
    camera = log.sensors.camera
    K = camera.calibration()
    bTc = gtsam.Pose3(camera.body_T_camera())
    pix_noise = gtsam.noiseModel.Robust.Create(
        gtsam.noiseModel.mEstimator.Huber.Create(params.huber_k),
        gtsam.noiseModel.Isotropic.Sigma(2, camera.pixel_sigma_px),
    )
    lm_prior = None
    if params.landmark_prior_sigma_m:
        lm_prior = gtsam.noiseModel.Isotropic.Sigma(3, params.landmark_prior_sigma_m)
    tilt, tilt_noise, world_up = log.tilt_up, None, gtsam.Unit3(np.array([0.0, 0.0, 1.0]))
    if params.use_tilt and tilt is not None:
        sigma = math.radians(log.sensors.tilt.sigma_deg)
        tilt_noise = gtsam.noiseModel.Isotropic.Sigma(2, sigma)
    isam_params = isam2_params(params)
    isam = gtsam.ISAM2(isam_params)
    history = gtsam.NonlinearFactorGraph()  # every factor added so far (for a rebuild)
    guard = OnlineGuard(bTc, params.min_depth_m)  # views unsafe to linearize online (rebuild.py)

    gps_row = {int(k): i for i, k in enumerate(log.gps_k)}
    order = np.argsort(log.obs_k, kind="stable")
    bounds = np.searchsorted(log.obs_k[order], np.arange(log.n_keyframes + 1))
    white = np.array(gps.sigma_white_m)
    bias_model = params.gps_model == "bias"
    tracks = _Tracks()
    poses: dict[int, Any] = {}
    fresh: dict[int, int] = {}
    bias_prev, drift_prev = np.zeros(3), np.zeros(2)
    step_s = np.zeros(log.n_keyframes)
    online = np.zeros((log.n_keyframes, 3))

    for k in range(log.n_keyframes):
        t0 = time.perf_counter()
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        lm_graph, lm_values, new_lids = gtsam.NonlinearFactorGraph(), gtsam.Values(), []
        if k == 0:
            guess = _initial_pose(log, params)
            att = np.radians(params.attitude_prior_deg)
            prior = gtsam.noiseModel.Diagonal.Sigmas(
                np.r_[att, 30.0, 30.0, 30.0]
            )  # weak: GPS fixes position
            graph.add(gtsam.PriorFactorPose3(X(0), guess, prior))
            if drift_model:
                noise = gtsam.noiseModel.Diagonal.Sigmas(drift_sigma)
                graph.add(gtsam.PriorFactorPoint2(Dk(0), np.zeros(2), noise))
                values.insert(Dk(0), np.zeros(2))
        else:
            step = log.odometry[k - 1]
            meas = _pose(step)
            sig = _odometry_sigmas(log, step, fold_drift=not drift_model)
            if drift_model:  # D(k) = D(k-1) + slow random walk; corrects this step
                d_km = max(float(np.linalg.norm(step[3:])), 0.01) / 1000.0
                walk = drift_sigma * params.drift_walk_per_km * math.sqrt(d_km)
                graph.add(
                    gtsam.BetweenFactorPoint2(
                        Dk(k - 1), Dk(k), np.zeros(2), gtsam.noiseModel.Diagonal.Sigmas(walk)
                    )
                )
                graph.add(drift_odometry_factor(X(k - 1), X(k), Dk(k), step, sig))
                values.insert(Dk(k), drift_prev)
                s, w = drift_prev  # the guess: the step corrected by the current drift
                yaw = gtsam.Rot3.Rz(-w * float(np.linalg.norm(step[3:])))
                meas = gtsam.Pose3(meas.rotation().compose(yaw), step[3:] / (1 + s))
            else:
                noise = gtsam.noiseModel.Diagonal.Sigmas(sig)
                graph.add(gtsam.BetweenFactorPose3(X(k - 1), X(k), meas, noise))
            guess = poses[k - 1].compose(meas)
        values.insert(X(k), guess)
        if bias_model:
            if k == 0:
                prior = gtsam.noiseModel.Diagonal.Sigmas(np.maximum(gps.bias_sigma_m, 1e-6))
                graph.add(gtsam.PriorFactorPoint3(B(0), np.zeros(3), prior))
                values.insert(B(0), np.zeros(3))
            else:
                phi, q = gm_transition(log.t[k] - log.t[k - 1], gps.bias_sigma_m, gps.bias_tau_s)
                graph.add(gauss_markov_factor(B(k - 1), B(k), phi, np.maximum(q, 1e-6)))
                values.insert(B(k), phi * bias_prev)
        if tilt_noise is not None:  # gravity fixes roll and pitch: R_k^T e_z = measured up
            graph.add(gtsam.AttitudeFactorPose3(X(k), world_up, tilt_noise, gtsam.Unit3(tilt[k])))
        if k in gps_row:
            z = log.gps_xyz[gps_row[k]]
            # the fix's own sigma when the log has one (fix quality, DOP, solution sigmas)
            w = white if log.gps_sigma is None else log.gps_sigma[gps_row[k]]
            if bias_model:
                graph.add(biased_gps_factor(X(k), B(k), z, w))
            else:
                graph.add(gtsam.GPSFactor(X(k), z, gtsam.noiseModel.Diagonal.Sigmas(w)))
        poses[k] = guess
        if params.use_landmarks:
            lin = isam.getLinearizationPoint()  # a view into iSAM2's theta, not a copy
            idx = order[bounds[k] : bounds[k + 1]]
            seen_now = set()
            for i in idx:
                lid, uv = int(log.obs_id[i]), log.obs_uv[i]
                seen_now.add(lid)
                if lid in tracks.banned:
                    continue
                if lid in tracks.active:
                    f = gtsam.GenericProjectionFactorCal3_S2(uv, pix_noise, X(k), L(lid), K, bTc)
                    guard.view(f, guess, lin.atPoint3(L(lid)), graph)
                    continue
                tracks.pending.setdefault(lid, []).append((k, uv))
                views = tracks.pending[lid]
                if len(views) < params.min_views:
                    tracks.last_try[lid] = "too_few_views"
                    continue
                for kv, _ in views:  # the cached estimate moves with every GPS fix: refresh
                    if kv < k and fresh.get(kv) != k:
                        poses[kv], fresh[kv] = isam.calculateEstimatePose3(X(kv)), k
                pt, why = _triangulate(views, poses, camera, bTc, K, params)
                if pt is not None and not guard.new_landmark_ok(
                    pt, [guess if kv == k else lin.atPose3(X(kv)) for kv, _ in views]
                ):  # at the poses' linearization points: wait for a view or the retry
                    pt, why = None, "depth_at_linearization_point"
                tracks.last_try[lid] = why
                if pt is None:
                    continue
                lm_values.insert(L(lid), pt)
                new_lids.append(lid)
                if lm_prior is not None:
                    lm_graph.add(gtsam.PriorFactorPoint3(L(lid), pt, lm_prior))
                for kv, uvv in views:
                    lm_graph.add(
                        gtsam.GenericProjectionFactorCal3_S2(uvv, pix_noise, X(kv), L(lid), K, bTc)
                    )
                tracks.active.add(lid)
                tracks.first_k[lid] = views[0][0]
                tracks.init_distance[lid] = float(np.linalg.norm(pt - guess.translation()))
                del tracks.pending[lid], tracks.last_try[lid]
            for lid in [j for j, v in tracks.pending.items() if v[-1][0] < k and j not in seen_now]:
                tracks.drop(lid)
        try:
            step_graph, step_values = gtsam.NonlinearFactorGraph(graph), gtsam.Values(values)
            step_graph.push_back(lm_graph)
            step_values.insert(lm_values)
            isam.update(step_graph, step_values)
            history.push_back(step_graph)
        except RuntimeError as exc:
            # Never let one landmark end the run: drop this step's new landmarks (counted)
            # and rebuild iSAM2 from every other factor at the current linearization point.
            isam, history, lost = rebuild_isam(
                isam, isam_params, history, graph, values, new_lids, k, exc
            )
            guard.counts["rebuilds"] += 1
            guard.counts["rebuild_dropped_landmarks"] += len(lost)
            for lid in lost:
                tracks.active.discard(lid)
                tracks.banned.add(lid)
                tracks.dropped["degenerate_in_graph"] += 1
        poses[k] = isam.calculateEstimatePose3(X(k))
        if bias_model:
            bias_prev = isam.calculateEstimatePoint3(B(k))
        if drift_model:
            drift_prev = isam.calculateEstimatePoint2(Dk(k))
        online[k] = poses[k].translation()
        step_s[k] = time.perf_counter() - t0
        if progress is not None:
            progress(k + 1, log.n_keyframes)
    for lid in list(tracks.last_try):
        tracks.drop(lid)
    if ctrl_plan is not None:
        add_control_factors(ctrl_plan, isam, history, tracks.active)
    estimate = isam.calculateBestEstimate()  # a full back-substitution: no wildfire lag
    graph = history
    graph.push_back(guard.deferred)  # linearized at the refined estimate from here on
    refine_report, retry, gate = None, {}, None
    if params.refine:
        online_estimate = estimate
        estimate, refine_report = refine_estimate(
            graph, estimate, bTc, K, params.refine_max_iterations, params.refine_rtol
        )
        if params.view_gate_rounds:  # wrong associations out (factorgraph/view_gate.py)
            gate_px = view_gate_px(camera.pixel_sigma_px, params.view_gate_false_alarm)
            graph, estimate, refine_report, gate = gated_refinement(
                graph, online_estimate, estimate, refine_report, bTc, K, gate_px, params
            )
            for lid in gate.pop("removed_ids"):  # counted, not listed; not retried
                tracks.active.discard(lid)
                tracks.banned.add(lid)
                tracks.dropped["gate_after_refine"] += 1
        if params.retry_failed_tracks:  # at the refined poses (factorgraph/track_init.py)
            graph, estimate, retry = retry_failed_tracks(
                graph, estimate, tracks, camera, bTc, K, pix_noise, params
            )
    graph = _drop_landmarks_at_cameras(  # the triangulation gate's range, 1.5 x the camera's
        graph, estimate, tracks, bTc, params.min_depth_m, 1.5 * camera.range_max_m
    )
    t0 = time.perf_counter()
    marg = landmark_marginals(
        graph, estimate, log.n_keyframes, sorted(tracks.active), bias_model, drift_model
    )
    marginal_s = time.perf_counter() - t0
    report = {**refine_report.as_dict(), **retry} if refine_report is not None else {}
    if gate is not None:
        report["view_gate"] = gate
    if report:  # views deferred, landmarks postponed, rebuilds (rebuild.py); with refine off
        report["isam2_recovery"] = guard.report()  # only n_rebuilds (result.py has no field)
    result = LocalizationResult.build(
        log=log,
        params=params,
        estimate=estimate,
        graph=graph,
        marginals=marg,
        tracks=tracks,
        online_xyz=online,
        n_rebuilds=guard.counts["rebuilds"],
        step_s=step_s,
        marginal_s=marginal_s,
        refine=report,
    )
    if ctrl_plan is not None:
        result.control = control_report(ctrl_plan, result)
    return result
