"""Accuracy certificate of a DEM against independent checkpoints (docs/architecture.md §1 step 6).

The certificate is a plain JSON-ready dict: vertical RMSE with a seeded bootstrap 95 %
interval, bias, spread, NSSDA Accuracy_z, the contour interval the accuracy supports, one
verdict per standard (:func:`survey.standards.verdicts`), the calibration of the 1-sigma band
at the checkpoints, what was dropped and why, the seed and the software versions. It holds no
wall-clock time unless one is passed in: the same inputs give the same bytes.

One sign convention throughout: errors are ``map - checkpoint`` (DEM minus checkpoint,
metres; a positive bias means the map is too high), and z-scores are that error over its
1-sigma, ``(map - checkpoint) / sigma`` (a positive mean z: the map is too high as well).
Checkpoints in another CRS than the DEM (EPSG:4326 included) are reprojected to the DEM's
with pyproj; the certificate says so.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from survey import standards
from terrain.atomic import atomic_path
from terrain.dem_projection import in_metres
from terrain.errors import InputError, bad_input
from terrain.json_safe import json_safe as _clean
from terrain.metrics import interval_coverage, standardized_error_stats
from terrain.validation import CrossValidation

from .breakline_record import breakline_block
from .certify_bias import bias_assessment
from .certify_heights import checkpoints_in_dem_datum
from .certify_heldout import heldout_block
from .certify_io import Checkpoints, as_checkpoints, read_checkpoints, reproject_checkpoints
from .dem_io import DemRaster, read_dem, sample_bilinear

__all__ = [
    "CONVENTIONAL_INTERVALS_M",
    "SCHEMA",
    "Checkpoints",
    "DemRaster",
    "as_checkpoints",
    "bias_assessment",
    "bootstrap_rmse_ci",
    "certify",
    "certificate_json",
    "check_output_path",
    "conventional_interval",
    "heldout_block",
    "read_checkpoints",
    "read_dem",
    "require_checkpoints_on",
    "sample_bilinear",
    "software_versions",
    "write_certificate",
]

SCHEMA = "glacimap-certificate/1"
#: Contour intervals (m) a certified interval is rounded up to (metric map practice).
CONVENTIONAL_INTERVALS_M = (0.1, 0.2, 0.25, 0.5, 1.0, 2.0, 2.5, 5.0, 10.0, 20.0, 25.0, 50.0)
_PACKAGES = ("glacimap", "numpy", "scipy", "xarray", "rasterio", "pyproj", "gtsam")
_MAX_ROWS_LISTED = 100  # dropped row indices listed per reason


# --------------------------------------------------------------------------- statistics
def bootstrap_rmse_ci(
    errors: np.ndarray, *, n_boot: int = 2000, seed: int = 0, level: float = 0.95
) -> tuple[float, float]:
    """Percentile-bootstrap interval of RMSE (Efron & Tibshirani 1993, ch. 13).

    ``errors`` (n,) in metres are resampled with replacement ``n_boot`` times with
    ``numpy.random.default_rng(seed)``; returns the ``(1 - level) / 2`` and ``(1 + level) / 2``
    percentiles of the resampled RMSEs, metres.
    """
    sq = np.asarray(errors, dtype=float) ** 2
    if sq.ndim != 1 or sq.size == 0 or not np.isfinite(sq).all():
        raise bad_input("errors", sq.shape, "a non-empty 1-D finite array (m)", "")
    if int(n_boot) < 1:
        raise bad_input("n_boot", n_boot, "at least 1 resample", "e.g. 2000")
    rng = np.random.default_rng(seed)
    rmses = np.empty(int(n_boot))
    chunk = max(1, 2_000_000 // sq.size)  # bound memory at ~16 MB of indices per draw
    for start in range(0, rmses.size, chunk):
        k = min(chunk, rmses.size - start)
        rmses[start : start + k] = np.sqrt(sq[rng.integers(0, sq.size, (k, sq.size))].mean(1))
    lo, hi = np.percentile(rmses, [50.0 * (1 - level), 50.0 * (1 + level)])
    return float(lo), float(hi)


def conventional_interval(ci_m: float) -> float:
    """Smallest of :data:`CONVENTIONAL_INTERVALS_M` >= ``ci_m`` (m); beyond them, the next
    multiple of 100 m."""
    for c in CONVENTIONAL_INTERVALS_M:
        if c >= ci_m * (1 - 1e-9):
            return c
    return 100.0 * math.ceil(ci_m / 100.0)


def software_versions() -> dict[str, str]:
    """Installed versions (importlib.metadata) of glacimap and the libraries it certifies
    with; packages that are not installed are left out."""
    from importlib.metadata import PackageNotFoundError, version

    out = {}
    for name in _PACKAGES:
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            continue
    return out


def _dropped(mask: np.ndarray) -> dict[str, Any]:
    rows = np.flatnonzero(mask)
    return {
        "count": int(rows.size),
        "rows": rows[:_MAX_ROWS_LISTED].tolist(),
        "rows_truncated": bool(rows.size > _MAX_ROWS_LISTED),
    }


def _stated_shared_std(provenance: Mapping[str, Any]) -> float | None:
    """The product's shared vertical offset 1-sigma (m), when it states one."""
    try:
        v = float(provenance.get("shared_vertical_offset_std_m"))
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) and v >= 0 else None


