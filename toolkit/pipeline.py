"""The main job (DESIGN.md §1): plan → simulate → iSAM2 → select landmarks → reconstruct →
certify → export → report, over the public APIs of survey, factorgraph and terrain."""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from factorgraph.evaluate import frame_floor, horizontal_floor
from factorgraph.localize import LocalizeParams, localize
from factorgraph.log import MeasurementLog
from factorgraph.result import LocalizationResult
from factorgraph.select import LandmarkSelection, select_landmarks
from factorgraph.sensors import SensorSuite
from factorgraph.simulate import simulate_traverse
from terrain import Grid, TerrainGP, TriangulatedMean, coarse_dem, delaunay_linear, evaluate
from terrain.atomic import atomic_path, ensure_writable_dir
from terrain.sampling import sample_dem
from terrain.synthetic import default_site, random_terrain

from .config import load_scenario
from .error_budget import inflate_std
from .export._files import staged_folder

__all__ = [
    "RunResult",
    "STAGES",
    "landmark_table",
    "localization_summary",
    "localize_log",
    "make_plan",
    "make_truth",
    "run_scenario",
    "samples_table",
    "select_samples",
    "simulate_log",
    "trajectory_table",
]

STAGES = ("plan", "simulate", "localize", "select", "reconstruct", "certify", "export", "report")


@dataclass
class RunResult:
    """What ``glacimap run`` made: products on disk plus the in-memory objects."""

    out: Path
    scenario: dict[str, Any]
    timings: dict[str, float] = field(default_factory=dict)
    summary: dict[str, Any] = field(default_factory=dict)
    objects: dict[str, Any] = field(default_factory=dict)


def make_truth(scenario: dict[str, Any]):
    """The true DEM of the scenario's ``[site]`` (``xarray.DataArray``, metres)."""
    site, seed = scenario["site"], int(scenario["seed"])
    if site["kind"] == "default":
        return default_site(resolution=float(site["truth_resolution_m"]))
    grid = Grid.from_bounds(tuple(site["bounds"]), float(site["truth_resolution_m"]), site["crs"])
    return random_terrain(grid, relief=float(site["relief_m"]), seed=seed, features=True)


def make_plan(scenario: dict[str, Any], truth):
    """The scenario's ``[plan]`` over its site bounds: a lawnmower, or the piecewise-continuous
    pattern (Eq 10) on the 8 x 8 satellite prior of ``truth``."""
    from survey.lawnmower import lawnmower
    from survey.piecewise import piecewise_continuous

    p, bounds = scenario["plan"], tuple(scenario["site"]["bounds"])
    seed = int(scenario["seed"])
    if p["pattern"] == "lawnmower":
        return lawnmower(
            bounds, int(p["n_swaths"]), margin=float(p["margin_m"]), crs=truth_crs(truth)
        )
    prior = TriangulatedMean(coarse_dem(truth, cells=(8, 8)))
    return piecewise_continuous(
        bounds, int(p["n_swaths"]), prior, seed=seed, margin=float(p["margin_m"])
    )


def truth_crs(truth) -> str:
    return Grid.from_dataarray(truth).crs.to_string()


def simulate_log(scenario: dict[str, Any], truth, plan) -> MeasurementLog:
    """Drive ``plan`` over ``truth`` with the scenario's ``[sensors]`` and seed."""
    sensors = SensorSuite.from_dict(scenario["sensors"])
    return simulate_traverse(truth, plan, sensors=sensors, seed=int(scenario["seed"]))


def localize_log(
    log: MeasurementLog,
    scenario: dict[str, Any],
    progress: Callable[[int, int], None] | None = None,
) -> LocalizationResult:
    """iSAM2 over ``log`` with the scenario's ``[localize]`` settings."""
    return localize(log, LocalizeParams(**scenario["localize"]), progress=progress)


def select_samples(loc: LocalizationResult, scenario: dict[str, Any]) -> LandmarkSelection:
    """The paper's landmark rules with the scenario's ``[select]`` settings (Eq 7)."""
    sel_cfg = scenario["select"]
    return select_landmarks(
        loc,
        max_sigma=float(sel_cfg["max_sigma_m"]),
        min_first_seen_distance=float(sel_cfg["min_first_seen_distance_m"]),
        variance=sel_cfg["variance"],
        rule=sel_cfg["rule"],
    )


