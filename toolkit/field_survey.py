"""A simulated survey written as the files a field team brings home, for :func:`process`.

``glacimap run`` makes the world (truth, plan, traverse) and then hands :func:`process` the
same kinds of files a real survey has, so that both take one road (docs/pipeline.md):

``rover/``
    The rover's field folder (docs/field-format.md): GPS as NMEA GGA/RMC/GST (or GPX /
    RTKLIB ``.pos``), odometry and tilt CSV on the rover clock, the camera as OpenCV YAML,
    feature tracks, ``survey.json``.
``prior.tif``
    A satellite DEM with realistic error: the truth block-averaged to ``[prior]
    resolution_m`` cells, shifted by a vertical datum offset ``offset_m`` and with an
    independent error of ``noise_sd_m`` per cell (seeded).
``checkpoints.csv``
    ``[certify] n_checkpoints`` independent points at random places in the site (seeded),
    heights from the truth, with a ``crs`` column.
``control.csv``
    Only with ``[control] n_targets > 0``: 4 control points at the survey's corners, surveyed
    with ``[control] sigma_m`` (factorgraph.control_sim). ``[control] mode``: ``"stops"``
    (the rover stands on them where the lawnmower turns; the stop keyframes go into
    ``rover/stops.csv``), ``"targets"`` (marked targets 6 m outside the corners that the
    camera tracks, ``target_id`` in the CSV) or ``"both"`` (8 points).
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from factorgraph.log import MeasurementLog
from terrain import Grid
from terrain.atomic import atomic_path, ensure_writable_dir
from terrain.sampling import sample_dem

__all__ = ["FieldSurvey", "simulated_control", "simulated_prior", "write_field_survey"]


@dataclass
class FieldSurvey:
    """Paths of a survey's files (``control`` None when there is no ground control)."""

    rover: Path
    prior: Path
    checkpoints: Path
    control: Path | None
    log: MeasurementLog  # the simulated log (truth kept for evaluation only)


def simulated_prior(truth, resolution_m: float, offset_m: float, noise_sd_m: float, rng):
    """The truth block-averaged to ``resolution_m`` cells over its extent, extended by one
    cell on every side, plus a constant ``offset_m`` and independent ``N(0, noise_sd_m^2)``
    per cell (``xarray.DataArray``, m).

    A satellite DEM covers more than the survey: without the margin a landmark estimated
    a few decimetres outside the site (seed 1000 of the default scenario: 0.8 m) fell off
    the prior. The margin cells continue the edge linearly (odd reflection)."""
    from terrain import coarse_dem
    from terrain.grid import north_up

    grid = Grid.from_dataarray(truth)
    w, s, e, n = grid.bounds
    cells = (max(1, round((n - s) / resolution_m)), max(1, round((e - w) / resolution_m)))
    dem = north_up(coarse_dem(truth, cells=cells))
    core = Grid.from_dataarray(dem)
    values = np.asarray(dem.values, float)
    mode = "reflect" if min(values.shape) >= 2 else "edge"
    kw = {"reflect_type": "odd"} if mode == "reflect" else {}
    values = np.pad(values, 1, mode=mode, **kw)
    (dx, dy), (cw, _, _, cn) = core.resolution, core.bounds
    big = Grid(cw - dx, cn + dy, (dx, dy), values.shape, core.crs)
    noise = rng.normal(0.0, float(noise_sd_m), values.shape) if noise_sd_m > 0 else 0.0
    own = {k: v for k, v in dem.attrs.items() if k not in big.attrs() and k != "units"}
    return big.data_array(values + float(offset_m) + noise, "elevation", **own)