# --------------------------------------------------------------------------- certify
def _dropped_warning(n_total: int, n_used: int, *masks: np.ndarray) -> str | None:
    """Words for checkpoints that were read but not scored (None when all were)."""
    if n_used == n_total:
        return None
    names = ("with NaN values", "not projectable", "outside the DEM", "on nodata")
    why = ", ".join(f"{int(m.sum())} {w}" for m, w in zip(masks, names, strict=True) if m.any())
    return (
        f"{n_total - n_used} of {n_total} checkpoints were not scored ({why}): the certificate "
        f"rests on {n_used}; check the checkpoints' CRS and the map's extent"
    )


def _geographic_note(g: Any) -> dict[str, str]:
    """How a DEM in degrees was certified (nothing for a projected one)."""
    if not g.crs.is_geographic:
        return {}
    _, why = in_metres(np.zeros((1, 2)) + g.bounds[:2], g)
    return {
        "geographic_note": "sampled bilinearly on its own longitude/latitude cells (not "
        f"warped); resolution_m at its centre; checkpoint distances in {why}"
    }


def place_checkpoints(
    cps: Checkpoints, grid: Any
) -> tuple[np.ndarray, dict[str, str] | None, np.ndarray, np.ndarray, np.ndarray]:
    """Checkpoints in ``grid``'s CRS and which of them can be scored there.

    Returns
    -------
    xy : ndarray of shape (n, 2)
        Checkpoint x, y in the grid's CRS, m (0 on the rows that cannot be placed).
    reprojected : dict or None
        The record of the transformation (``None`` when already in the grid's CRS).
    nan, unprojectable, outside : ndarray of bool, shape (n,)
        Rows with a NaN value, rows pyproj cannot transform, rows outside the grid.
    """
    nan = cps.nan_rows()
    xy, reprojected = reproject_checkpoints(cps, grid.crs, nan)
    unprojectable = ~nan & ~np.isfinite(xy).all(axis=1)
    xy[unprojectable] = 0.0
    outside = ~nan & ~unprojectable & ~grid.contains(xy)
    return xy, reprojected, nan, unprojectable, outside


def _none_usable(cps: Checkpoints, nan, unprojectable, outside, nodata) -> InputError:
    """The error for checkpoints of which none can be scored, with the counts and the fix."""
    ok = ~nan
    degrees = ok.any() and bool(
        (np.abs(cps.xy[ok, 0]) <= 180).all() and (np.abs(cps.xy[ok, 1]) <= 90).all()
    )
    return bad_input(
        "checkpoints",
        f"0 of {cps.n} usable ({int(nan.sum())} NaN, {int(unprojectable.sum())} not "
        f"projectable, {int(outside.sum())} outside the DEM, {int(nodata.sum())} on nodata)",
        "checkpoints on valid DEM cells",
        "the coordinates look like longitude / latitude degrees but the file names no CRS: "
        "add a crs column (e.g. EPSG:4326) or a .crs sidecar"
        if cps.crs is None and degrees
        else "check the CRS and the extent of both files",
    )


def require_checkpoints_on(checkpoints: Any, grid: Any, crs: Any = None) -> Checkpoints:
    """Read ``checkpoints`` and fail before any work when none of them lies on ``grid`` (the
    map to be made): the same error :func:`certify` gives once the map exists, without the
    wait for the fit. Returns the checkpoints read."""
    cps = as_checkpoints(checkpoints, crs)
    _, _, nan, unprojectable, outside = place_checkpoints(cps, grid)
    if not (~nan & ~unprojectable & ~outside).any():
        raise _none_usable(cps, nan, unprojectable, outside, np.zeros(cps.n, dtype=bool))
    return cps


