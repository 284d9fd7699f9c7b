"""Ground control (issue 17, item 4): the default scenario with and without 4 surveyed control
points at the survey's corners (σ 2 cm), through localization, selection, the GP map and the
certificate, the stages ``toolkit/pipeline.py`` runs.

    python benchmarks/ground_control.py --out benchmarks/results/ground_control.json
    python benchmarks/ground_control.py --seeds 0 1 2 --no-map     # landmarks only, 3 seeds
    python benchmarks/ground_control.py --route process --out benchmarks/results/ground_control.json
    python benchmarks/ground_control.py --route process --calibration --cases none stops4 stops8 \
        --seeds 0-11 --out benchmarks/results/ground_control_calibration.json
    python benchmarks/ground_control.py --route small --cases small150 --seeds 0-11 \
        --out benchmarks/results/ground_control_small.json

``--calibration`` scores each seed's realised vertical offset (keyframe mean, map mean,
checkpoint bias) against the run's stated shared 1-sigma (:mod:`benchmarks._calibration`);
``--route small`` does it on scaled-down traverses (:data:`SMALL_CASES`) in seconds per seed.

``--route stages`` (default) runs the stages below on the simulated log in memory, with the
paper's perfect 8 x 8 prior and checkpoints drawn with ``default_rng(seed)``. ``--route
process`` runs ``glacimap run`` itself (:func:`toolkit.pipeline.run_scenario`): the survey
written as field files (NMEA, ``stops.csv``, ``control.csv``, a noisy offset ``prior.tif``,
its own 400 checkpoints) and processed by ``toolkit.process`` with no truth; the cases are
the scenario's ``[control] n_targets = 4`` with ``mode`` stops / targets / both, an
RTK-grade GPS (:data:`RTK_GPS`, written as NMEA fix quality 4 with GST sigmas), and two
diagnostics with the satellite DEM written without its 0.3 m per-cell noise (``_prior0``)
and one with 8 swaths (``_swaths8``).
Its rows go to ``process_rows`` of the JSON (the other keys are kept).

Cases, on the same simulated log (same seed, same bytes: the control draws have their own
stream, ``factorgraph.control_sim``):

``none``
    No control (what ``glacimap run`` does today).
``stops4``
    The rover stops on 4 control points at the corners of its path (``path_corners``: where the
    lawnmower's swaths turn; the site's own corners lie 75 m outside the outer swaths, beyond
    the camera's 25 m), surveyed with σ 2 cm per axis, centring σ 2 cm
    (``factorgraph.control_sim.simulate_control``).
``stops2``
    Only the first and last stop (2 points, both ends of the traverse in time).
``stops8``
    A stop at every turn of the lawnmower (its 8 waypoints: both ends of every swath).
``targets4``
    No stops: 4 marked targets 6 m outside the path's corners, tracked by the camera, with a
    2 cm prior on their landmarks (``factorgraph.control_sim.simulate_targets``).

Scores. Landmarks (all in the graph): mean and RMS of the vertical error against the truth,
its NEES ``mean(e_z^2 / Sigma_zz)`` (1 when the stated 1-sigma is right); keyframes: mean
vertical error (what the shared offset describes); the shared-offset vertical 1-sigma the
marginals state. Map: ``gp_satellite`` exactly as the
pipeline builds it (``TerrainGP`` on the selected landmarks, satellite prior, error budget),
RMSE against the truth on the grid; certificate (``toolkit.certify``) against the run's 400
seeded checkpoints: bias (DEM minus checkpoint), RMSE, std. Each case runs in its own process.
Timings are wall times on the shared 2-core machine (inflated by other jobs).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks._calibration import (  # noqa: E402
    CALIBRATION_COLUMNS,
    calibration,
    guarded,
    seed_list,
)
from benchmarks._harness import (  # noqa: E402
    in_subprocess,
    paper_prior_map,
    table,
    write_json,
)

CASES = ("none", "stops4", "stops2", "stops8", "targets4")
PROCESS_CASES = (
    *("none", "stops4", "targets4", "both4", "stops8", "rtk", "rtk_stops4"),
    *("stops4_prior0", "rtk_prior0"),  # diagnostics: [prior] noise_sd_m = 0
    "rtk_swaths8",  # diagnostic: [plan] n_swaths = 8 (swaths 75 m apart, not 150 m)
)
#: RTK-fixed GPS: 2 cm horizontal, 3 cm vertical white noise per fix (the receiver's GST
#: sigmas, fix quality 4) and a small correlated part (multipath, base coordinates): 1 cm
#: horizontal, 2 cm vertical Gauss-Markov bias (tau 60 s, the default).
RTK_GPS = {"sigma_white_m": [0.02, 0.02, 0.03], "bias_sigma_m": [0.01, 0.01, 0.02]}


def _checkpoints(scenario: dict[str, Any], truth):
    """The run's checkpoints: ``n_checkpoints`` seeded uniform points in the site, z from the
    truth (the draw ``toolkit.pipeline`` makes with ``default_rng(seed)``)."""
    from terrain import Grid
    from terrain.sampling import sample_dem
    from toolkit.certify_io import Checkpoints

    rng = np.random.default_rng(int(scenario["seed"]))
    w, s, e, n = (float(v) for v in scenario["site"]["bounds"])
    grid = Grid.from_dataarray(truth)
    lo = np.maximum([w, s], [grid.x[0], grid.y[-1]])
    hi = np.minimum([e, n], [grid.x[-1], grid.y[0]])
    xy = rng.uniform(lo, hi, (int(scenario["certify"]["n_checkpoints"]), 2))
    return Checkpoints(xy, sample_dem(truth, xy), crs=grid.crs, source="truth (simulated)")


def _map(scenario, truth, loc, sel) -> dict[str, Any]:
    """The pipeline's ``gp_satellite`` product and its certificate."""
    from terrain import Grid, evaluate
    from toolkit.certify import certify

    seed = int(scenario["seed"])
    product = paper_prior_map(sel, truth, scenario)  # the pipeline's GP map, 8 x 8 prior
    grid = Grid.from_dataarray(product)
    truth_on_grid = truth.interp(x=grid.x, y=grid.y, method="linear")
    m = evaluate(product["elevation"].values, truth_on_grid.values, product["elevation_std"].values)
    cert = certify(product, _checkpoints(scenario, truth), seed=seed, n_boot=200)
    acc = cert["accuracy"]
    return {
        "map_rmse_m": float(m["rmse"]),
        "map_coverage95": m.get("coverage_95"),
        "checkpoint_bias_m": acc["bias_m"],
        "checkpoint_rmse_m": acc["rmse_m"],
        "checkpoint_std_m": acc["std_m"],
        "n_checkpoints": acc["n"],
    }


