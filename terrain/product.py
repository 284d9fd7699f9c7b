"""The terrain product (docs/architecture.md §3): an ``xarray.Dataset`` with ``elevation`` and
``elevation_std`` (metres) on dims ``(y, x)`` of a :class:`Grid`, CRS and provenance in attrs."""

from __future__ import annotations

import json
from typing import Any

import numpy as np

from .grid import Grid

__all__ = ["VERTICAL_DATUM", "cf_grid_mapping", "software_version", "terrain_dataset"]

#: What the product's heights are, unless its attrs say otherwise: the rover's GPS heights
#: (WGS 84 ellipsoid); glacimap applies no geoid model. A prior or samples in another datum
#: set ``attrs["vertical_datum"]``.
VERTICAL_DATUM = "ellipsoidal height above the WGS 84 ellipsoid (GPS); no geoid applied"


def software_version() -> str:
    """The installed glacimap version ("unknown" when running from a bare source tree)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("glacimap")
    except PackageNotFoundError:  # pragma: no cover - running from a source tree
        return "unknown"


def cf_grid_mapping(grid: Grid) -> dict[str, Any]:
    """CF-1.8 grid-mapping attributes of ``grid.crs`` (pyproj ``CRS.to_cf``) plus
    ``spatial_ref`` (WKT, what GDAL reads), for a scalar ``spatial_ref`` variable."""
    cf = {k: v for k, v in grid.crs.to_cf().items() if isinstance(v, str | int | float)}
    return {**cf, "spatial_ref": grid.crs.to_wkt()}


def terrain_dataset(grid: Grid, elevation: Any, elevation_std: Any, attrs: dict[str, Any]):
    """Wrap mean and 1-sigma arrays of shape ``grid.shape`` (numpy or dask) as the product.

    GIS conventions: a CF ``grid_mapping`` (scalar coordinate ``spatial_ref``, so that GDAL,
    QGIS and rioxarray read the CRS from a NetCDF file) and ``attrs["vertical_datum"]``
    (:data:`VERTICAL_DATUM` unless ``attrs`` names one).
    """
    import xarray as xr

    var = {"units": "m", "grid_mapping": "spatial_ref"}
    return xr.Dataset(
        {
            "elevation": (
                ("y", "x"),
                elevation,
                {**var, "long_name": "posterior mean elevation"},
            ),
            "elevation_std": (
                ("y", "x"),
                elevation_std,
                {**var, "long_name": "posterior 1-sigma of elevation"},
            ),
        },
        coords={**grid.coords(), "spatial_ref": ((), np.int32(0), cf_grid_mapping(grid))},
        attrs={
            "Conventions": "CF-1.8",
            **grid.attrs(),
            "vertical_datum": VERTICAL_DATUM,
            **attrs,
        },
    )


def json_rows(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Kernel-search scores with plain floats (netCDF attrs are flat strings)."""
    out = []
    for r in rows:
        out.append({k: (float(v) if isinstance(v, np.floating) else v) for k, v in r.items()})
    return out


def mean_coefficients(mean: Any) -> dict[str, Any]:
    """A linear mean's fitted coefficients with 1-sigma, e.g. {"offset_m": [1.2, 0.05]}."""
    coef = getattr(mean, "coef_", None)
    if coef is None:
        return {}
    sd = np.sqrt(np.diag(np.atleast_2d(getattr(mean, "coef_cov_", np.zeros((1, 1))))))
    names = getattr(mean, "coef_names", [f"b{i}" for i in range(len(coef))])
    return {n: [float(c), float(s)] for n, c, s in zip(names, np.ravel(coef), sd, strict=False)}


def gp_provenance(gp: Any) -> dict[str, Any]:
    """Flat, netCDF-safe description of how a fitted :class:`terrain.TerrainGP`'s map was
    made: method, kernel and its geometric anisotropy with their evidence, hyperparameters,
    mean, sample counts, seed and software."""
    hyper = dict(zip(gp.kernel_.param_names, np.exp(gp.kernel_.theta).tolist(), strict=True))
    hyper["nugget"] = gp.nugget_
    method, wp = "exact GP (Rasmussen & Williams Alg. 2.1)", gp.window_plan_
    if gp.method_ == "tiled":
        method = gp.tiles_.describe(gp.amplitude_prior_sd if gp.local_amplitude_ else None)
    evidence = json_rows([gp.anisotropy_evidence_ or {}])[0]
    return {
        "method": method,
        "kernel": repr(gp.kernel_),
        "anisotropy": json.dumps({**gp.anisotropy_.to_dict(), **evidence}),
        "hyperparameters": json.dumps(hyper),
        "mean_function": repr(gp.mean_),
        "n_samples": int(gp.samples_.n),
        "n_fit_samples": int(gp.fit_index_.size),
        "n_merged_duplicates": int(gp.samples_.n_merged),
        "log_marginal_likelihood": gp.log_marginal_likelihood_value_,
        "jitter": gp.jitter_,
        "kernel_selection": json.dumps(json_rows(gp.kernel_scores_)),
        "kernel_windows": "none" if wp is None else wp.describe(),
        # noise no sample states, from the windows' evidence ("" where it was not needed)
        "noise_estimate": json.dumps(json_rows([gp.noise_estimate_])[0])
        if getattr(gp, "noise_estimate_", None)
        else "",
        "mean_coefficients": json.dumps(mean_coefficients(gp.mean_)),
        # the lines of a BreaklineMean and their widths ("" without): a GeoJSON Feature
        "breaklines": _breaklines_text(gp.mean_),
        # per line, what the prior DEM lacks of its step in the DEM's own metres, 1-sigma
        # (terrain.dem_reading.dem_lacks; "" without a DEM prior that smooths the steps)
        "breakline_dem_lacks": _dem_lacks_text(gp.mean_),
        "degenerate_fit": int(gp.degenerate_),
        # the tiles could not hold a long kernel part across the survey's gaps ("" if held)
        "tiling_warning": getattr(gp, "tiling_note_", None) or "",
        "seed": int(gp.seed),
        "software": f"glacimap {software_version()}",
    }


def _breaklines_text(mean: Any) -> str:
    """The lines as :meth:`terrain.BreaklineMean.geojson` gives them, with each width's
    1-sigma (``widths_sd_m``, m; None for a width given, not chosen)."""
    if not hasattr(mean, "geojson"):
        return ""
    feature = mean.geojson()
    sds = getattr(mean, "widths_sd_", None)
    feature["properties"]["widths_sd_m"] = None if sds is None else [float(s) for s in sds]
    return json.dumps(feature)


def _dem_lacks_text(mean: Any) -> str:
    from .dem_reading import dem_lacks

    lacks = dem_lacks(mean)
    return json.dumps([{"m": v, "sd_m": sd} for v, sd in lacks]) if lacks else ""
