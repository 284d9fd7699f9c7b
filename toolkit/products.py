"""Write a certified map's products into a folder: the same set for ``glacimap run``,
``glacimap process`` and the chained commands.

``certificate.json``, ``product.nc`` (CF, with ``elevation``, ``elevation_std`` and
``elevation_std_relative``), ``elevation.tif`` (COG, a band each), ``contours.gpkg``
(+ ``.geojson``), ``mesh.ply/.vtp/.png``, ``survey.gpkg`` (trajectory and landmarks),
``trajectory.csv``, ``landmarks.csv``, ``samples.csv`` and ``report.html``.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any

import numpy as np

from factorgraph.result import LocalizationResult
from factorgraph.select import LandmarkSelection
from terrain.atomic import atomic_path

from .stages import Reconstruction

__all__ = [
    "contour_interval",
    "landmark_table",
    "samples_table",
    "trajectory_table",
    "write_csv",
    "write_map_products",
    "write_products",
]


def trajectory_table(loc: LocalizationResult) -> dict[str, np.ndarray]:
    """One row per keyframe: ``k, t_s``, final estimate ``x, y, z`` (projected CRS, m), its
    marginal 1-sigma ``std_x, std_y, std_z`` (m), the online estimate ``online_x, online_y,
    online_z``, the estimated GPS bias ``bias_x, bias_y, bias_z`` (bias model), in
    simulation the truth ``true_x, true_y, true_z``, and ``crs`` (of x, y, on every row)."""
    log = loc.log
    est = loc.to_projected(loc.keyframe_xyz)
    online = loc.to_projected(loc.online_xyz)
    std = np.sqrt(np.clip(np.diagonal(loc.pose_cov_xyz, axis1=1, axis2=2), 0.0, None))
    out: dict[str, np.ndarray] = {"k": np.arange(log.n_keyframes), "t_s": log.t}
    for prefix, arr in (("", est), ("std_", std), ("online_", online)):
        for i, a in enumerate("xyz"):
            out[f"{prefix}{a}"] = arr[:, i]
    if loc.gps_bias is not None:
        for i, a in enumerate("xyz"):
            out[f"bias_{a}"] = loc.gps_bias[:, i]
    if log.has_truth:
        true = loc.to_projected(log.truth["xyz"])
        for i, a in enumerate("xyz"):
            out[f"true_{a}"] = true[:, i]
    out["crs"] = _crs_column(log.crs, log.n_keyframes)  # as samples.csv: never guessed
    return out


def _crs_column(crs: Any, n: int) -> np.ndarray:
    """The CRS of a table's x, y, one value per row (a GIS import reads it from the file)."""
    text = "" if crs is None else (crs if isinstance(crs, str) else crs.to_string())
    return np.full(n, text)


def landmark_table(loc: LocalizationResult, sel: LandmarkSelection) -> dict[str, np.ndarray]:
    """One row per landmark in the graph: the selection's diagnostics (``landmark_id, x, y, z,
    sigma_max_m, sigma_max_full_m, z_std_m, first_seen_distance_m, n_views, kept, reason``)
    and, in simulation, the true position ``true_x, true_y, true_z`` (projected CRS, m);
    ``crs`` (of x, y, on every row)."""
    out = dict(sel.table)
    if "landmark_xyz" in loc.log.truth and loc.n_landmarks:
        true = loc.to_projected(loc.true_landmarks())
        for i, a in enumerate("xyz"):
            out[f"true_{a}"] = true[:, i]
    out["crs"] = _crs_column(loc.log.crs, len(out["x"]))
    return out


def samples_table(sel: LandmarkSelection) -> dict[str, np.ndarray]:
    """The selected landmarks as terrain samples ``x, y, z, z_var`` (m, m^2) plus what the
    error budget needs (:mod:`toolkit.error_budget`): ``track_z_std_m`` (relative vertical
    1-sigma, m), the survey's ``shared_offset_std_m`` (m, one value repeated) and, when the
    selection has it, ``t_s``: the landmark's mean observation time (s, the log's clock; the
    along-track correlation of :mod:`terrain.along_track`). It is the table ``glacimap
    reconstruct SAMPLES.csv`` and ``glacimap change`` read, so the chained commands give the
    same 1-sigma as ``glacimap run`` / ``process``."""
    from .samples_io import SampleTable, sample_columns

    s, kept = sel.samples, sel.table["kept"]
    track = sel.table["z_std_m"][kept] if kept.sum() == s.n else np.sqrt(s.z_var)
    shared = float(sel.shared_offset_std_m[2])
    return sample_columns(SampleTable(s, track, shared, ""))