def trajectory_table(loc: LocalizationResult) -> dict[str, np.ndarray]:
    """One row per keyframe: ``k, t_s``, final estimate ``x, y, z`` (projected CRS, m), its
    marginal 1-sigma ``std_x, std_y, std_z`` (m), the online estimate ``online_x, online_y,
    online_z``, the estimated GPS bias ``bias_x, bias_y, bias_z`` (bias model) and, in
    simulation, the truth ``true_x, true_y, true_z``."""
    log = loc.log
    est = loc.to_projected(loc.keyframe_xyz)
    online = loc.to_projected(loc.online_xyz)
    std = np.sqrt(np.clip(np.diagonal(loc.pose_cov_xyz, axis1=1, axis2=2), 0.0, None))
    out: dict[str, np.ndarray] = {"k": np.arange(log.n_keyframes), "t_s": log.t}
    for i, a in enumerate("xyz"):
        out[a] = est[:, i]
    for i, a in enumerate("xyz"):
        out[f"std_{a}"] = std[:, i]
    for i, a in enumerate("xyz"):
        out[f"online_{a}"] = online[:, i]
    if loc.gps_bias is not None:
        for i, a in enumerate("xyz"):
            out[f"bias_{a}"] = loc.gps_bias[:, i]
    if log.has_truth:
        true = loc.to_projected(log.truth["xyz"])
        for i, a in enumerate("xyz"):
            out[f"true_{a}"] = true[:, i]
    return out


def landmark_table(loc: LocalizationResult, sel: LandmarkSelection) -> dict[str, np.ndarray]:
    """One row per landmark in the graph: the selection's diagnostics (``landmark_id, x, y, z,
    sigma_max_m, sigma_max_full_m, z_std_m, first_seen_distance_m, n_views, kept, reason``)
    and, in simulation, the true position ``true_x, true_y, true_z`` (projected CRS, m)."""
    out = dict(sel.table)
    if "landmark_xyz" in loc.log.truth and loc.n_landmarks:
        true = loc.to_projected(loc.true_landmarks())
        for i, a in enumerate("xyz"):
            out[f"true_{a}"] = true[:, i]
    return out


def samples_table(sel: LandmarkSelection) -> dict[str, np.ndarray]:
    """The selected landmarks as terrain samples ``x, y, z, z_var`` (m, m^2): the table
    ``glacimap reconstruct SAMPLES.csv`` reads."""
    s = sel.samples
    return {"x": s.xy[:, 0], "y": s.xy[:, 1], "z": s.z, "z_var": s.z_var}


def _checkpoints(truth, bounds, n: int, rng: np.random.Generator):
    """Independent checkpoints: ``n`` seeded random points inside the site, z from the truth."""
    w, s, e, nn = bounds
    grid = Grid.from_dataarray(truth)
    lo = np.maximum([w, s], [grid.x[0], grid.y[-1]])
    hi = np.minimum([e, nn], [grid.x[-1], grid.y[0]])
    xy = rng.uniform(lo, hi, (n, 2))
    from .certify_io import Checkpoints

    return Checkpoints(xy, sample_dem(truth, xy), crs=grid.crs, source="truth (simulated)")


