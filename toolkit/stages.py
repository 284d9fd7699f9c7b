"""The stages every survey goes through, simulated or real: localize -> select -> reconstruct
-> certify. Typed inputs and outputs; no stage reads the truth.

``glacimap run`` (:func:`toolkit.pipeline.run_scenario`) writes a simulated survey as field
files and calls :func:`toolkit.process.process`, which chains these stages; ``glacimap
localize`` / ``reconstruct`` / ``certify`` call the same functions, so the chained commands
and ``process`` give the same products and the same 1-sigma (docs/pipeline.md).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from factorgraph.evaluate import frame_floor, horizontal_floor
from factorgraph.localize import LocalizeParams, localize
from factorgraph.log import MeasurementLog
from factorgraph.result import LocalizationResult
from factorgraph.select import LandmarkSelection, select_landmarks
from terrain import ElevationSamples, Grid, TerrainGP, cross_validate
from terrain.errors import InputError, bad_input

from .config import anisotropy_option
from .error_budget import heldout_along_track, heldout_slope_term, inflate_std

__all__ = [
    "Reconstruction",
    "certify_stage",
    "localization_summary",
    "localize_stage",
    "map_estimator",
    "map_grid",
    "reconstruct_selection",
    "reconstruct_stage",
    "select_stage",
]


def localize_stage(
    log: MeasurementLog,
    settings: dict[str, Any],
    control: Any = None,
    progress: Callable[[int, int], None] | None = None,
) -> LocalizationResult:
    """iSAM2 over ``log`` with the ``[localize]`` settings and optional ground control."""
    return localize(log, LocalizeParams(**settings["localize"]), progress=progress, control=control)


def select_stage(loc: LocalizationResult, settings: dict[str, Any]) -> LandmarkSelection:
    """The paper's landmark rules with the ``[select]`` settings (Eq 7)."""
    sel = settings["select"]
    return select_landmarks(
        loc,
        max_sigma=float(sel["max_sigma_m"]),
        min_first_seen_distance=float(sel["min_first_seen_distance_m"]),
        variance=sel["variance"],
        rule=sel["rule"],
    )


def map_grid(
    bounds: tuple[float, float, float, float] | None,
    resolution: float,
    crs: Any,
    samples: ElevationSamples | None = None,
) -> Grid:
    """The map grid: ``bounds`` (west, south, east, north; m) or, when None, the samples'
    bounding box snapped outwards to whole cells."""
    if bounds is None:
        if samples is None or samples.n == 0:
            raise bad_input("bounds", None, "map bounds or samples", "pass --bounds W S E N")
        extent = (*samples.xy.min(axis=0), *samples.xy.max(axis=0))
        what = "the samples' extent"
        lo = np.floor(samples.xy.min(axis=0) / resolution) * resolution
        hi = np.ceil(samples.xy.max(axis=0) / resolution) * resolution
        hi = np.maximum(hi, lo + resolution)
        bounds = (lo[0], lo[1], hi[0], hi[1])
    else:
        extent, what = bounds, "--bounds"
    if bounds is not None and samples is not None and samples.n > 0:
        w, s, e, n = (float(b) for b in bounds)
        x, y = samples.xy[:, 0], samples.xy[:, 1]
        if not ((x >= w) & (x <= e) & (y >= s) & (y <= n)).any():
            box = ", ".join(f"{v:.1f}" for v in (x.min(), y.min(), x.max(), y.max()))
            raise bad_input(
                "--bounds",
                f"({w:g}, {s:g}, {e:g}, {n:g})",
                f"a map extent (W S E N, m, {crs}) holding some of the {samples.n} samples "
                f"(their box: {box})",
                "check the order W S E N and that the bounds are in the survey's CRS",
            )
    grid = Grid.from_bounds(tuple(float(b) for b in bounds), float(resolution), crs)
    if min(grid.shape) < MIN_MAP_CELLS:  # a 1 x 1 map has no contours, mesh or slope
        w, s, e, n = (float(v) for v in extent)
        raise bad_input(
            "--resolution",
            f"{resolution:g} m",
            f"a cell size giving at least {MIN_MAP_CELLS} x {MIN_MAP_CELLS} cells over "
            f"{what} ({e - w:.4g} m x {n - s:.4g} m; this one gives {grid.ny} x {grid.nx})",
            f"pass --resolution {_finest_allowed(extent):g} or less, or wider --bounds",
        )
    return grid


#: Fewest cells along each axis of a map: contours, the mesh and the report's figures need
#: at least 2 x 2 (a 1 x 1 map from ``--resolution`` larger than the site was fitted and
#: then failed in the mesh export).
MIN_MAP_CELLS = 2