def write_csv(path: Path, table: dict[str, np.ndarray]) -> Path:
    """A dict of equal-length columns as CSV (header row), atomically; a cell with a comma
    or a quote (a CRS without an EPSG code is WKT) is quoted (``csv`` module, RFC 4180)."""
    cols = list(table)
    rows = np.column_stack([np.asarray(table[c]).astype(str) for c in cols])
    with atomic_path(path) as tmp:
        with open(tmp, "w", encoding="utf-8", newline="") as f:
            out = csv.writer(f, lineterminator="\n")
            out.writerow(cols)
            out.writerows(rows.tolist())
    return path


def contour_interval(
    cert: dict[str, Any], fallback_rmse_m: float | None, shared_offset_std_m: float = 0.0
) -> float:
    """The certified interval, or (no checkpoints) 3 x the expected RMSE_z rounded up to a
    conventional interval (ASPRS 1990 Class 1, CI = 3 RMSE_z), stated as uncertified.

    Without checkpoints the expected RMSE_z is ``sqrt(heldout_rmse^2 + shared^2)``: the
    held-out RMSE (m) only measures the map against its own samples, which all carry the
    survey's shared vertical offset (1-sigma ``shared_offset_std_m``, m), and a checkpoint
    would see both. The example field folder (consumer GPS, 2.5 m bias) got 0.1 m contours
    from its held-out RMSE alone."""
    from .certify import CONVENTIONAL_INTERVALS_M

    ci = (cert.get("contour_interval") or {}).get("certified_m")
    if ci:
        return float(ci)
    heldout = float(fallback_rmse_m or 1.0)
    shared = float(shared_offset_std_m or 0.0)
    rmse = math.hypot(heldout, shared)
    ci = next((c for c in CONVENTIONAL_INTERVALS_M if c >= 3 * rmse), 3 * rmse)
    cert["contour_interval"] = {
        "certified_m": None,
        "uncertified_m": float(ci),
        "expected_rmse_m": rmse,
        "basis": (
            f"3 x sqrt(held-out RMSE^2 + shared vertical offset 1-sigma^2) = 3 x "
            f"sqrt({heldout:.3g}^2 + {shared:.3g}^2) m, rounded up to a conventional interval "
            "(no checkpoints: not certified)"
        ),
    }
    return float(ci)


def write_map_products(
    out: Path,
    rec: Reconstruction,
    cert: dict[str, Any] | None,
    settings: dict[str, Any],
    truth_on_grid: Any = None,
    samples_xy: np.ndarray | None = None,
    trajectory: dict[str, Any] | None = None,
    coverage: dict[str, Any] | None = None,
) -> dict[str, Path]:
    """The map's products in ``out``: ``product.nc``, ``elevation.tif`` (COG: elevation,
    total and relative 1-sigma), contours, mesh and, with a certificate, ``certificate.json``
    and ``report.html``. Without checkpoints the contour interval is 3 x the held-out RMSE,
    marked uncertified."""
    from .certify import write_certificate
    from .export import write_cog, write_contours, write_mesh, write_netcdf
    from .report import write_report

    product = rec.product
    heldout_rmse = None if rec.heldout is None else rec.heldout.pooled["rmse_m"]
    cert = cert if cert is not None else {}
    shared = float(product.attrs.get("shared_vertical_offset_std_m", 0.0) or 0.0)
    interval = contour_interval(cert, heldout_rmse, shared)
    paths: dict[str, Path] = {}
    certified = bool(cert.get("accuracy") or cert.get("heldout_calibration"))
    if certified:
        paths["certificate"] = write_certificate(cert, out / "certificate.json")
    paths["product"] = write_netcdf(product, out / "product.nc")
    paths["cog"] = write_cog(product, out / "elevation.tif")
    exp = settings["export"]
    geojson = out / "contours.geojson" if exp["geojson"] else None
    write_contours(product, out / "contours.gpkg", interval, geojson)
    paths["contours"] = out / "contours.gpkg"
    if exp["mesh"]:
        write_mesh(product, out / "mesh.ply", out / "mesh.vtp", out / "mesh.png")
    if certified and cert.get("accuracy"):  # the HTML certificate needs checkpoints
        paths["report"] = write_report(
            out / "report.html",
            product=product,
            certificate=cert,
            truth=truth_on_grid,
            samples=rec.samples if samples_xy is None else samples_xy,
            trajectory=trajectory,
            coverage=coverage,
        )
    return paths