def _checkpoint_rmse(given: float | None, cps: Checkpoints, used: np.ndarray) -> tuple[float, str]:
    """The checkpoint survey's own RMSE (ASPRS 2014 / 2023): ``given``, else the RMS of the
    used checkpoints' stated 1-sigma, else 0; and where it came from."""
    if given is not None:
        return float(given), "given (--checkpoint-rmse)"
    if cps.z_std is not None and np.isfinite(cps.z_std[used]).all():
        rms = float(np.sqrt(np.mean(cps.z_std[used] ** 2)))
        return rms, f"the RMS of the {int(used.sum())} checkpoints' stated 1-sigma (z_std)"
    return 0.0, "not stated (no z_std column, no --checkpoint-rmse): taken as 0"


def certify(
    dem: Any,
    checkpoints: Checkpoints | str | os.PathLike | Mapping[str, Any],
    *,
    contour_interval_m: float | None = None,
    checkpoint_rmse_m: float | None = None,
    seed: int = 0,
    n_boot: int = 2000,
    feature: str = "contour",
    crs: Any = None,
    created: str | None = None,
    heldout: CrossValidation | Mapping[str, Any] | None = None,
    dem_heights: str | None = None,
    checkpoint_heights: str | None = None,
) -> dict[str, Any]:
    """Certify the vertical accuracy of ``dem`` against ``checkpoints``.

    Parameters
    ----------
    dem : xarray.Dataset, xarray.DataArray or path-like
        Terrain product (``elevation``, optional ``elevation_std``, m), truth DEM, GeoTIFF
        or NetCDF path; see :func:`read_dem`.
    checkpoints : Checkpoints, path-like, mapping or DataFrame
        Independent check points: a file (:func:`read_checkpoints`) or a table with columns
        ``x, y, z[, z_std, crs]`` or their aliases (:func:`as_checkpoints`), in any CRS
        pyproj knows (reprojected to the DEM's; heights must be in the DEM's vertical datum).
    contour_interval_m : float, optional
        Interval to certify (m). Default: the finest interval ASPRS 1990 Class 1 allows
        (CI = 3 RMSE_z for contours), rounded up to :data:`CONVENTIONAL_INTERVALS_M`.
    checkpoint_rmse_m : float, optional
        RMSE of the checkpoint survey itself (m); used by ASPRS 2014/2023 rules. Default: the
        root mean square of the used checkpoints' stated 1-sigma (``z_std``) when they state
        one, else 0; ``parameters.checkpoint_rmse_source`` says which.
    seed, n_boot : int
        Seed of ``numpy.random.default_rng`` and number of bootstrap resamples for the RMSE
        confidence interval.
    feature : {"contour", "spot"}
        ASPRS 1990 feature type.
    crs : optional
        CRS of checkpoints that name none (see :func:`as_checkpoints`).
    created : str, optional
        A timestamp to record; none is recorded otherwise (reproducible bytes).
    heldout : terrain.CrossValidation or its ``to_dict()``, optional
        Spatial block cross-validation of the map's GP (:func:`terrain.cross_validate`):
        adds the ``heldout_calibration`` block (:func:`heldout_block`). Default: none.
    dem_heights, checkpoint_heights : str, optional
        What the DEM's / the checkpoints' heights are above where they do not state it
        (``"ellipsoidal"``, ``"egm96"``, ``"egm2008"``); both known and different: the
        checkpoints are carried to the DEM's datum (:mod:`toolkit.certify_heights`,
        recorded as ``checkpoints.heights``).

    Returns
    -------
    dict
        JSON-ready certificate; keys ``schema, dem, checkpoints, parameters, accuracy,
        contour_interval, verdicts, calibration, error_histogram, seed, software`` (and
        ``created``, ``heldout_calibration`` when given; ``breaklines`` when the map was
        fitted with them: each line's step and 1-sigma, width, open ends and what the prior
        DEM lacks of it, :func:`toolkit.breakline_record.breakline_rows`).

    Raises
    ------
    terrain.errors.InputError
        Bad DEM / checkpoints / parameters, or no checkpoint on valid DEM cells.
    terrain.errors.CRSMismatchError
        The ``crs`` argument and the checkpoint file name different CRSs.
    """
    if not isinstance(feature, str) or feature not in ("contour", "spot"):
        raise bad_input("feature", feature, "'contour' or 'spot'", "ASPRS 1990 feature type")
    if checkpoint_rmse_m is not None:  # validated before any work
        standards.combined_rmse_with_checkpoints(0.0, checkpoint_rmse_m)
    if contour_interval_m is not None and not (
        math.isfinite(float(contour_interval_m)) and float(contour_interval_m) > 0
    ):
        raise bad_input("contour_interval_m", contour_interval_m, "a positive interval (m)", "")
    heldout_cal = None if heldout is None else heldout_block(heldout)  # fail before any work
    raster = read_dem(dem)
    cps = as_checkpoints(checkpoints, crs)
    cps, heights = checkpoints_in_dem_datum(cps, raster, dem_heights, checkpoint_heights)
    xy, reprojected, nan, unprojectable, outside = place_checkpoints(cps, raster.grid)
    dem_z = np.full(cps.n, np.nan)
    cand = ~nan & ~unprojectable & ~outside
    dem_z[cand] = sample_bilinear(raster.grid, raster.elevation, xy[cand])
    nodata = cand & ~np.isfinite(dem_z)
    used = cand & ~nodata
    n = int(used.sum())
    if n == 0:
        raise _none_usable(cps, nan, unprojectable, outside, nodata)
    err = dem_z[used] - cps.z[used]
    rmse = float(np.sqrt(np.mean(err**2)))
    cp_rmse, cp_source = _checkpoint_rmse(checkpoint_rmse_m, cps, used)
    lo, hi = bootstrap_rmse_ci(err, n_boot=n_boot, seed=seed)
    accuracy = {
        "n": n,
        "error_definition": "map minus checkpoint (DEM - checkpoint), m: positive = map high",
        "rmse_m": rmse,
        "rmse_ci95_m": [lo, hi],
        "bias_m": float(err.mean()),
        "std_m": float(err.std(ddof=1)) if n > 1 else None,
        "mae_m": float(np.abs(err).mean()),
        "max_abs_error_m": float(np.abs(err).max()),
        "p95_abs_error_m": float(np.percentile(np.abs(err), 95)),
        "accuracy_95_m": standards.accuracy_95(rmse, "nssda"),
        "rmse_with_checkpoint_error_m": standards.combined_rmse_with_checkpoints(rmse, cp_rmse),
        "bias_assessment": bias_assessment(
            err, in_metres(xy[used], raster.grid)[0], _stated_shared_std(raster.provenance)
        ),
    }

    finest = {
        f"asprs1990_class{k}": standards.finest_contour_interval(rmse, "asprs1990", str(k), feature)
        for k in (1, 2, 3)
    }
    finest["nmas"] = standards.finest_contour_interval(rmse, "nmas")
    finest["paper"] = standards.finest_contour_interval(rmse, "paper")
    if contour_interval_m is None:
        ci = conventional_interval(finest["asprs1990_class1"])
        how = "finest ASPRS 1990 Class 1 interval, rounded up to a conventional one"
    else:
        ci, how = float(contour_interval_m), "given"
    g = raster.grid  # a Footprint for a DEM in degrees: its area on the ground
    area_km2 = (
        g.area_km2()
        if g.crs.is_geographic
        else (lambda b: (b[2] - b[0]) * (b[3] - b[1]) / 1e6)(g.bounds)
    )
    verdicts = standards.verdicts(
        rmse, ci, cp_rmse, n_checkpoints=n, feature=feature, area_km2=area_km2
    )
    if accuracy["bias_assessment"]["message"]:
        frac = accuracy["bias_assessment"]["fraction_of_rmse"]
        for v in verdicts:  # a pass on the RMSE says nothing of where the error comes from
            v["notes"] = [*v["notes"], f"bias {accuracy['bias_m']:+.2f} m is {frac:.0%} of RMSE"]

    calibration = None
    if raster.elevation_std is not None:
        std = sample_bilinear(raster.grid, raster.elevation_std, xy[used])
        if cps.z_std is not None:
            std = np.hypot(std, cps.z_std[used])  # difference of independent errors
        ok = np.isfinite(std)
        if ok.any():
            pred, truth, s = dem_z[used][ok], cps.z[used][ok], std[ok]
            z_mean, z_std = standardized_error_stats(truth, s, pred)  # (map - checkpoint) / s
            calibration = {
                "n": int(ok.sum()),
                "sigma": "elevation_std"
                + (" (+) checkpoint z_std" if cps.z_std is not None else ""),
                "coverage_68": interval_coverage(pred, s, truth, z=1.0),
                "coverage_95": interval_coverage(pred, s, truth, z=1.96),
                "z_definition": "(map - checkpoint) / sigma, the sign of bias_m",
                "z_mean": z_mean,
                "z_std": z_std,
                "mean_sigma_m": float(s.mean()),
            }
    counts, edges = np.histogram(err, bins=min(30, max(5, int(np.sqrt(n)))))
    cert = {
        "schema": SCHEMA,
        "dem": {
            **raster.source,
            "crs": g.crs.to_string(),
            "shape": list(g.shape),
            "resolution_m": list(g.ground_resolution() if g.crs.is_geographic else g.resolution),
            "bounds": list(g.bounds),
            "area_km2": area_km2,
            "has_std_band": raster.elevation_std is not None,
            **_geographic_note(g),
            "vertical_datum": raster.provenance.get("vertical_datum")
            or (f"heights above {heights['dem']}" if heights["dem"] else "not stated by the DEM"),
            "provenance": raster.provenance,
        },
        "checkpoints": {
            "source": cps.source,
            "sha256": cps.sha256,
            "crs": None if cps.crs is None else cps.crs.to_string(),
            "crs_note": None if cps.crs is not None else "none given: assumed the DEM's",
            "reprojected": reprojected,
            "columns": cps.columns,
            "ignored_columns": list(cps.ignored_columns),
            **({"read": cps.note} if cps.note else {}),  # a GIS layer: its vertices, layers
            "n_total": cps.n,
            "n_used": n,
            "n_dropped": cps.n - n,
            "dropped": {
                "nan_values": _dropped(nan),
                "not_projectable": _dropped(unprojectable),
                "outside_dem": _dropped(outside),
                "nodata": _dropped(nodata),
            },
            "has_z_std": cps.z_std is not None,
            "heights": heights,
        },
        "parameters": {
            "contour_interval_m": contour_interval_m,
            "checkpoint_rmse_m": cp_rmse,
            "checkpoint_rmse_source": cp_source,
            "feature": feature,
            "n_boot": int(n_boot),
            "bootstrap": "percentile, numpy.random.default_rng(seed)",
            "sampling": "bilinear between cell centres; any NaN neighbour -> nodata",
        },
        "accuracy": accuracy,
        "contour_interval": {"certified_m": ci, "how": how, "finest_m": finest},
        "verdicts": verdicts,
        "warnings": [
            m
            for m in (
                _dropped_warning(cps.n, n, nan, unprojectable, outside, nodata),
                accuracy["bias_assessment"]["message"],
            )
            if m
        ],  # fmt: skip
        "calibration": calibration,
        "error_histogram": {"edges_m": edges, "counts": counts},
        "seed": int(seed),
        "software": software_versions(),
    }
    if created is not None:
        cert["created"] = str(created)
    if heldout_cal is not None:
        cert["heldout_calibration"] = heldout_cal
    cert.update(breakline_block(raster.provenance))  # the cliffs the map was fitted with
    return _clean(cert)