def _finest_allowed(bounds: tuple[float, float, float, float]) -> float:
    """The largest cell size (rounded down to 2 significant digits) giving 2 x 2 cells."""
    w, s, e, n = (float(b) for b in bounds)
    size = min(e - w, n - s) / MIN_MAP_CELLS
    if size <= 0:
        return 0.0
    digits = 10 ** (np.floor(np.log10(size)) - 1)
    return float(np.floor(size / digits) * digits)


@dataclass
class Reconstruction:
    """What the reconstruct stage made: the product and how it was made."""

    product: Any  # xarray.Dataset: elevation, elevation_std, elevation_std_relative
    gp: TerrainGP
    samples: ElevationSamples
    heldout: Any = None  # terrain.CrossValidation
    extra: dict[str, Any] = field(default_factory=dict)


def map_estimator(mean: Any, grid: Grid, settings: dict[str, Any], seed: int) -> TerrainGP:
    """The map's GP, unfitted: ``mean`` (a :class:`terrain.RasterMean` bound to ``grid``:
    its coarse cells cover the map, not the samples) and the ``[reconstruct]`` settings
    (``method``, ``max_fit_samples``, ``n_restarts``, ``anisotropy``); the kernel by
    evidence (the terrain layer's default: the family member with the best BIC)."""
    rc = settings["reconstruct"]
    if hasattr(mean, "for_grid"):
        mean.for_grid(grid)
    return TerrainGP(
        mean=mean,
        method=rc["method"],
        max_fit_samples=int(rc["max_fit_samples"]),
        n_restarts=int(rc["n_restarts"]),
        anisotropy=anisotropy_option(rc["anisotropy"]),
        seed=seed,
    )


def reconstruct_stage(
    samples: ElevationSamples,
    grid: Grid,
    mean: Any,
    settings: dict[str, Any],
    seed: int,
    landmark_xy: np.ndarray | None = None,
    landmark_rel_z_std: np.ndarray | None = None,
    shared_z_std: float = 0.0,
    heldout_folds: int = 5,
    landmark_t_s: np.ndarray | None = None,
    shared_xy_std: tuple[float, float] | None = None,
    horizontal_sd: float | None = None,
    fitted: TerrainGP | None = None,
) -> Reconstruction:
    """The GP map (the terrain layer's defaults: kernel by evidence) with its error budget.

    Parameters
    ----------
    samples : ElevationSamples
        Selected landmarks as terrain samples (``z_var``: relative vertical variance, m^2).
    grid : Grid
        Map cells, in the samples' CRS.
    mean : prior mean
        A :class:`terrain.RasterMean` (satellite DEM file), ``"constant"``, or any mean
        :class:`terrain.TerrainGP` accepts.
    settings : dict
        The ``[reconstruct]`` table: ``method``, ``max_fit_samples``, ``n_restarts``.
    seed : int
        The one seed.
    landmark_xy, landmark_rel_z_std : ndarray, optional
        Landmarks and their relative vertical 1-sigma (m) for the along-track error term
        (:mod:`toolkit.error_budget`); default: the samples and ``sqrt(z_var)``.
    shared_z_std : float
        1-sigma of the survey's map-wide vertical offset (m), stated once in the product.
    heldout_folds : int
        Spatial-block folds of :func:`terrain.cross_validate` (0: skip the held-out check).
    landmark_t_s : ndarray, optional
        The landmarks' mean observation times (s) for the along-track term's time
        correlation; default: the samples' ``extra["t_s"]`` when ``landmark_xy`` is not given.
    shared_xy_std : (float, float), optional
        1-sigma of the survey's map-wide horizontal offset, east and north (m): its error
        through the map's slope joins both 1-sigmas (:func:`toolkit.error_budget.inflate_std`).
    horizontal_sd : float, optional
        The samples' own horizontal 1-sigma (m; digitised contours): through the map's slope
        into both 1-sigmas and into the held-out check (:func:`toolkit.error_budget.
        heldout_slope_term`).
    fitted : TerrainGP, optional
        The map's GP already fitted on ``samples`` with ``mean`` and these settings (the
        DEM reading's choice fits it: :mod:`toolkit.prior_reading`); not fitted again.

    Returns
    -------
    Reconstruction
        ``product`` has ``elevation``, ``elevation_std`` (total: GP + along-track + shared
        offset) and ``elevation_std_relative`` (the map's own: without the shared offset, so
        data gaps show), all in metres.
    """
    gp = fitted if fitted is not None else map_estimator(mean, grid, settings, seed)
    prior_note = prior_coarsening_note(gp.mean)
    if fitted is None:
        gp.fit(samples)
    if landmark_xy is None:
        landmark_xy = samples.xy
        if landmark_rel_z_std is None:
            landmark_rel_z_std = np.sqrt(samples.z_var)
        if landmark_t_s is None:
            landmark_t_s = samples.extra.get("t_s")
    from terrain.gp_mean import n_coef

    scale_note = (getattr(gp.mean_, "scale_check_", None) or {}).get("note")
    prior_note = "; ".join(n for n in (prior_note, scale_note) if n) or None
    fitted_offset = n_coef(gp.mean_) > 0  # the prior's datum offset is fitted to the samples
    product = inflate_std(
        gp.predict_grid(grid),
        gp,
        landmark_xy,
        landmark_rel_z_std,
        shared_z_std,
        shared_everywhere=fitted_offset,
        landmark_t_s=landmark_t_s,
        shared_xy_std=shared_xy_std,
        horizontal_sd=horizontal_sd,
    )
    product.attrs.update(
        {
            "seed": int(seed),
            "shared_vertical_offset_std_m": float(shared_z_std),
            "n_landmarks_selected": int(samples.n),
            "predict_route": str(getattr(gp, "predict_route_", "")),
        }
    )
    heldout, why = None, "heldout_folds = 0"
    if heldout_folds:
        try:
            along = heldout_along_track(
                gp, samples.xy, landmark_xy, landmark_rel_z_std, landmark_t_s
            )
            if horizontal_sd:  # the check is of the 1-sigma the product states
                along = _summed(along, heldout_slope_term(gp, product, horizontal_sd))
            heldout = cross_validate(
                gp,
                samples,
                n_folds=int(heldout_folds),
                seed=seed,
                targets=grid,
                extra_variance=along,
            )
            why = ""
        except InputError as exc:  # too few samples or blocks: said, not fatal
            why = str(exc)
    product.attrs["heldout_check"] = (
        "spatial block CV" if heldout is not None else f"skipped: {why}"
    )
    if prior_note:
        product.attrs["prior_note"] = prior_note
    return Reconstruction(product=product, gp=gp, samples=samples, heldout=heldout)