def run_case(case: str, seed: int, with_map: bool) -> dict[str, Any]:
    from factorgraph.control_sim import (
        nearest_keyframes,
        path_corners,
        simulate_control,
        simulate_targets,
    )
    from factorgraph.localize import LocalizeParams, localize
    from factorgraph.select import select_landmarks
    from toolkit.config import load_scenario
    from toolkit.pipeline import make_plan, make_truth, simulate_log

    scenario = load_scenario(None, {"seed": seed})
    truth = make_truth(scenario)
    plan = make_plan(scenario, truth)
    log = simulate_log(scenario, truth, plan)
    control = None
    if case == "targets4":
        log, control, _ = simulate_targets(log, truth, sigma_m=0.02)
    elif case != "none":
        ks = path_corners(log)
        if case == "stops2":
            ks = np.array([ks.min(), ks.max()])
        elif case == "stops8":
            ks = nearest_keyframes(log, np.asarray(plan.waypoints))
        log, control, _ = simulate_control(log, ks, sigma_m=0.02, centring_sigma_m=0.02)
    t0 = time.perf_counter()
    loc = localize(log, LocalizeParams(**scenario["localize"]), control=control)
    out: dict[str, Any] = {"case": case, "seed": seed, "localize_s": time.perf_counter() - t0}
    ez = (loc.landmark_xyz - loc.true_landmarks())[:, 2]
    ek = loc.keyframe_xyz - log.truth["xyz"]
    out.update(
        {
            "landmark_z_mean_m": float(ez.mean()),
            "landmark_z_rmse_m": float(np.sqrt(np.mean(ez**2))),
            "landmark_z_nees": float(np.mean(ez**2 / loc.landmark_cov[:, 2, 2])),
            "keyframe_z_mean_m": float(ek[:, 2].mean()),
            "keyframe_z_rmse_m": float(np.sqrt(np.mean(ek[:, 2] ** 2))),
            "keyframe_h_rmse_m": float(np.sqrt(np.mean((ek[:, :2] ** 2).sum(1)))),
            "shared_z_std_m": float(np.sqrt(loc.shared_offset_cov[2, 2])),
            "shared_h_std_m": float(np.sqrt(np.trace(loc.shared_offset_cov[:2, :2]))),
            "control": loc.control,
        }
    )
    if with_map:
        rules = scenario["select"]  # the pipeline's selection settings
        sel = select_landmarks(
            loc,
            max_sigma=float(rules["max_sigma_m"]),
            min_first_seen_distance=float(rules["min_first_seen_distance_m"]),
            variance=rules["variance"],
            rule=rules["rule"],
        )
        t0 = time.perf_counter()
        out.update(_map(scenario, truth, loc, sel))
        out["map_s"] = time.perf_counter() - t0
        out["landmarks_selected"] = int(sel.counts["kept"])
    return out