def run_scenario(
    config: str | Path | None = None,
    out: str | Path = "out/run",
    overrides: dict[str, Any] | None = None,
    on_stage: Callable[[str, str], None] | None = None,
    on_progress: Callable[[int, int], None] | None = None,
) -> RunResult:
    """Run the whole pipeline on a scenario and write every product into ``out``.

    Parameters
    ----------
    config : path, optional
        Scenario TOML (see :mod:`toolkit.config`); default: the embedded scenario.
    out : path
        Output folder (created; must be writable).
    overrides : dict, optional
        Nested keys replacing those of the scenario (same validation).
    on_stage : callable, optional
        ``on_stage(stage, "start" | "done")`` for progress display.
    on_progress : callable, optional
        ``on_progress(k, K)`` during localization.
    """
    from .certify import certify, write_certificate
    from .export import VectorLayer, write_cog, write_contours, write_mesh, write_vector_layers
    from .report import write_report

    scenario = load_scenario(config, overrides)
    out = ensure_writable_dir(out)
    seed = int(scenario["seed"])
    rng = np.random.default_rng(seed)
    res = RunResult(out=out, scenario=scenario)
    notify = on_stage or (lambda stage, state: None)

    def stage(name: str):
        class _Timer:
            def __enter__(self):
                notify(name, "start")
                self.t = time.perf_counter()

            def __exit__(self, *exc):
                res.timings[name] = round(time.perf_counter() - self.t, 3)
                if exc[0] is None:
                    notify(name, "done")

        return _Timer()

    bounds = tuple(float(v) for v in scenario["site"]["bounds"])
    with stage("plan"):
        truth = make_truth(scenario)
        plan = make_plan(scenario, truth)
    with stage("simulate"):
        log = simulate_log(scenario, truth, plan)
    with stage("localize"):
        loc = localize_log(log, scenario, progress=on_progress)
    with stage("select"):
        sel = select_samples(loc, scenario)
    with stage("reconstruct"):
        rc = scenario["reconstruct"]
        grid = Grid.from_bounds(bounds, float(rc["resolution_m"]), scenario["site"]["crs"])
        coarse = coarse_dem(truth, cells=(8, 8))  # the paper's 64-value satellite DEM
        shared_z = float(sel.shared_offset_std_m[2])
        maps = {}
        kept = sel.table["kept"]
        lm_xy = np.column_stack([sel.table["x"][kept], sel.table["y"][kept]])
        lm_rel_z = sel.table["z_std_m"][kept]  # relative (shared offset removed), Eq 7
        for name, mean in (("gp_satellite", TriangulatedMean(coarse)), ("gp_constant", "constant")):
            gp = TerrainGP(
                mean=mean,  # kernel="auto": the family member with the best evidence
                method=rc["method"],
                max_fit_samples=int(rc["max_fit_samples"]),
                n_restarts=int(rc["n_restarts"]),
                seed=seed,
            ).fit(sel.samples)
            maps[name] = inflate_std(gp.predict_grid(grid), gp, lm_xy, lm_rel_z, shared_z)
        maps["delaunay"] = delaunay_linear(sel.samples, grid)
        product = maps["gp_satellite"]
        product.attrs.update(
            {
                "seed": seed,
                "shared_vertical_offset_std_m": shared_z,
                "n_landmarks_selected": int(sel.samples.n),
            }
        )
        truth_on_grid = truth.interp(x=grid.x, y=grid.y, method="linear")
        metrics = {}
        for name, ds in maps.items():
            std = ds["elevation_std"].values if "elevation_std" in ds else None
            metrics[name] = evaluate(ds["elevation"].values, truth_on_grid.values, std)
    # Every product is written into a staging folder inside ``out`` and moved into ``out``
    # only when all of them are complete: a failed run leaves no partial set of products.
    with staged_folder(out) as tmp_out:
        with stage("certify"):
            cps = _checkpoints(truth, bounds, int(scenario["certify"]["n_checkpoints"]), rng)
            cert = certify(product, cps, seed=seed, n_boot=int(scenario["certify"]["n_boot"]))
            cert["scenario"] = scenario
            cert["truth_metrics"] = metrics
            cert["reconstruction"] = {  # the kernel chosen by evidence and its rivals
                "kernel": product.attrs.get("kernel"),
                "kernel_selection": json.loads(product.attrs.get("kernel_selection", "[]")),
            }
            cert["localization"] = localization_summary(loc, sel)
            write_certificate(cert, tmp_out / "certificate.json")
        with stage("export"):
            with atomic_path(tmp_out / "product.nc") as tmp:
                product.to_netcdf(tmp, engine="scipy")
            write_cog(product, tmp_out / "elevation.tif")
            interval = float(cert["contour_interval"]["certified_m"])
            geojson = tmp_out / "contours.geojson" if scenario["export"]["geojson"] else None
            write_contours(product, tmp_out / "contours.gpkg", interval, geojson)
            if scenario["export"]["mesh"]:
                write_mesh(
                    product, tmp_out / "mesh.ply", tmp_out / "mesh.vtp", tmp_out / "mesh.png"
                )
            est = loc.to_projected(loc.keyframe_xyz)
            true = loc.to_projected(log.truth["xyz"])
            t = sel.table
            layers = {
                "trajectory": VectorLayer.lines([est, true], kind=np.array(["estimated", "true"])),
                "landmarks": VectorLayer.points(
                    np.column_stack([t["x"], t["y"], t["z"]]),
                    landmark_id=t["landmark_id"],
                    z_std=t["z_std_m"],
                    sigma_max=t["sigma_max_m"],
                    n_views=t["n_views"],
                    kept=t["kept"],
                ),
            }
            write_vector_layers(tmp_out / "survey.gpkg", layers, scenario["site"]["crs"])
        with stage("report"):
            cov = loc.pose_cov_xyz[:, :2, :2]
            trajectory = {
                "xy_est": est[:, :2],
                "xy_true": true[:, :2],
                "cov_xy": cov,
                "landmarks_xy": sel.samples.xy,
            }
            write_report(
                tmp_out / "report.html",
                product=product,
                certificate=cert,
                truth=truth_on_grid,
                samples=sel.samples,
                trajectory=trajectory,
                coverage={k: v for k, v in cert["localization"].items() if np.isscalar(v)},
            )
        res.summary = {
            "seed": seed,
            "rmse_m": metrics["gp_satellite"]["rmse"],
            "metrics": metrics,
            "certificate": {k: cert[k] for k in cert if k not in ("scenario", "truth_metrics")},
            "timings_s": res.timings,
        }
        with atomic_path(tmp_out / "summary.json") as tmp:
            tmp.write_text(json.dumps(res.summary, indent=2, default=_json_default))
    res.objects = {
        "truth": truth,
        "plan": plan,
        "log": log,
        "localization": loc,
        "selection": sel,
        "maps": maps,
    }
    return res