def _summed(*hooks: Any) -> Any:
    """One ``extra_variance`` hook of :func:`terrain.cross_validate` adding ``hooks``."""

    def extra(train: np.ndarray, query: np.ndarray, var_f: np.ndarray) -> np.ndarray:
        return np.sum([h(train, query, var_f) for h in hooks], axis=0)

    return extra


def prior_coarsening_note(mean: Any) -> str | None:
    """A note when a bound :class:`terrain.RasterMean` with ``cells`` given (e.g. the
    paper's coarse 8 x 8) averages a DEM whose own cells are at least
    :data:`terrain.raster_mean.AUTO_OWN_FACTOR` times finer: its resolution is thrown away
    (a 31 m DEM over a 3.7 km map: 472 m cells), where ``cells="auto"`` would have kept it.
    ``None`` otherwise (the default site: a 75 m prior into 8 x 8 cells of 75 m)."""
    from terrain.raster_mean import AUTO_OWN_FACTOR

    sizes = mean.coarse_and_own_cell_m() if hasattr(mean, "coarse_and_own_cell_m") else None
    if sizes is None or sizes[0] < AUTO_OWN_FACTOR * sizes[1]:
        return None
    coarse, own = sizes
    ny, nx = mean.cells
    return (
        f"the prior DEM's {own:.0f} m cells are averaged into {ny} x {nx} cells of "
        f"{coarse:.0f} m over this map (the paper's coarse satellite prior, [prior] cells); "
        "set [prior] cells = [] to use the DEM's own resolution"
    )


def reconstruct_selection(
    sel: Any,
    grid: Grid,
    mean: Any,
    settings: dict[str, Any],
    seed: int,
    heldout_folds: int,
    samples: ElevationSamples | None = None,
    fitted: TerrainGP | None = None,
) -> Reconstruction:
    """:func:`reconstruct_stage` on a :func:`select_stage` result: its samples (or
    ``samples``: them and more, e.g. a DEM's cells as data), with the kept landmarks'
    relative vertical 1-sigma (shared offset removed, Eq 7) for the along-track term and
    the survey's shared vertical 1-sigma; ``fitted``: the GP already fitted on them."""
    kept = sel.table["kept"]
    return reconstruct_stage(
        sel.samples if samples is None else samples,
        grid,
        mean,
        settings,
        seed,
        landmark_xy=np.column_stack([sel.table["x"][kept], sel.table["y"][kept]]),
        landmark_rel_z_std=sel.table["z_std_m"][kept],
        shared_z_std=float(sel.shared_offset_std_m[2]),
        shared_xy_std=(float(sel.shared_offset_std_m[0]), float(sel.shared_offset_std_m[1])),
        heldout_folds=heldout_folds,
        landmark_t_s=sel.table["t_s"][kept] if "t_s" in sel.table else None,
        fitted=fitted,
    )


