"""The main job (docs/architecture.md §1): make a world, survey it, and process the survey's
files like a real one.

plan -> simulate -> *write the survey as field files* (``toolkit.field_survey``: NMEA GPS,
odometry CSV, tracks, camera YAML, a prior DEM GeoTIFF with realistic error, checkpoints and
control CSVs) -> :func:`toolkit.processing.process` (ingest -> localize -> select ->
reconstruct -> certify -> export) -> evaluation against the truth (simulation only: RMSE and
coverage of the map, Delaunay and, on request, a constant-mean GP, in ``summary.json`` and
the certificate's ``truth_metrics``).
"""

from __future__ import annotations

import json
import shutil
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from factorgraph.log import MeasurementLog
from factorgraph.sensors import SensorSuite
from factorgraph.simulate import simulate_traverse
from terrain import Grid, TerrainGP, TriangulatedMean, coarse_dem, delaunay_linear, evaluate
from terrain.atomic import atomic_path, ensure_writable_dir
from terrain.synthetic import default_site, random_terrain

from .config import anisotropy_option, load_scenario
from .epochs import epoch_truth, survey_scenario, write_change_truth
from .field_survey import write_field_survey
from .processing import PROCESS_STAGES, ProcessResult, _json_default, process
from .products import landmark_table, samples_table, trajectory_table
from .stages import landmark_truth_errors, localization_summary, localize_stage, select_stage

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
    "simulate_survey",
    "trajectory_table",
]

STAGES = ("plan", "simulate", *PROCESS_STAGES)


class RunResult(ProcessResult):
    """What ``glacimap run`` made: products on disk plus the in-memory objects; its
    ``settings`` are the scenario. The attributes of :class:`ProcessResult`, plus in
    ``summary`` the truth metrics (``rmse_m``: the map against the true DEM, m; ``metrics``
    per method) and in ``objects`` ``truth`` (the true DEM, ``xarray.DataArray``, m),
    ``plan``, ``field_survey`` and ``maps``."""

    def __repr__(self) -> str:
        text = super().__repr__()
        if "rmse_m" in self.summary:
            text = text[:-1] + f", RMSE vs truth {self.summary['rmse_m']:.3f} m)"
        return text

    @property
    def scenario(self) -> dict[str, Any]:
        return self.settings


def make_truth(scenario: dict[str, Any]):
    """The true DEM of the scenario's ``[site]`` (``xarray.DataArray``, metres); with
    ``[change] epoch = 2``, after the known change (:func:`toolkit.epochs.epoch_truth`)."""
    return epoch_truth(scenario, make_site(scenario))


def make_site(scenario: dict[str, Any]):
    """The scenario's ``[site]`` as it is (epoch 1): the embedded site, a random one, or a
    DEM file (``kind = "dem"``, :func:`toolkit.site_dem.dem_truth`)."""
    site, seed = scenario["site"], int(scenario["seed"])
    if site["kind"] == "default":
        return default_site(resolution=float(site["truth_resolution_m"]))
    if site["kind"] == "dem":  # resolved by load_scenario (toolkit.site_dem)
        from .site_dem import dem_truth

        return dem_truth(site)
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


def simulate_survey(
    scenario: dict[str, Any],
    truth,
    plan,
    images_dir: Path,
    on_frames: Callable[[int, int], None] | None = None,
) -> MeasurementLog:
    """The scenario's survey log: ideal feature tracks, or with ``[field] camera = "images"``
    frames rendered with the vision camera preset into ``images_dir`` (PNG, timestamps and
    the tracks stored beside them) and tracked by the OpenCV front-end
    (:func:`factorgraph.vision.simulate_images`; landmark truth from the renderer;
    ``on_frames(k, K)`` after each frame)."""
    shutil.rmtree(images_dir, ignore_errors=True)  # no stale frames for process to track
    if scenario["field"]["camera"] != "images":
        return simulate_log(scenario, truth, plan)
    from factorgraph.vision import SCENES, simulate_images, vision_sensors

    sensors = vision_sensors(SensorSuite.from_dict(scenario["sensors"]))
    scene = SCENES[scenario["field"]["scene"]]
    seed = int(scenario["seed"])
    return simulate_images(
        truth, plan, sensors, seed, scene, images_dir=images_dir, progress=on_frames
    ).log


#: kept for the chained commands: the same stage functions ``process`` uses
localize_log = localize_stage
select_samples = select_stage