def process_overrides(case: str, seed: int) -> dict[str, Any]:
    """Scenario overrides of a ``--route process`` case (``_prior0``: the satellite DEM
    written without its per-cell noise, the datum offset kept: what the map owes the prior;
    ``_swaths8``: 8 swaths instead of 4: what it owes the gaps between swaths)."""
    over: dict[str, Any] = {"seed": seed}
    if case.endswith("_prior0"):
        case = case.removesuffix("_prior0")
        over["prior"] = {"noise_sd_m": 0.0}
    if case.endswith("_swaths8"):
        case = case.removesuffix("_swaths8")
        over["plan"] = {"n_swaths": 8}
    mode = {"stops4": "stops", "targets4": "targets", "both4": "both", "rtk_stops4": "stops"}
    if case in mode:
        over["control"] = {"n_targets": 4, "mode": mode[case]}
    if case == "stops8":  # a stop at every turn of the lawnmower (its 8 waypoints)
        over["control"] = {"n_targets": 8, "mode": "stops"}
    if case.startswith("rtk"):
        over["sensors"] = {"gps": dict(RTK_GPS)}
    return over


def _landmark_errors(loc, sim_log, ids=None) -> dict[str, float]:
    """Vertical error of the processed landmarks (``ids``: a subset) against the simulation's
    true landmarks, matched by track id (the field files keep the ids)."""
    tr = sim_log.truth
    lid = loc.landmark_id if ids is None else np.asarray(ids)
    row = np.searchsorted(loc.landmark_id, lid)
    pos = np.searchsorted(tr["landmark_id"], lid)
    shift = np.r_[loc.log.origin - sim_log.origin, 0.0]  # same origin when from survey.json
    e = loc.landmark_xyz[row] + shift - tr["landmark_xyz"][pos]
    return {
        "z_mean_m": float(e[:, 2].mean()),
        "z_rmse_m": float(np.sqrt(np.mean(e[:, 2] ** 2))),
        "z_nees": float(np.mean(e[:, 2] ** 2 / loc.landmark_cov[row, 2, 2])),
        "h_rmse_m": float(np.sqrt(np.mean((e[:, :2] ** 2).sum(1)))),
        "n": int(lid.size),
    }