def certify_stage(
    rec: Reconstruction,
    checkpoints: Any,
    settings: dict[str, Any],
    seed: int,
) -> dict[str, Any]:
    """Certify ``rec.product`` against independent checkpoints (none: held-out check only).

    Returns the certificate dict (:func:`toolkit.certify.certify`) with the kernel chosen by
    evidence and its rivals under ``reconstruction``.
    """
    from .breakline_record import breakline_block
    from .certify import certify, heldout_block

    cfg = settings["certify"]
    product = rec.product
    note = product.attrs.get("prior_note")
    if checkpoints is not None:
        cert = certify(
            product, checkpoints, seed=seed, n_boot=int(cfg["n_boot"]), heldout=rec.heldout
        )
    else:  # no checkpoints: the map's sigma is still checked on held-out samples
        cert = {"seed": int(seed), "checkpoints": None, "warnings": ["no checkpoints given"]}
        if rec.heldout is not None:
            cert["heldout_calibration"] = heldout_block(rec.heldout)
        cert.update(breakline_block(product.attrs))  # the cliffs the map was fitted with
    if note:  # stated with the certificate's warnings (printed by run / process)
        cert.setdefault("warnings", []).append(note)
    if product.attrs.get("tiling_warning"):  # the tiles could not hold a long part
        cert.setdefault("warnings", []).append(product.attrs["tiling_warning"])
    cert["reconstruction"] = {
        "kernel": product.attrs.get("kernel"),
        "kernel_selection": json.loads(product.attrs.get("kernel_selection", "[]")),
        "anisotropy": json.loads(product.attrs.get("anisotropy", "{}")),
        "mean_function": product.attrs.get("mean_function"),
        "mean_coefficients": json.loads(product.attrs.get("mean_coefficients", "{}")),
        "predict_route": product.attrs.get("predict_route"),
        "shared_vertical_offset_std_m": product.attrs.get("shared_vertical_offset_std_m"),
    }
    if product.attrs.get("prior_as_data"):  # the DEM's cells were samples, not the mean
        cert["reconstruction"]["prior_as_data"] = product.attrs["prior_as_data"]
    if product.attrs.get("prior_reading"):  # --prior-as auto: the choice and its scores
        cert["reconstruction"]["prior_reading"] = json.loads(product.attrs["prior_reading"])
    return cert


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
            # what kept the online pass going, by kind (factorgraph.rebuild.OnlineGuard)
            "isam2_recovery": dict((loc.refine or {}).get("isam2_recovery", {})),
            # wrong associations cut after the refinement (factorgraph.view_gate)
            "view_gate": {
                k: v
                for k, v in (loc.refine or {}).get("view_gate", {}).items()
                if k != "removed_ids"  # the ids are in landmarks.csv (reason)
            },
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
    if getattr(loc, "control", None):
        out["control"] = loc.control  # which ground control was used, and its residuals
    if "landmark_xyz" in log.truth and loc.n_landmarks:
        out.update(landmark_truth_errors(loc))
    return out


def landmark_truth_errors(loc: LocalizationResult) -> dict[str, Any]:
    """Simulation only: every landmark in the graph against its log's truth (by id).

    ``landmark_nees_mean`` (3-D, full marginal; expected 3), ``landmark_within_2sigma``
    (share with NEES under the chi2(3) 95.45 % quantile), ``landmark_rmse_3d_m`` (m) and
    ``landmarks_without_truth`` (image tracks whose reference ray met the sky)."""
    e = loc.landmark_xyz - loc.true_landmarks()
    known = np.isfinite(e).all(axis=1)
    e, cov = e[known], loc.landmark_cov[known]
    nees = np.einsum("ni,ni->n", e, np.linalg.solve(cov, e[..., None])[..., 0])
    return {
        "landmark_nees_mean": float(nees.mean()) if nees.size else None,
        "landmark_within_2sigma": float(np.mean(nees <= 8.025)) if nees.size else None,
        "landmark_rmse_3d_m": float(np.sqrt((e**2).sum(1).mean())) if nees.size else None,
        "landmarks_without_truth": int((~known).sum()),
    }