def truth_metrics(truth, res_process, scenario: dict[str, Any]) -> dict[str, dict[str, float]]:
    """Simulation only: the map, Delaunay and (``[reconstruct] compare_constant_mean``) a
    constant-mean GP against the truth on the map grid (RMSE, coverage, ...); the map also
    on Delaunay's hull only (``gp_satellite_on_delaunay_hull``), like for like."""
    rec, grid = res_process.objects["reconstruction"], res_process.objects["grid"]
    truth_on_grid = truth.interp(x=grid.x, y=grid.y, method="linear").values
    maps = {"gp_satellite": rec.product, "delaunay": delaunay_linear(rec.samples, grid)}
    rc = scenario["reconstruct"]
    if rc["compare_constant_mean"]:
        gp = TerrainGP(
            mean="constant",
            method=rc["method"],
            max_fit_samples=int(rc["max_fit_samples"]),
            n_restarts=int(rc["n_restarts"]),
            anisotropy=anisotropy_option(rc["anisotropy"]),
            seed=int(scenario["seed"]),
        ).fit(rec.samples)
        maps["gp_constant"] = gp.predict_grid(grid)
    rel = rec.product["elevation_std_relative"].values
    shifted = rec.product["elevation"].values - float(_offset_error(rec, truth_on_grid))
    rows = {name: (ds["elevation"].values, ds.get("elevation_std")) for name, ds in maps.items()}
    rows["gp_satellite_relative_sigma"] = (shifted, rel)
    # like for like with Delaunay, which exists only inside the samples' hull (near data)
    hull = np.isfinite(maps["delaunay"]["elevation"].values)
    gp, gp_std = rows["gp_satellite"]
    rows["gp_satellite_on_delaunay_hull"] = (
        np.where(hull, gp, np.nan),
        None if gp_std is None else np.where(hull, np.asarray(gp_std), np.nan),
    )
    return {name: _against_truth(z, std, truth_on_grid) for name, (z, std) in rows.items()}


def _against_truth(z, std, truth_on_grid) -> dict[str, float]:
    """:func:`terrain.evaluate` in the certificate's sign: errors are map - truth (ASPRS:
    DEM - reference), so ``mean_error`` and ``z_mean`` read as the checkpoint block's bias
    and ``calibration.z_mean`` (terrain.metrics standardizes truth - map)."""
    std = None if std is None else np.asarray(std)
    row = evaluate(z, truth_on_grid, std)
    row["mean_error"] = float(np.nanmean(z - truth_on_grid))
    if "z_mean" in row:
        row["z_mean"] = -row["z_mean"]
    return row


def _offset_error(rec, truth_on_grid) -> float:
    """The map's mean error where it leans on the data (the shared survey offset's draw)."""
    err = rec.product["elevation"].values - truth_on_grid
    w = rec.product["elevation_std_relative"].values < np.nanpercentile(
        rec.product["elevation_std_relative"].values, 50
    )
    return float(np.nanmean(err[w]))