#: bands of distance from a map cell to the nearest selected landmark (m)
DISTANCE_BANDS = ((0, 5), (5, 15), (15, 30), (30, 60), (60, 1e9))


def map_error_by_distance(product, truth, xy: np.ndarray) -> dict[str, dict[str, float]]:
    """Map error against the truth by distance to the nearest sample ``xy`` (n, 2): per band
    the share of cells, RMSE and mean (m). On the swaths the map is the rover's; between
    them (swaths 150 m apart, the camera's 25 m reach) it leans on the satellite prior."""
    from scipy.spatial import cKDTree

    err = product["elevation"].values - truth.interp(x=product.x, y=product.y).values
    X, Y = np.meshgrid(product.x.values, product.y.values)
    dist = cKDTree(xy).query(np.column_stack([X.ravel(), Y.ravel()]))[0].reshape(X.shape)
    ok = np.isfinite(err)
    out = {}
    for lo, hi in DISTANCE_BANDS:
        m = ok & (dist >= lo) & (dist < hi)
        out[f"{lo}-{hi:g}"] = {
            "share": float(m.sum() / ok.sum()),
            "rmse_m": float(np.sqrt(np.mean(err[m] ** 2))) if m.any() else None,
            "mean_m": float(err[m].mean()) if m.any() else None,
        }
    return out


def realised_offsets(loc, sim_log, product, truth) -> dict[str, float]:
    """The drawn map-wide vertical offset of one run, three ways (m): the mean vertical error
    of the keyframes (exactly the quantity whose covariance the marginals state as the shared
    offset, :mod:`factorgraph.marginals`) and the map's mean error over the whole site."""
    true = sim_log.truth["xyz"] + np.r_[sim_log.origin - loc.log.origin, 0.0]
    kf = float((loc.keyframe_xyz - true)[:, 2].mean())
    err = product["elevation"].values - truth.interp(x=product.x, y=product.y).values
    return {"keyframe_z_mean_m": kf, "map_mean_error_m": float(np.nanmean(err))}


def run_process_case(case: str, seed: int) -> dict[str, Any]:
    """``glacimap run`` (field files -> ``process``) for one case; scores against the truth."""
    import tempfile

    from toolkit.pipeline import run_scenario

    over = process_overrides(case, seed)
    with tempfile.TemporaryDirectory(prefix="gc_process_") as tmp:
        res = run_scenario(None, out=tmp, overrides=over)
    cert, metrics = res.summary["certificate"], res.summary["metrics"]
    loc, sel, sim = res.objects["localization"], res.objects["selection"], res.objects["log"]
    acc, locs = cert["accuracy"], cert["localization"]
    kept_ids = sel.table["landmark_id"][sel.table["kept"]]
    all_lm, kept_lm = _landmark_errors(loc, sim), _landmark_errors(loc, sim, kept_ids)
    ctl = locs.get("control") or {}
    product = res.objects["reconstruction"].product
    by_dist = map_error_by_distance(product, res.objects["truth"], sel.samples.xy)
    offsets = realised_offsets(loc, sim, product, res.objects["truth"])
    return {
        **offsets,
        "swath_mean_error_m": by_dist["0-5"]["mean_m"],
        "case": case,
        "seed": seed,
        "route": "process",
        "overrides": over,
        "landmark_z_mean_m": all_lm["z_mean_m"],
        "landmark_z_rmse_m": all_lm["z_rmse_m"],
        "landmark_z_nees": all_lm["z_nees"],
        "selected_z_mean_m": kept_lm["z_mean_m"],
        "selected_z_rmse_m": kept_lm["z_rmse_m"],
        "selected_h_rmse_m": kept_lm["h_rmse_m"],
        "landmarks_in_graph": all_lm["n"],
        "landmarks_selected": kept_lm["n"],
        "keyframe_h_rmse_m": locs["simulation"].get("horizontal_rmse_m"),
        "keyframe_z_rmse_m": locs["simulation"].get("vertical_rmse_m"),
        "shared_z_std_m": float(locs["shared_offset_std_m"][2]),
        "checkpoint_bias_m": acc["bias_m"],
        "checkpoint_rmse_m": acc["rmse_m"],
        "checkpoint_std_m": acc["std_m"],
        "map_rmse_m": float(metrics["gp_satellite"]["rmse"]),
        "map_coverage95": metrics["gp_satellite"].get("coverage_95"),
        "delaunay_rmse_m": float(metrics["delaunay"]["rmse"]),
        "kernel": cert["reconstruction"]["kernel"],
        "map_by_distance": by_dist,
        "control_used": [(u["id"], u["kind"]) for u in ctl.get("used", [])],
        "control_unused": ctl.get("unused", {}),
        "ingest_stops": cert["ingest"].get("stops", {}),
        "gps_quality": cert["ingest"].get("gps_quality", {}),
        "timings_s": res.timings,
    }