#: The fields of ``survey.gpkg``'s layers, stated in its layer metadata (``fields``).
SURVEY_FIELDS = (
    "trajectory: kind = 'estimated' (iSAM2 keyframes) or 'true' (simulation only); x, y in the "
    "layer CRS, m. landmarks: x, y, z (m; z a height on the vertical datum), landmark_id; "
    "z_std = the elevation 1-sigma the map uses as the sample's noise, relative to the survey "
    "(its shared vertical offset excluded, stated once in the map), m; sigma_max = largest "
    "relative 1-sigma semi-axis of the position, m; n_views = camera views; kept = selected "
    "for the map by the [select] rules (the reason for each rejection is in landmarks.csv)"
)


def write_products(
    out: Path,
    rec: Reconstruction,
    cert: dict[str, Any],
    loc: LocalizationResult,
    sel: LandmarkSelection,
    settings: dict[str, Any],
    truth_on_grid: Any = None,
    truth_path: np.ndarray | None = None,
) -> dict[str, Path]:
    """Every product of a processed survey in ``out``: the map's
    (:func:`write_map_products`) plus ``survey.gpkg`` (trajectory, landmarks),
    ``trajectory.csv``, ``landmarks.csv`` and ``samples.csv``.

    ``truth_on_grid`` and ``truth_path`` ((n, 3) projected true keyframe positions) are for
    simulation only: the report's error map and calibration curve, the true path layer.
    """
    from .export import VectorLayer, write_vector_layers
    from .export._product import provenance_strings

    est = loc.to_projected(loc.keyframe_xyz)
    t = sel.table
    lines, kinds = [est], ["estimated"]
    if truth_path is None and loc.log.has_truth:
        truth_path = loc.to_projected(loc.log.truth["xyz"])
    if truth_path is not None:
        lines.append(np.asarray(truth_path, float))
        kinds.append("true")
    layers = {
        "trajectory": VectorLayer.lines(lines, kind=np.array(kinds)),
        "landmarks": VectorLayer.points(
            np.column_stack([t["x"], t["y"], t["z"]]),
            landmark_id=t["landmark_id"],
            z_std=t["z_std_m"],
            sigma_max=t["sigma_max_m"],
            n_views=t["n_views"],
            kept=t["kept"],
        ),
    }
    # what each field is and in which unit, with the map's provenance (seed, inputs and
    # their SHA-256, software, vertical datum): the layers said nothing of either
    meta = {
        **provenance_strings(rec.product.attrs),
        "fields": SURVEY_FIELDS,
        "vertical_datum": str(rec.product.attrs.get("vertical_datum", "not stated")),
    }
    paths = {"survey": write_vector_layers(out / "survey.gpkg", layers, loc.log.crs, metadata=meta)}
    write_csv(out / "trajectory.csv", trajectory_table(loc))
    write_csv(out / "landmarks.csv", landmark_table(loc, sel))
    write_csv(out / "samples.csv", samples_table(sel))
    trajectory = {
        "xy_est": est[:, :2],
        "xy_true": lines[1][:, :2] if len(lines) > 1 else None,
        "cov_xy": loc.pose_cov_xyz[:, :2, :2],
        "landmarks_xy": sel.samples.xy,
    }
    loc_summary = cert.get("localization", {})
    coverage = {k: v for k, v in loc_summary.items() if np.isscalar(v)}
    paths.update(
        write_map_products(
            out, rec, cert, settings, truth_on_grid, sel.samples, trajectory, coverage
        )
    )
    return paths