def simulated_control(scenario: dict[str, Any], truth, log: MeasurementLog, plan=None):
    """The ``[control]`` ground control of a simulated survey: ``(log, ControlPoints)``, or
    ``(log, None)`` with ``n_targets = 0``.

    ``n_targets = 8`` (``mode = "stops"`` only): the rover stops at every turn, the keyframes
    nearest the ``plan``'s waypoints (a 4-swath lawnmower: both ends of every swath; a plan
    with more waypoints: 8 spread evenly along them).

    ``mode = "stops"``: the rover stands on 4 points at the corners of its path (the
    keyframes nearest the corners of its bounding box, ``control_sim.path_corners``; the
    log's ``control_id`` names them); ``"targets"``: 4 marked targets 6 m outside those
    corners, tracked by the camera (``target_id``); ``"both"``: the 8 points. Survey 1-sigma
    ``sigma_m`` per axis, centring 1-sigma 2 cm (``read_control``'s default, so that the CSV
    read back states the same). The draws have their own streams (children 1 and 2 of the
    seed): the traverse is untouched.
    """
    from factorgraph.control import ControlPoints
    from factorgraph.control_sim import (
        nearest_keyframes,
        path_corners,
        simulate_control,
        simulate_targets,
    )
    from terrain.errors import bad_input

    c, seed = scenario["control"], int(scenario["seed"])
    n, mode, sigma = int(c["n_targets"]), str(c.get("mode", "stops")), float(c["sigma_m"])
    if n == 0:
        return log, None
    if n not in (4, 8):
        raise bad_input("control.n_targets", c["n_targets"], "0, 4 or 8", "4: the corners")
    if mode not in ("stops", "targets", "both"):
        raise bad_input("control.mode", mode, "stops|targets|both", 'e.g. mode = "stops"')
    if n == 8:
        if mode != "stops" or plan is None:
            raise bad_input("control.n_targets", 8, 'mode = "stops" with a plan', "or 4")
        wp = np.asarray(plan.waypoints, float)
        wp = wp[np.round(np.linspace(0, len(wp) - 1, min(8, len(wp)))).astype(int)]
        ks = nearest_keyframes(log, wp)
        if len(set(ks.tolist())) < len(ks):
            raise bad_input("control.n_targets", 8, "8 distinct turns in the plan", "use 4")
        return simulate_control(log, ks, sigma_m=sigma, centring_sigma_m=0.02, seed=seed)[:2]
    parts = []
    if mode in ("targets", "both"):
        log, targets, _ = simulate_targets(log, truth, sigma_m=sigma, seed=seed)
        parts.append(targets)
    if mode in ("stops", "both"):
        corners = path_corners(log)
        if len(set(corners.tolist())) < len(corners):  # a single straight swath
            raise bad_input(
                "control.n_targets",
                n,
                f"a path with 4 distinct corners (the nearest keyframes: {corners.tolist()})",
                "survey 2 or more swaths ([plan] n_swaths), or n_targets = 0",
            )
        log, stops, _ = simulate_control(
            log, corners, sigma_m=sigma, centring_sigma_m=0.02, seed=seed
        )
        parts.append(stops)
    if len(parts) == 1:
        return log, parts[0]
    return log, ControlPoints(
        np.concatenate([p.ids for p in parts]),
        np.vstack([p.xyz for p in parts]),
        np.vstack([p.sigma for p in parts]),
        parts[0].crs,
        np.concatenate([p.target_id for p in parts]),
        0.02,
        "simulated",
    )


def _write_geotiff(da, path: Path) -> Path:
    import rasterio

    grid = Grid.from_dataarray(da)
    with atomic_path(path) as tmp:
        profile = {
            "driver": "GTiff",
            "width": grid.nx,
            "height": grid.ny,
            "count": 1,
            "dtype": "float32",
            "crs": grid.crs.to_wkt(),
            "transform": grid.transform,
            "nodata": np.nan,
        }
        with rasterio.open(tmp, "w", **profile) as dst:
            dst.write(np.asarray(da.values, dtype=np.float32)[None])
            dst.update_tags(source="glacimap simulated satellite DEM", units="m")
    return path


def _write_checkpoints(truth, bounds, n: int, rng, path: Path) -> Path:
    grid = Grid.from_dataarray(truth)
    w, s, e, nn = bounds
    lo = np.maximum([w, s], [grid.x[0], grid.y[-1]])
    hi = np.minimum([e, nn], [grid.x[-1], grid.y[0]])
    xy = rng.uniform(lo, hi, (n, 2))
    z = sample_dem(truth, xy)
    crs = grid.crs.to_string()
    with atomic_path(path) as tmp:
        with open(tmp, "w", encoding="utf-8", newline="") as f:
            out = csv.writer(f, lineterminator="\n")  # a WKT crs (no EPSG code) is quoted
            out.writerow(["id", "x", "y", "z", "crs"])
            for i, (x, y, h) in enumerate(zip(xy[:, 0], xy[:, 1], z, strict=True)):
                out.writerow([f"CP{i + 1}", f"{x:.4f}", f"{y:.4f}", f"{h:.4f}", crs])
    return path


def write_field_survey(
    scenario: dict[str, Any], truth, log: MeasurementLog, folder: str | Path, plan=None
) -> FieldSurvey:
    """Write the simulated survey ``log`` over ``truth`` as field files into ``folder``
    (``plan``: the survey plan, for ``[control] n_targets = 8``, stops at every turn).

    The draws (prior error, checkpoints) come from their own stream of the scenario's seed
    (child 3 of its ``SeedSequence``), so they do not change the traverse.
    """
    from factorgraph.field import write_field_log

    folder = ensure_writable_dir(folder)
    seed = int(scenario["seed"])
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(3,)))
    p = scenario["prior"]
    prior = simulated_prior(
        truth, float(p["resolution_m"]), float(p["offset_m"]), float(p["noise_sd_m"]), rng
    )
    cps = _write_checkpoints(
        truth,
        tuple(float(v) for v in scenario["site"]["bounds"]),
        int(scenario["certify"]["n_checkpoints"]),
        rng,
        folder / "checkpoints.csv",
    )
    control_path = None
    log, ctrl = simulated_control(scenario, truth, log, plan)
    if ctrl is not None:
        control_path = ctrl.write_csv(folder / "control.csv")
    else:
        (folder / "control.csv").unlink(missing_ok=True)  # no stale control from a rerun
    rover = write_field_log(
        log, folder / "rover", gps_format=scenario["field"]["gps_format"], crs=log.crs
    )
    return FieldSurvey(
        rover=rover,
        prior=_write_geotiff(prior, folder / "prior.tif"),
        checkpoints=cps,
        control=control_path,
        log=log,
    )