#: scaled-down calibration geometries (``--route small``): a 500 m leg, a turn, a 500 m leg
#: back, ``apart`` m from the first (40 m: the camera's 25 m reach ties the legs; 150 m: it
#: does not, as on the default lawnmower); a stop at each end only; default sensors
SMALL_CASES = {"small40": 40.0, "small150": 150.0, "small40_pose": 40.0}


def run_small_case(case: str, seed: int) -> dict[str, Any]:
    """One seed of a :data:`SMALL_CASES` traverse, localized with its two end stops
    (``_pose``: without the camera's landmarks): the realised keyframe vertical offset against
    the stated shared 1-sigma, in seconds instead of minutes."""
    from factorgraph.control_sim import simulate_control
    from factorgraph.localize import LocalizeParams, localize
    from factorgraph.sensors import CameraModel, GPSModel, SensorSuite
    from factorgraph.simulate import simulate_traverse
    from terrain.synthetic import default_site

    w, n, apart = 526000.0, 6475600.0, SMALL_CASES[case]
    wp = np.array([[w + 50, n - 75], [w + 550, n - 75], [w + 550, n - 75 - apart]])
    wp = np.vstack([wp, [w + 50, n - 75 - apart]])
    sensors = SensorSuite(
        gps=GPSModel(rate_hz=0.5),
        camera=CameraModel(texture_density_per_m2=0.05),
        keyframe_dt_s=2.0,
    )
    log = simulate_traverse(default_site(2.0), wp, sensors, seed=seed)
    log, ctrl, _ = simulate_control(log, [0, log.n_keyframes - 1])
    loc = localize(log, LocalizeParams(use_landmarks=not case.endswith("_pose")), control=ctrl)
    e = loc.keyframe_xyz - log.truth["xyz"]
    return {
        "case": case,
        "seed": seed,
        "route": "small",
        "keyframes": int(log.n_keyframes),
        "keyframe_z_mean_m": float(e[:, 2].mean()),
        "shared_z_std_m": float(np.sqrt(loc.shared_offset_cov[2, 2])),
        "keyframe_z_nees": float(np.mean(e[:, 2] ** 2 / loc.pose_cov_xyz[:, 2, 2])),
        "map_mean_error_m": None,  # no map on this route
        "checkpoint_bias_m": None,
    }


COLUMNS = [
    ("case", "case", ""),
    ("seed", "seed", "d"),
    ("landmark_z_mean_m", "lm z mean", ".3f"),
    ("landmark_z_rmse_m", "lm z RMSE", ".3f"),
    ("landmark_z_nees", "lm z NEES", ".2f"),
    ("keyframe_z_mean_m", "kf z mean", ".3f"),
    ("shared_z_std_m", "shared z σ", ".3f"),
    ("keyframe_h_rmse_m", "kf h RMSE", ".3f"),
    ("checkpoint_bias_m", "cp bias", ".3f"),
    ("checkpoint_rmse_m", "cp RMSE", ".3f"),
    ("checkpoint_std_m", "cp std", ".3f"),
    ("map_rmse_m", "map RMSE", ".3f"),
    ("localize_s", "localize s", ".1f"),
]