def run_scenario(
    config: str | Path | None = None,
    out: str | Path = "out/run",
    overrides: dict[str, Any] | None = None,
    on_stage: Callable[[str, str], None] | None = None,
    on_progress: Callable[[int, int], None] | None = None,
    on_frames: Callable[[int, int], None] | None = None,
) -> RunResult:
    """Simulate the scenario's survey, write it as field files, and process them.

    Parameters
    ----------
    config : path, optional
        Scenario TOML (see :mod:`toolkit.config`); default: the embedded scenario.
    out : path
        Output folder (created; must be writable). The simulated field files go to
        ``out/field`` (``glacimap process out/field/rover --prior out/field/prior.tif ...``
        reproduces the products from them).
    overrides : dict, optional
        Nested keys replacing those of the scenario (same validation).
    on_stage : callable, optional
        ``on_stage(stage, "start" | "done")`` for progress display.
    on_progress : callable, optional
        ``on_progress(k, K)`` during localization.
    on_frames : callable, optional
        ``on_frames(k, K)`` after each rendered frame (``[field] camera = "images"``).

    Returns
    -------
    RunResult
        As :func:`toolkit.process` returns, plus the truth metrics (m) and the simulated
        world (``.objects["truth"]``).
    """
    scenario = load_scenario(config, overrides)
    out = ensure_writable_dir(out)
    res = RunResult(out=out, settings=scenario)

    def timed(name: str, fn: Callable[[], Any]) -> Any:
        with res.stage(name, on_stage):
            return fn()

    truth = timed("plan", lambda: make_truth(scenario))
    site_scenario, scenario = scenario, survey_scenario(scenario)  # epoch 2: seed + offset
    res.settings = scenario
    plan = make_plan(scenario, truth)

    def _simulate():
        images = out / "field" / "rover" / "images"
        log = simulate_survey(scenario, truth, plan, images, on_frames)
        return write_field_survey(scenario, truth, log, out / "field", plan=plan)

    fresh = not (out / "field").exists()
    try:  # a failed or interrupted run leaves no half set of files, Ctrl-C included
        survey = timed("simulate", _simulate)  # interrupted while writing the field files too
        true_path = survey.log.truth["xyz"] + np.r_[survey.log.origin, 0.0]
        pres = process(
            survey.rover,
            prior=survey.prior,
            control=survey.control,
            checkpoints=survey.checkpoints,
            config=scenario,
            out=out,
            bounds=tuple(float(v) for v in scenario["site"]["bounds"]),
            on_stage=on_stage,
            on_progress=on_progress,
            truth=truth,
            truth_path=true_path,
        )
    except BaseException:
        if fresh:
            shutil.rmtree(out / "field", ignore_errors=True)
        raise
    res.timings.update(pres.timings)
    if scenario["change"]["epoch"] == 2:  # the outline and the true change beside the map
        write_change_truth(site_scenario, make_site(site_scenario), out)
    t = time.perf_counter()
    metrics = truth_metrics(truth, pres, scenario)
    loc = pres.objects["localization"]
    cert = pres.summary["certificate"]
    cert["scenario"] = scenario
    cert["truth_metrics"] = metrics
    # The simulation's truth of the localization (errors against the true path/landmarks).
    sim_log = survey.log
    cert["localization"]["simulation"] = _localization_truth(loc, sim_log)
    from .certify import write_certificate

    write_certificate(cert, out / "certificate.json")
    res.timings["evaluate"] = round(time.perf_counter() - t, 3)
    res.summary = {
        "seed": int(scenario["seed"]),
        "rmse_m": metrics["gp_satellite"]["rmse"],
        "metrics": metrics,
        "certificate": {k: cert[k] for k in cert if k not in ("scenario", "truth_metrics")},
        "timings_s": res.timings,
        "localization_timings_s": pres.summary.get("localization_timings_s", {}),
        "products": pres.products,  # what the next run into ``out`` may replace
    }
    if "site_dem" in truth.attrs:  # kind = "dem": the CRS, bounds and nodata, stated
        res.summary["site"] = json.loads(truth.attrs["site_dem"])
    with atomic_path(out / "summary.json") as tmp:
        tmp.write_text(json.dumps(res.summary, indent=2, default=_json_default))
    res.objects = {
        "truth": truth,
        "plan": plan,
        "log": sim_log,
        "field_survey": survey,
        "localization": loc,
        "selection": pres.objects["selection"],
        "reconstruction": pres.objects["reconstruction"],
        "maps": {"gp_satellite": pres.objects["reconstruction"].product},
    }
    return res


def _localization_truth(loc, sim_log: MeasurementLog) -> dict[str, Any]:
    """Errors of the processed (field-file) localization against the simulation's truth:
    keyframes matched by keyframe time (the field log keeps the rover clock), landmarks by
    id (:func:`toolkit.stages.landmark_truth_errors`: NEES, within 2 sigma, 3-D RMSE)."""
    if not sim_log.has_truth or loc.log.n_keyframes != sim_log.n_keyframes:
        return {}
    shift = np.r_[sim_log.origin - loc.log.origin, 0.0]  # the simulation's frame -> the log's
    err = loc.keyframe_xyz - (sim_log.truth["xyz"] + shift)
    out: dict[str, Any] = {
        "horizontal_rmse_m": float(np.sqrt((err[:, :2] ** 2).sum(1).mean())),
        "vertical_rmse_m": float(np.sqrt((err[:, 2] ** 2).mean())),
    }
    if "landmark_xyz" in sim_log.truth and loc.n_landmarks:
        truth = {
            "landmark_id": sim_log.truth["landmark_id"],
            "landmark_xyz": np.asarray(sim_log.truth["landmark_xyz"], float) + shift,
        }
        out.update(landmark_truth_errors(replace(loc, log=replace(loc.log, truth=truth))))
    return out
