"""Ground control (issue 17, item 4): the default scenario with and without 4 surveyed control
points at the survey's corners (σ 2 cm), through localization, selection, the GP map and the
certificate, the stages ``toolkit/pipeline.py`` runs.

    python benchmarks/ground_control.py --out benchmarks/results/ground_control.json
    python benchmarks/ground_control.py --seeds 0 1 2 --no-map     # landmarks only, 3 seeds

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

from benchmarks._harness import in_subprocess, table, write_json  # noqa: E402

CASES = ("none", "stops4", "stops2", "stops8", "targets4")


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
    from terrain import Grid, TriangulatedMean, coarse_dem, evaluate
    from toolkit.certify import certify
    from toolkit.stages import reconstruct_stage

    seed = int(scenario["seed"])
    grid = Grid.from_bounds(
        tuple(scenario["site"]["bounds"]),
        float(scenario["reconstruct"]["resolution_m"]),
        scenario["site"]["crs"],
    )
    kept = sel.table["kept"]
    product = reconstruct_stage(  # the pipeline's GP map with the paper's 8 x 8 prior
        sel.samples,
        grid,
        TriangulatedMean(coarse_dem(truth, cells=(8, 8))),
        scenario,
        seed,
        landmark_xy=np.column_stack([sel.table["x"][kept], sel.table["y"][kept]]),
        landmark_rel_z_std=sel.table["z_std_m"][kept],
        shared_z_std=float(sel.shared_offset_std_m[2]),
        heldout_folds=0,
    ).product
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


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", nargs="+", default=list(CASES), choices=CASES)
    ap.add_argument("--seeds", nargs="+", type=int, default=[0])
    ap.add_argument("--no-map", action="store_true", help="landmarks only (no GP, no certify)")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)
    rows = []
    for seed in args.seeds:
        for case in args.cases:
            rows.append(in_subprocess(run_case, case, seed, not args.no_map))
            print(table(rows[-1:], COLUMNS), flush=True)
    print(table(rows, COLUMNS))
    if args.out:
        write_json(args.out, {"benchmark": "ground_control", "rows": rows})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