def certificate_json(cert: dict[str, Any]) -> str:
    """The certificate as deterministic JSON text (2-space indent, NaN as null, other
    non-JSON objects as ``str``, final newline)."""
    return json.dumps(_clean(cert), indent=2, allow_nan=False, default=str) + "\n"


def check_output_path(path: str | os.PathLike, field: str = "--out") -> Path:
    """Check before any work that ``path`` can be written: an existing, writable folder and
    not a folder itself. Raises :class:`terrain.errors.InputError` naming ``field``."""
    path = Path(path)
    if path.is_dir() or not path.parent.is_dir():
        fix = "add a file name" if path.is_dir() else f"create {path.parent} first"
        raise bad_input(field, str(path), "a file path in an existing folder", fix)
    if not os.access(path.parent, os.W_OK | os.X_OK):
        raise bad_input(field, str(path), "a path in a writable folder", "choose another one")
    return path


def write_certificate(cert: dict[str, Any], path: str | os.PathLike) -> Path:
    """Write ``cert`` as JSON (:func:`certificate_json`) to ``path`` atomically: the file is
    complete or absent.

    Raises
    ------
    terrain.errors.InputError
        The folder is missing or not writable, or ``path`` is a folder.
    """
    text = certificate_json(cert)
    path = check_output_path(path)
    try:
        with atomic_path(path) as tmp:
            tmp.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise bad_input("--out", str(path), "a writable file", str(exc)) from exc
    return path
