"""Camera images to landmarks (issue 18): the renderer and front-end per scene and setting,
then the full chain (images -> tracks -> iSAM2 -> selection -> GP map) against the
ideal-track simulation of the same traverse.

    python benchmarks/vision.py --out benchmarks/results/vision.json          # everything
    python benchmarks/vision.py --cases frontend --keyframes 30              # a subset

Cases
-----
``frontend``
    A straight ``--keyframes``-keyframe traverse (2 m apart, the default scenario's keyframe
    spacing) of ``terrain.synthetic.default_site(2.0)`` with the vision camera preset
    (``factorgraph.vision.VISION_CAMERA``: 1.5 m, 10 deg down, f = 600 px), rendered in each
    scene (sunny snow, sunny dirty ice, overcast snow, low sun), tracked by SIFT, ORB, AKAZE
    and GFTT+KLT with CLAHE on and off (guided by the odometry in every case). Per row:
    features and essential-RANSAC inliers per frame, inlier ratio (inliers / matches),
    observations per keyframe in >= 3-view tracks, mean track length, ground-truth pixel error
    of every observation against its track's surface point (the renderer's ray cast under the
    track's last, nearest view: :func:`factorgraph.vision.track_truth`; median, p95, share
    > 4 px), and ms per frame (render; front-end).
``render``
    The renderer alone on the ``frontend`` traverse: CPU and wall ms per 640 x 480 frame,
    each scene twice (the second pass is the steady state), share of pixels taken from a
    triangle's plane, sha256 of the frames. ``OMP_NUM_THREADS=1 taskset -c 1`` for one core.
``headings``
    Front-end yield heading east, north, south and west (20 keyframes 2 m apart from the
    site centre, sunny snow, SIFT) with ``max_features`` 2000 and 4000.
``scaleD`` (e.g. ``scale1.3``)
    The default survey with ideal tracks at D texture points per m^2 (1.3: ~50,000
    landmarks): wall and CPU time of localize (online pass, refinement, retry, marginals),
    peak RSS before / after the online pass, selection.
``gateN`` (e.g. ``gate4``)
    ``chain_sunny``'s frames (re-rendered when absent) tracked again with the current
    front-end, localizer gate N px; ``--wrong-in-gate`` adds the wrong-match rows (view gate
    off / on) of those tracks: the full-survey wrong-match chain without rendering.
``chain_sunny``
    The default scenario (embedded TOML: 600 m site, 4-swath lawnmower, keyframes every 2 s,
    GPS 0.5 Hz, seed 0) with the vision camera: ideal tracks vs rendered sunny-snow images
    tracked by the default front-end, on the same log (same GPS, odometry, tilt). Also the
    image tracks with 10 % of the tracks given one wrong association (an observation swapped
    with another track's in the same keyframe: the repeated-texture failure), localized with
    the view gate off (``[localize] view_gate_rounds = 0``) and on (the default); those rows
    also count the wrong observations left in the final graph (``--wrong-fracs 0.1 0.2``:
    a row pair per fraction). Per row:
    landmarks in the graph and selected, graph landmarks seen per keyframe, landmark NEES
    (3-D, full marginal) and share within 2 sigma (NEES < chi2(3) 95.45 %), keyframe
    horizontal / vertical RMSE, GPS-only horizontal RMSE, map RMSE and 95 % coverage of the
    satellite-mean GP map (as ``glacimap run``), timings.
``chain_sunny_part``
    ``chain_sunny`` on the part of the site that ``chain_overcast`` uses.
``chain_overcast``
    The same on a 240 m part of the site (``--overcast-bounds``, ``--overcast-swaths`` 2:
    560 m, 281 keyframes), overcast snow, CLAHE off and on.

Timings are wall-clock on a shared 2-core machine (other jobs running): compare rows of one
run, not absolute numbers.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _harness import in_subprocess, paper_prior_map, table, write_json  # noqa: E402

SCENE_NAMES = ("sunny_snow", "sunny_dirty_ice", "overcast_snow", "low_sun")
DETECTORS = ("sift", "orb", "akaze", "klt")


def _track_stats(tracks, err, n_frames) -> dict[str, Any]:
    pf = tracks.per_frame
    e = err[np.isfinite(err) & (err > 0)]
    matches = sum(p["matches"] for p in pf)
    return {
        "features_per_frame": float(np.mean([p["features"] for p in pf])),
        "inliers_per_frame": float(np.mean([p["inliers"] for p in pf[1:]])) if len(pf) > 1 else 0,
        "inlier_ratio": sum(p["inliers"] for p in pf) / matches if matches else 0.0,
        "views_per_keyframe": len(tracks.k) / n_frames,
        "tracks": tracks.n_tracks,
        "track_length": len(tracks.k) / max(tracks.n_tracks, 1),
        "err_median_px": float(np.median(e)) if e.size else None,
        "err_p95_px": float(np.percentile(e, 95)) if e.size else None,
        "err_gt4_frac": float(np.mean(e > 4)) if e.size else None,
        "track_ms": float(np.mean([p["ms"] for p in pf])),
        "counts": dict(tracks.counts),
    }


def case_frontend(n_keyframes: int, seed: int) -> dict[str, Any]:
    from factorgraph import SensorSuite, simulate_traverse
    from factorgraph.vision import (
        SCENES,
        TrackParams,
        render_frames,
        track_features,
        track_truth,
        vision_sensors,
    )
    from terrain.synthetic import default_site

    dem = default_site(2.0)
    x, y = dem.x.values, dem.y.values
    wp = np.array([[x[40], y[150]], [x[40] + 2.0 * n_keyframes, y[150] + 4.0]])
    sensors = vision_sensors(SensorSuite(keyframe_dt_s=2.0))
    log = simulate_traverse(dem, wp, sensors, seed=seed)
    rows = []
    for name in SCENE_NAMES:
        t0 = time.perf_counter()
        ren, it = render_frames(log, dem, SCENES[name], seed=seed)
        frames = list(it)
        render_ms = 1e3 * (time.perf_counter() - t0) / len(frames)
        for det in DETECTORS:
            for clahe in (False, True):
                tr = track_features(
                    frames, sensors.camera, TrackParams(detector=det, clahe=clahe), log.odometry
                )
                _, err = track_truth(ren, tr, ren.poses)
                row = {"scene": name, "detector": det, "clahe": clahe, "render_ms": render_ms}
                row.update(_track_stats(tr, err, len(frames)))
                rows.append(row)
                print(name, det, clahe, {k: row[k] for k in list(row)[4:13]}, flush=True)
    return {"rows": rows, "keyframes": len(log.t), "seed": seed}


def case_render(n_keyframes: int, seed: int) -> dict[str, Any]:
    """CPU time per frame of the renderer alone on the ``frontend`` traverse, each scene twice
    (the first pass warms the process up; the first frame of every pass, which builds the
    BVH, is left out), the sha256 of the frames and the share of pixels whose distance came
    from a triangle's plane (``Renderer.cast_counts``). Pin one core for the "one core"
    figure: ``OMP_NUM_THREADS=1 taskset -c 1 python benchmarks/vision.py --cases render``."""
    import hashlib

    import cv2

    from factorgraph import SensorSuite, simulate_traverse
    from factorgraph.vision import SCENES, render_frames, vision_sensors
    from terrain.synthetic import default_site

    cv2.setNumThreads(1)
    dem = default_site(2.0)
    x, y = dem.x.values, dem.y.values
    wp = np.array([[x[40], y[150]], [x[40] + 2.0 * n_keyframes, y[150] + 4.0]])
    sensors = vision_sensors(SensorSuite(keyframe_dt_s=2.0))
    log = simulate_traverse(dem, wp, sensors, seed=seed)
    rows = []
    for name in [n for n in SCENE_NAMES for _ in (0, 1)]:
        ren, it = render_frames(log, dem, SCENES[name], seed=seed)
        h, cpu, wall = hashlib.sha256(), 0.0, 0.0
        for k, img in it:
            h.update(img.tobytes())
            if k == 0:
                c0, w0 = time.process_time(), time.perf_counter()
        cpu, wall = time.process_time() - c0, time.perf_counter() - w0
        n = log.n_keyframes - 1
        cc = ren.cast_counts
        rows.append(
            {
                "scene": name,
                "cpu_ms": 1e3 * cpu / n,
                "wall_ms": 1e3 * wall / n,
                "plane_share": cc["plane"] / (cc["plane"] + cc["cast"]),
                "sha256": h.hexdigest()[:16],
            }
        )
        print(rows[-1], flush=True)
    return {"rows": rows, "keyframes": log.n_keyframes, "seed": seed}


def case_headings(n_keyframes: int, seed: int) -> dict[str, Any]:
    """Front-end yield by heading: ``n_keyframes`` keyframes 2 m apart from the site centre
    heading east, north, south and west (sunny snow, SIFT), with ``max_features`` 2000 (the
    old default) and 4000 (the default)."""
    from factorgraph import SensorSuite, simulate_traverse
    from factorgraph.vision import (
        SCENES,
        TrackParams,
        render_frames,
        track_features,
        track_truth,
        vision_sensors,
    )
    from terrain.synthetic import default_site

    dem = default_site(2.0)
    x0, y0 = dem.x.values[150], dem.y.values[150]
    sensors = vision_sensors(SensorSuite(keyframe_dt_s=2.0))
    rows = []
    for name, d in (("east", (1, 0)), ("north", (0, 1)), ("south", (0, -1)), ("west", (-1, 0))):
        end = [x0 + 2.0 * n_keyframes * d[0] + 0.01, y0 + 2.0 * n_keyframes * d[1] + 0.01]
        log = simulate_traverse(dem, np.array([[x0, y0], end]), sensors, seed=seed)
        ren, it = render_frames(log, dem, SCENES["sunny_snow"], seed=seed)
        frames = list(it)
        for max_features in (2000, 4000):
            params = TrackParams(max_features=max_features)
            tr = track_features(frames, sensors.camera, params, log.odometry)
            _, err = track_truth(ren, tr, ren.poses)
            row = {"heading": name, "max_features": max_features}
            row.update(_track_stats(tr, err, len(frames)))
            rows.append(row)
            print(name, max_features, {k: row[k] for k in list(row)[2:10]}, flush=True)
    return {"rows": rows, "keyframes": n_keyframes, "seed": seed}


def _map_metrics(sel, truth, scenario) -> dict[str, float]:
    """The satellite-mean GP map of ``glacimap run`` (toolkit.pipeline) and its metrics."""
    from terrain import Grid, evaluate

    ds = paper_prior_map(sel, truth, scenario)  # the pipeline's GP map, 8 x 8 prior
    grid = Grid.from_dataarray(ds)
    t = truth.interp(x=grid.x, y=grid.y, method="linear").values
    m = evaluate(ds["elevation"].values, t, ds["elevation_std"].values)
    return {"map_rmse_m": m["rmse"], "map_coverage_95": m["coverage_95"]}


def _chain_row(name, log, truth, scenario, wrong_rows=None) -> dict[str, Any]:
    """One chain row; ``wrong_rows`` (observation rows of ``log`` given a wrong association)
    adds how many of them are projection factors of the final graph and the reprojection
    errors of wrong and correct views there (:func:`_wrong_views`)."""
    from scipy.stats import chi2

    from factorgraph import gps_only, horizontal_rmse
    from toolkit.pipeline import localization_summary, localize_log, select_samples

    t0 = time.perf_counter()
    loc = localize_log(log, scenario)
    loc_s = time.perf_counter() - t0
    sel = select_samples(loc, scenario)
    s = localization_summary(loc, sel)
    e = loc.landmark_xyz - loc.true_landmarks()
    known = np.isfinite(e).all(axis=1)  # tracks whose reference ray met the sky: no truth
    e = e[known]
    cov, cov_rel = loc.landmark_cov[known], loc.landmark_cov_relative[known]
    nees = np.einsum("ni,ni->n", e, np.linalg.solve(cov, e[..., None])[..., 0])
    # decomposition (docs/vision.md, "Landmark NEES"): the shared offset (the mean keyframe
    # error, one 3-dof draw per run) and the relative part, each against its covariance
    delta = (loc.keyframe_xyz - log.truth["xyz"]).mean(0)
    er = e - delta
    rel = np.linalg.solve(cov_rel, er[..., None])[..., 0]
    in_graph = set(loc.landmark_id.tolist())
    per_k = np.bincount(log.obs_k[np.isin(log.obs_id, list(in_graph))], minlength=log.n_keyframes)
    row = {
        "case": name,
        "keyframes": log.n_keyframes,
        "landmarks_in_graph": loc.n_landmarks,
        "landmarks_selected": int(sel.counts["kept"]),
        "graph_landmarks_per_keyframe": float(per_k.mean()),
        "graph_landmarks_per_keyframe_p10": float(np.percentile(per_k, 10)),
        "landmark_nees": float(nees.mean()),
        "landmark_in_2sigma": float(np.mean(nees < chi2.ppf(0.9545, 3))),
        "landmarks_without_truth": int((~known).sum()),
        "shared_offset_chi2": float(delta @ np.linalg.solve(loc.shared_offset_cov, delta)),
        "relative_nees": float(np.einsum("ni,ni->n", er, rel).mean()),
        "retry_recovered": int(loc.refine.get("retry_recovered", 0)),
        "landmark_rmse_3d_m": float(np.sqrt((e**2).sum(1).mean())),
        "horizontal_rmse_m": s["horizontal_rmse_m"],
        "online_horizontal_rmse_m": float(
            np.sqrt(((loc.online_xyz - log.truth["xyz"])[:, :2] ** 2).sum(1).mean())
        ),
        "vertical_rmse_m": s["vertical_rmse_m"],
        "gps_only_horizontal_rmse_m": horizontal_rmse(gps_only(log).xyz, log.truth["xyz"]),
        "localize_s": loc_s,
        "marginals_s": s["marginals_s"],
        "never_initialised": dict(loc.dropped),
        # wrong associations cut at the refined estimate (factorgraph/view_gate.py)
        "view_gate": dict(loc.refine.get("view_gate", {})),
    }
    if wrong_rows is not None:
        row.update(_wrong_views(loc, log, wrong_rows))
    t0 = time.perf_counter()
    row.update(_map_metrics(sel, truth, scenario))
    row["reconstruct_s"] = time.perf_counter() - t0
    print({k: v for k, v in row.items() if k != "never_initialised"}, flush=True)
    return row


def _wrong_views(loc, log, rows) -> dict[str, Any]:
    """Which of the observation ``rows`` of ``log`` (the wrong associations) are projection
    factors of the result's final graph, and the reprojection error (px) at the final
    estimate of those and of the other (correct) views: median / p90 / p99."""
    import gtsam

    from factorgraph.view_gate import camera_poses, projection_views, view_residuals_px

    v = projection_views(loc.graph)
    k = np.array([gtsam.Symbol(int(x)).index() for x in v["pose"]], dtype=np.int64)
    index = {
        (int(a), int(b)): i for i, (a, b) in enumerate(zip(log.obs_k, log.obs_id, strict=True))
    }
    in_graph = np.array([index[(int(a), int(b))] for a, b in zip(k, v["lid"], strict=True)])
    wrong = np.isin(in_graph, rows)
    cam = log.sensors.camera
    R, c = camera_poses(loc.estimate, v["pose"], gtsam.Pose3(cam.body_T_camera()))
    pts = np.array([loc.estimate.atPoint3(int(key)) for key in v["landmark"]]).reshape(-1, 3)
    err = view_residuals_px(R, c, pts, v["uv"], cam.calibration().K())

    def q(e):
        return [float(x) for x in np.percentile(e, [50, 90, 99])] if e.size else None

    return {
        "wrong_views_in_graph": int(wrong.sum()),
        "wrong_view_px_p50_p90_p99": q(err[wrong]),
        "correct_view_px_p50_p90_p99": q(err[~wrong]),
    }


def _wrong_matches(tracks, frac: float, rng):
    """``tracks`` with ``frac`` of the tracks given one wrong association: an interior
    observation exchanged with another track's observation in the same keyframe. Returns
    the tracks, the number of tracks given a wrong view and the observation rows changed."""
    k, lid, uv = tracks.k.copy(), tracks.landmark_id.copy(), tracks.uv.copy()
    ids = np.unique(lid)
    hit = rng.choice(ids, int(frac * ids.size), replace=False)
    swapped = 0
    for t in hit:
        rows = np.flatnonzero(lid == t)
        if rows.size < 3:
            continue
        r = rows[rng.integers(1, rows.size - 1)] if rows.size > 2 else rows[0]
        others = np.flatnonzero((k == k[r]) & (lid != t))
        if others.size == 0:
            continue
        o = rng.choice(others)
        uv[[r, o]] = uv[[o, r]]
        swapped += 1
    # rows whose pixel changed (a row swapped twice can come back to its own value)
    rows_changed = np.flatnonzero(np.any(uv != tracks.uv, axis=1))
    return dataclasses.replace(tracks, uv=uv), swapped, rows_changed


def _wrong_match_rows(label, tracks, img_log, truth, scenario, fracs, seed) -> list[dict]:
    """Chain rows of ``img_log`` (the log of ``tracks``) with ``frac`` of the tracks given
    one wrong association, for each of ``fracs``: localized without the view gate (the
    localizer before it) and with it (the default)."""
    from factorgraph.vision import attach_tracks

    full = np.full((tracks.n_tracks, 3), np.nan)
    full[img_log.truth["landmark_id"]] = img_log.truth["landmark_xyz"]
    off = {**scenario, "localize": {**scenario["localize"], "view_gate_rounds": 0}}
    rows = []
    for frac in fracs:
        bad, n, changed = _wrong_matches(tracks, frac, np.random.default_rng(seed))
        wrong_log = attach_tracks(img_log, bad, full)
        what = "wrong matches" if frac == 0.10 else f"{100 * frac:g} % wrong matches"
        for gate, scen in (("view gate off", off), ("view gate", scenario)):
            r = _chain_row(f"{label} SIFT + {what}, {gate}", wrong_log, truth, scen, changed)
            r["wrong_fraction"] = frac
            r["tracks_with_wrong_match"] = n
            r["wrong_observations"] = int(changed.size)
            rows.append(r)
    return rows


def case_chain(
    scene: str,
    swaths: int,
    clahe_both: bool,
    bounds=None,
    seed: int = 0,
    wrong_fracs: tuple[float, ...] = (0.10,),
) -> dict[str, Any]:
    from factorgraph import SensorSuite
    from factorgraph.vision import (
        SCENES,
        TrackParams,
        attach_tracks,
        simulate_images,
        track_features,
        track_truth,
        vision_sensors,
    )
    from toolkit.config import load_scenario
    from toolkit.pipeline import make_plan, make_truth

    over: dict[str, Any] = {"plan": {"n_swaths": swaths}, "seed": seed}
    if bounds is not None:  # a part of the default site (plan and map inside it)
        over["site"] = {"bounds": [float(v) for v in bounds]}
    scenario = load_scenario(None, over)
    truth = make_truth(scenario)
    plan = make_plan(scenario, truth)
    sensors = vision_sensors(SensorSuite.from_dict(scenario["sensors"]))
    seed = int(scenario["seed"])
    t0 = time.perf_counter()
    params = TrackParams(clahe=False)
    suffix = f"_s{seed}" if seed else ""
    frames_dir = Path("out/bench_vision_frames") / f"{scene}_{swaths}{suffix}"
    run = simulate_images(truth, plan, sensors, seed, SCENES[scene], params, frames_dir)
    chain_s = time.perf_counter() - t0
    rows = [_chain_row("ideal tracks", run.ideal, truth, scenario)]
    row = _chain_row(f"{scene} SIFT", run.log, truth, scenario)
    row.update(run.timings)
    e = run.reprojection_px[np.isfinite(run.reprojection_px) & (run.reprojection_px > 0)]
    row["err_median_px"], row["err_p95_px"] = float(np.median(e)), float(np.percentile(e, 95))
    row["render_track_s"] = chain_s
    rows.append(row)
    if not clahe_both:
        rows += _wrong_match_rows(scene, run.tracks, run.log, truth, scenario, wrong_fracs, seed)
    else:
        from factorgraph.vision import read_frames

        folder = read_frames(frames_dir, run.log.t, sensors.camera)
        tr = track_features(folder, sensors.camera, TrackParams(clahe=True), run.log.odometry)
        xyz, err = track_truth(run.renderer, tr, run.renderer.poses)
        r = _chain_row(f"{scene} SIFT CLAHE", attach_tracks(run.log, tr, xyz), truth, scenario)
        e = err[np.isfinite(err) & (err > 0)]
        r["err_median_px"], r["err_p95_px"] = float(np.median(e)), float(np.percentile(e, 95))
        rows.append(r)
    return {
        "rows": rows,
        "swaths": swaths,
        "bounds": scenario["site"]["bounds"],
        "scene": scene,
        "seed": seed,
        "sensors": sensors.to_dict(),
    }


def case_gate(gate_px: float, wrong_fracs: tuple[float, ...] = ()) -> dict[str, Any]:
    """``chain_sunny`` with the localizer's triangulation gate at ``gate_px``: the frames
    ``chain_sunny`` wrote are tracked again (rendered first when absent); with
    ``wrong_fracs`` also the wrong-match rows (view gate off / on) of those tracks."""
    from factorgraph import SensorSuite, simulate_traverse
    from factorgraph.vision import (
        SCENES,
        attach_tracks,
        read_frames,
        render_frames,
        track_features,
        track_truth,
        vision_sensors,
    )
    from toolkit.config import load_scenario
    from toolkit.pipeline import make_plan, make_truth

    scenario = load_scenario(None, {"localize": {"max_reprojection_px": gate_px}})
    truth = make_truth(scenario)
    plan = make_plan(scenario, truth)
    sensors = vision_sensors(SensorSuite.from_dict(scenario["sensors"]))
    seed = int(scenario["seed"])
    log = simulate_traverse(truth, plan, sensors, seed=seed)
    frames_dir = Path("out/bench_vision_frames/sunny_snow_4")
    ren, frames = render_frames(log, truth, SCENES["sunny_snow"], seed=seed)
    if not (frames_dir / "timestamps.csv").is_file():
        from factorgraph.vision import write_frames

        for _ in write_frames(frames_dir, frames, log.t):
            pass
    tr = track_features(
        read_frames(frames_dir, log.t, sensors.camera), sensors.camera, odometry=log.odometry
    )
    xyz, _ = track_truth(ren, tr, ren.poses)
    img_log = attach_tracks(log, tr, xyz)
    rows = [
        _chain_row(f"ideal tracks, gate {gate_px:g} px", log, truth, scenario),
        _chain_row(f"sunny_snow SIFT, gate {gate_px:g} px", img_log, truth, scenario),
    ]
    label = f"sunny_snow, gate {gate_px:g} px,"
    rows += _wrong_match_rows(label, tr, img_log, truth, scenario, wrong_fracs, seed)
    return {"rows": rows, "gate_px": gate_px, "seed": seed}


class _RssSampler:
    """Resident set size of this process (MB), sampled every ``every_s`` in a thread; the
    peak before and after a mark (``mark()``)."""

    def __init__(self, every_s: float = 0.2):
        import threading

        self.peaks = [0.0]
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(every_s,), daemon=True)
        self._thread.start()

    @staticmethod
    def rss_mb() -> float:
        text = Path("/proc/self/status").read_text()
        return int(text.split("VmRSS:")[1].split()[0]) / 1024

    def _run(self, every_s: float) -> None:
        while not self._stop.wait(every_s):
            self.peaks[-1] = max(self.peaks[-1], self.rss_mb())

    def mark(self) -> None:
        self.peaks.append(self.rss_mb())

    def stop(self) -> list[float]:
        self._stop.set()
        self._thread.join()
        self.peaks[-1] = max(self.peaks[-1], self.rss_mb())
        return self.peaks


def case_scale(density: float, seed: int, swaths: int = 4) -> dict[str, Any]:
    """The default survey (``swaths`` lawnmower, vision camera) with ideal tracks at
    ``density`` texture points per m^2 (1.5: ~50,000 landmarks in the graph): wall time and
    peak RSS of localize (online pass, refinement, retry, marginals) and the selection."""
    from scipy.stats import chi2

    from factorgraph import SensorSuite, localize, simulate_traverse
    from factorgraph.localize import LocalizeParams
    from toolkit.config import load_scenario
    from toolkit.pipeline import make_plan, make_truth, select_samples

    over = {"seed": seed, "plan": {"n_swaths": swaths}}
    over["sensors"] = {"camera": {"texture_density_per_m2": density}}
    scenario = load_scenario(None, over)
    truth = make_truth(scenario)
    plan = make_plan(scenario, truth)
    from factorgraph.vision import vision_sensors

    sensors = vision_sensors(SensorSuite.from_dict(scenario["sensors"]))
    rss = _RssSampler()
    t0 = time.perf_counter()
    log = simulate_traverse(truth, plan, sensors, seed=seed)
    sim_s = time.perf_counter() - t0
    rss.mark()
    t_online = [0.0]

    def progress(k: int, n: int) -> None:
        if k == n:
            t_online[0] = time.perf_counter()
            rss.mark()

    t0, c0 = time.perf_counter(), time.process_time()
    loc = localize(log, LocalizeParams(**scenario["localize"]), progress=progress)
    loc_s, loc_cpu_s = time.perf_counter() - t0, time.process_time() - c0
    after_s = time.perf_counter() - t_online[0]
    rss.mark()
    t1 = time.perf_counter()
    sel = select_samples(loc, scenario)
    sel_s = time.perf_counter() - t1
    peaks = rss.stop()
    e = loc.landmark_xyz - loc.true_landmarks()
    known = np.isfinite(e).all(axis=1)  # ideal tracks: every landmark has its truth
    e, cov = e[known], loc.landmark_cov[known]
    nees = np.einsum("ni,ni->n", e, np.linalg.solve(cov, e[..., None])[..., 0])
    ids, counts = np.unique(log.obs_id, return_counts=True)
    step = np.asarray(loc.step_s)
    row = {
        "case": f"density {density:g} / m^2, seed {seed}",
        "density_per_m2": density,
        "keyframes": log.n_keyframes,
        "observations": int(log.obs_id.size),
        "tracks": int(ids.size),
        "tracks_ge3_views": int((counts >= 3).sum()),
        "landmarks_in_graph": loc.n_landmarks,
        "landmarks_selected": int(sel.counts["kept"]),
        "never_initialised": dict(loc.dropped),
        "landmark_nees": float(nees.mean()),
        "landmark_in_2sigma": float(np.mean(nees < chi2.ppf(0.9545, 3))),
        "landmarks_without_truth": int((~known).sum()),
        "simulate_s": sim_s,
        "localize_s": loc_s,
        "localize_cpu_s": loc_cpu_s,  # CPU time of the process (all threads): load-independent
        "online_s": float(step.sum()),
        "online_step_p50_s": float(np.median(step)),
        "online_step_max_s": float(step.max()),
        "online_last100_s": float(step[-100:].sum()),
        "rebuilds": int(loc.n_rebuilds),
        # what kept the online pass alive, by kind (factorgraph/rebuild.py: OnlineGuard)
        "isam2_recovery": dict(loc.refine.get("isam2_recovery", {})),
        "after_online_s": after_s,
        "refine_s": float(loc.refine.get("seconds", 0.0)),
        "retry_s": float(loc.refine.get("retry_seconds", 0.0)),
        "retry_recovered": int(loc.refine.get("retry_recovered", 0)),
        "marginals_s": float(loc.marginal_s),
        "select_s": sel_s,
        "rss_after_simulate_mb": peaks[0],
        "rss_peak_online_mb": peaks[1],
        "rss_peak_refine_marginals_mb": peaks[2],
        "rss_peak_select_mb": peaks[3],
        "bandwidth_keyframes": int(loc.bandwidth),
    }
    print(row, flush=True)
    return {"rows": [row], "seed": seed, "load_at_end": list(__import__("os").getloadavg())}


CHAIN_COLS = [
    ("case", "case", ""),
    ("landmarks_in_graph", "in graph", "d"),
    ("landmarks_selected", "selected", "d"),
    ("graph_landmarks_per_keyframe", "lm/kf", ".1f"),
    ("landmark_nees", "NEES", ".2f"),
    ("landmark_in_2sigma", "in 2sig", ".2f"),
    ("horizontal_rmse_m", "horiz m", ".2f"),
    ("online_horizontal_rmse_m", "online h m", ".2f"),
    ("vertical_rmse_m", "vert m", ".2f"),
    ("gps_only_horizontal_rmse_m", "GPS-only m", ".2f"),
    ("map_rmse_m", "map RMSE", ".3f"),
    ("map_coverage_95", "cov95", ".3f"),
]


SCALE_COLS = [
    ("case", "case", ""),
    ("landmarks_in_graph", "in graph", "d"),
    ("observations", "obs", "d"),
    ("localize_s", "localize s", ".0f"),
    ("localize_cpu_s", "CPU s", ".0f"),
    ("online_s", "online s", ".0f"),
    ("refine_s", "refine s", ".0f"),
    ("retry_s", "retry s", ".0f"),
    ("marginals_s", "marg s", ".0f"),
    ("rss_peak_online_mb", "RSS online", ".0f"),
    ("rss_peak_refine_marginals_mb", "RSS after", ".0f"),
    ("landmark_nees", "NEES", ".2f"),
]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument(
        "--cases",
        nargs="+",
        default=["frontend", "chain_sunny", "chain_sunny_part", "chain_overcast"],
    )
    ap.add_argument("--keyframes", type=int, default=30)
    ap.add_argument("--overcast-swaths", type=int, default=2)
    ap.add_argument(
        "--overcast-bounds",
        type=float,
        nargs=4,
        default=[526000.0, 6475000.0, 526240.0, 6475240.0],
        help="chain_overcast runs on this part of the default site (west south east north)",
    )
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--wrong-fracs",
        type=float,
        nargs="+",
        default=[0.10],
        help="chain cases: fractions of the tracks given one wrong association (one row "
        "pair, view gate off / on, per fraction)",
    )
    ap.add_argument(
        "--wrong-in-gate",
        action="store_true",
        help="gateN cases: add the wrong-match rows (--wrong-fracs) of the re-tracked frames",
    )
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/vision.json"))
    args = ap.parse_args()
    results: dict[str, Any] = {}
    kept: dict[str, Any] = {}  # the file's other entries (notes, CLI timings) stay
    if args.out.exists():
        import json

        kept = json.loads(args.out.read_text())
        results = kept.pop("cases", {})
    for case in args.cases:
        if case.startswith("scale"):  # e.g. scale1.5: ideal tracks at 1.5 points / m^2
            res = in_subprocess(case_scale, float(case[5:]), args.seed)
            cols = SCALE_COLS
        elif case.startswith("gate"):  # e.g. gate8: chain_sunny with an 8 px gate
            fracs = tuple(args.wrong_fracs) if args.wrong_in_gate else ()
            res = in_subprocess(case_gate, float(case[4:]), fracs)
            cols = CHAIN_COLS
        elif case == "render":
            res = in_subprocess(case_render, args.keyframes, args.seed)
            cols = [
                ("scene", "scene", ""),
                ("cpu_ms", "cpu ms", ".1f"),
                ("wall_ms", "wall ms", ".1f"),
                ("plane_share", "plane", ".2f"),
                ("sha256", "sha256", ""),
            ]
        elif case == "headings":
            res = in_subprocess(case_headings, 20, args.seed)
            cols = [
                ("heading", "heading", ""),
                ("max_features", "max feat", "d"),
                ("features_per_frame", "feat/fr", ".0f"),
                ("inliers_per_frame", "inl/fr", ".0f"),
                ("views_per_keyframe", "views/kf", ".1f"),
                ("err_median_px", "err med", ".2f"),
                ("err_gt4_frac", ">4px", ".3f"),
                ("track_ms", "track ms", ".0f"),
            ]
        elif case == "frontend":
            res = in_subprocess(case_frontend, args.keyframes, args.seed)
            cols = [
                ("scene", "scene", ""),
                ("detector", "det", ""),
                ("clahe", "clahe", ""),
                ("features_per_frame", "feat/fr", ".0f"),
                ("inlier_ratio", "inl.ratio", ".2f"),
                ("views_per_keyframe", "views/kf", ".1f"),
                ("track_length", "length", ".2f"),
                ("err_median_px", "err med", ".2f"),
                ("err_p95_px", "err p95", ".2f"),
                ("err_gt4_frac", ">4px", ".3f"),
                ("render_ms", "render ms", ".0f"),
                ("track_ms", "track ms", ".0f"),
            ]
        else:
            scene = "overcast_snow" if case == "chain_overcast" else "sunny_snow"
            swaths = 4 if case == "chain_sunny" else args.overcast_swaths
            bounds = None if case == "chain_sunny" else args.overcast_bounds
            res = in_subprocess(
                case_chain,
                scene,
                swaths,
                case == "chain_overcast",
                bounds,
                args.seed,
                tuple(args.wrong_fracs),
            )
            if args.seed:  # other seeds: their own entry in the results
                case = f"{case}_seed{args.seed}"
            cols = CHAIN_COLS
        print(table(res["rows"], cols), flush=True)
        results[case] = res
        write_json(args.out, {**kept, "cases": results, "command": " ".join(sys.argv)})


if __name__ == "__main__":
    main()