def _json_default(o: Any):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)


def localization_summary(loc: LocalizationResult, sel: LandmarkSelection) -> dict[str, Any]:
    """Counts, timings and (in simulation) errors of one localization + selection, as plain
    JSON values: keyframes, duration, horizontal / vertical RMSE of the keyframes against the
    truth (m), iSAM2 step median / p95 and marginal times (s), landmarks in the graph and
    selected, the shared-offset 1-sigma (m), the selection counts, rebuilds and landmark NEES.

    Without truth too: ``predicted_horizontal_rmse_m`` (what the keyframe marginals predict,
    sqrt of their mean horizontal trace), ``horizontal_floor_m`` (the mean GPS bias floor) and
    ``frame_floor_m`` (:func:`factorgraph.evaluate.frame_floor` on the estimated path: the
    best any estimator of this GPS and relative sensors can expect on this traverse)."""
    log = loc.log
    out: dict[str, Any] = {"keyframes": log.n_keyframes, "duration_s": log.duration_s}
    pose_h = loc.pose_cov_xyz[:, :2, :2]
    out["predicted_horizontal_rmse_m"] = float(np.sqrt(np.mean(np.trace(pose_h, 0, 1, 2))))
    if log.gps_k.size and log.duration_s > 0:
        gps, xyz = log.sensors.gps, loc.keyframe_xyz
        out["horizontal_floor_m"] = horizontal_floor(gps, log.duration_s)
        out["frame_floor_m"] = frame_floor(
            gps,
            log.t[log.gps_k],
            xyz[log.gps_k],
            xyz,
            scale_sigma=log.sensors.odometry.scale_error_sigma,
        )
    if log.has_truth:
        err = loc.keyframe_xyz - log.truth["xyz"]
        out["horizontal_rmse_m"] = float(np.sqrt((err[:, :2] ** 2).sum(1).mean()))
        out["vertical_rmse_m"] = float(np.sqrt((err[:, 2] ** 2).mean()))
    out.update(
        {
            "step_median_s": float(np.median(loc.step_s)),
            "step_p95_s": float(np.percentile(loc.step_s, 95)),
            "marginals_s": float(loc.marginal_s),
            "landmarks_in_graph": loc.n_landmarks,
            "landmarks_selected": int(sel.counts["kept"]),
            "shared_offset_std_m": [float(v) for v in sel.shared_offset_std_m],
            "selection_counts": sel.counts,
            "isam2_rebuilds": loc.n_rebuilds,
        }
    )
    # GPS records not used, by reason: the field reader's counts (factorgraph.field) and the
    # gross outliers localize gated (factorgraph/field/gate.py)
    skipped = dict(log.ingest.get("gps_skipped", {}))
    if log.ingest.get("gps_gross_outliers_gated"):
        gated = int(log.ingest["gps_gross_outliers_gated"])
        skipped["gross_outlier"] = int(skipped.get("gross_outlier", 0)) + gated
    out["gps_used"] = int(log.gps_k.size)
    out["gps_skipped"] = skipped
    if "landmark_xyz" in log.truth and loc.n_landmarks:
        e = loc.landmark_xyz - loc.true_landmarks()
        nees = np.einsum("ni,ni->n", e, np.linalg.solve(loc.landmark_cov, e[..., None])[..., 0])
        out["landmark_nees_mean"] = float(nees.mean())
    return out