PROCESS_COLUMNS = [
    ("case", "case", ""),
    ("seed", "seed", "d"),
    ("landmark_z_mean_m", "lm z mean", ".3f"),
    ("landmark_z_rmse_m", "lm z RMSE", ".3f"),
    ("selected_z_rmse_m", "sel z RMSE", ".3f"),
    ("landmark_z_nees", "lm z NEES", ".2f"),
    ("keyframe_z_mean_m", "kf z mean", ".3f"),
    ("map_mean_error_m", "map mean", ".3f"),
    ("shared_z_std_m", "shared z σ", ".3f"),
    ("keyframe_h_rmse_m", "kf h RMSE", ".3f"),
    ("checkpoint_bias_m", "cp bias", ".3f"),
    ("checkpoint_rmse_m", "cp RMSE", ".3f"),
    ("map_rmse_m", "map RMSE", ".3f"),
    ("delaunay_rmse_m", "Delaunay", ".3f"),
    ("wall_s", "wall s", ".0f"),
]


def _save(path: Path, key: str, rows: list[dict[str, Any]], merge: bool, calib: bool) -> None:
    """Write ``rows`` under ``key`` of the JSON at ``path`` (other keys kept; with ``merge``
    the (case, seed) rows already there are replaced, the others kept)."""
    import json

    old = json.loads(path.read_text()) if path.is_file() else {}
    old = {k: v for k, v in old.items() if k not in ("python", "machine", "cpu_count")}
    if key in old and merge:
        done = {(r["case"], r["seed"]) for r in rows}
        rows = [r for r in old[key] if (r["case"], r["seed"]) not in done] + rows
    extra = {"calibration": calibration(rows)} if calib else {}
    write_json(path, {**old, "benchmark": "ground_control", key: rows, **extra})


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--cases", nargs="+", default=None, choices=sorted({*CASES, *PROCESS_CASES, *SMALL_CASES})
    )
    ap.add_argument("--seeds", nargs="+", default=["0"], help="seeds and ranges: 0-11 20")
    ap.add_argument("--no-map", action="store_true", help="landmarks only (no GP, no certify)")
    ap.add_argument("--route", choices=("stages", "process", "small"), default="stages")
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument(
        "--calibration",
        action="store_true",
        help="(--route process) score each seed's realised offset against the stated shared "
        "1-sigma; rows and the per-case table go to calibration_rows / calibration",
    )
    args = ap.parse_args(argv)
    if args.calibration and args.route == "stages":
        ap.error("--calibration runs on --route process (what glacimap run does) or small")
    if args.route == "small":
        args.calibration = True  # the small route only measures calibration
    known = {"stages": CASES, "process": PROCESS_CASES, "small": tuple(SMALL_CASES)}[args.route]
    cases = args.cases or list(known)
    if set(cases) - set(known):
        ap.error(f"--route {args.route} cases: {', '.join(known)}")
    rows: list[dict[str, Any]] = []
    cols = COLUMNS if args.route == "stages" else PROCESS_COLUMNS
    key = "rows" if args.route == "stages" else "process_rows"
    key = "calibration_rows" if args.calibration else key
    key = "small_rows" if args.route == "small" else key
    for seed in seed_list(args.seeds):
        for case in cases:
            if args.route == "stages":
                rows.append(in_subprocess(run_case, case, seed, not args.no_map))
            else:
                fn = run_small_case if args.route == "small" else run_process_case
                rows.append(in_subprocess(guarded, fn, case, seed))
            print(table(rows[-1:], cols), rows[-1].get("error", ""), flush=True)
            if args.out and args.route != "stages":  # saved row by row: a long sweep
                _save(args.out, key, rows, True, args.calibration)
    print(table(rows, cols))
    if args.out and args.route == "stages":
        _save(args.out, key, rows, False, False)
    if args.calibration:
        print(table(calibration(rows), CALIBRATION_COLUMNS))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
