"""The accuracy-certification report: one self-contained HTML file (docs/architecture.md §1 step 7).

:func:`write_report` renders ``templates/report.html.j2`` (jinja2, autoescaped) with the
certificate of :func:`toolkit.certify.certify` and matplotlib figures (Agg backend) embedded
as base64 PNG data URIs: no external files, scripts, fonts or URLs.

Maps are drawn in local metres from the product's south-west corner (stated in each caption
with the CRS); errors are ``product - truth``, metres, the certificate's sign.
"""

from __future__ import annotations

import base64
import io
import json
import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from terrain.atomic import atomic_path
from terrain.errors import bad_input
from terrain.metrics import calibration_curve

from .certify import check_output_path
from .dem_io import DemRaster, read_dem

__all__ = ["CHI2_2D_95", "write_report"]

#: sqrt of the chi-square 95 % quantile with 2 degrees of freedom: the 95 % ellipse of a
#: 2-D Gaussian is ``CHI2_2D_95`` times its 1-sigma ellipse (= sqrt(-2 ln 0.05)).
CHI2_2D_95 = math.sqrt(-2.0 * math.log(0.05))
_DPI = 80
_MAX_ELLIPSES = 60
_MAX_POINTS = 5000


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _png(fig) -> str:
    """Close ``fig`` and return it as a ``data:image/png;base64,...`` URI."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=_DPI, metadata={"Software": None})
    _plt().close(fig)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def _frame(raster: DemRaster) -> tuple[float, float, tuple[float, float, float, float]]:
    w, s, e, n = raster.grid.bounds
    return w, s, (0.0, e - w, 0.0, n - s)


def _axes(ax, title: str) -> None:
    ax.set(title=title, xlabel="easting from SW corner [m]", ylabel="northing [m]")
    ax.set_aspect("equal")


def _contour_levels(z: np.ndarray, interval: float, max_levels: int = 60) -> np.ndarray:
    lo, hi = float(np.nanmin(z)), float(np.nanmax(z))
    step = interval * max(1, math.ceil((hi - lo) / interval / max_levels))
    return np.arange(math.ceil(lo / step) * step, hi + step / 2, step)


def _fig_elevation(raster: DemRaster, interval: float, lines: list) -> dict[str, str]:
    from matplotlib.colors import LightSource

    plt = _plt()
    _, _, extent = _frame(raster)
    z = raster.elevation
    dx, dy = raster.grid.resolution
    fig, ax = plt.subplots(figsize=(6.4, 5.2), constrained_layout=True)
    im = ax.imshow(z, extent=extent, cmap="terrain", origin="upper")
    shade = LightSource(azdeg=315, altdeg=35).hillshade(
        np.where(np.isfinite(z), z, np.nanmean(z)), vert_exag=1.0, dx=dx, dy=dy
    )
    ax.imshow(np.where(np.isfinite(z), shade, np.nan), extent=extent, cmap="gray", alpha=0.35)
    levels = _contour_levels(z, interval)
    if levels.size > 1:
        k = max(1, math.ceil(max(z.shape) / 400))  # no finer than the figure's pixels
        xs = raster.grid.x[::k] - raster.grid.bounds[0]
        ys = raster.grid.y[::k] - raster.grid.bounds[1]
        ax.contour(xs, ys, z[::k, ::k], levels=levels, colors="k", linewidths=0.4)
    step = float(levels[1] - levels[0]) if levels.size > 1 else interval
    w, s = raster.grid.bounds[:2]
    for b in lines:  # the breaklines the map was fitted with (certificate "breaklines")
        xy = np.asarray(b["vertices"], dtype=float)
        ax.plot(xy[:, 0] - w, xy[:, 1] - s, color="crimson", linewidth=1.2)
    if lines:  # lines run on past the map stay clipped to it
        ax.set(xlim=extent[:2], ylim=extent[2:])
    fig.colorbar(im, ax=ax, shrink=0.85, label="elevation [m]")
    _axes(ax, "Elevation (hillshade, contours)")
    caption = f"contours every {step:g} m"
    if lines:
        caption += f"; in red the {len(lines)} breakline(s) the map was fitted with"
    return {"title": "Elevation", "src": _png(fig), "caption": caption}


def _fig_std(raster: DemRaster, samples_xy: np.ndarray | None) -> dict[str, str]:
    plt = _plt()
    w, s, extent = _frame(raster)
    fig, ax = plt.subplots(figsize=(6.4, 5.2), constrained_layout=True)
    im = ax.imshow(raster.elevation_std, extent=extent, cmap="magma", vmin=0.0)
    caption = "posterior 1-sigma of elevation"
    if samples_xy is not None and len(samples_xy):
        pts = samples_xy[:: max(1, len(samples_xy) // _MAX_POINTS)]
        ax.scatter(pts[:, 0] - w, pts[:, 1] - s, s=0.5, c="c", alpha=0.6, lw=0)
        ax.set(xlim=extent[:2], ylim=extent[2:])
        caption += f"; cyan: {len(samples_xy)} samples"
    fig.colorbar(im, ax=ax, shrink=0.85, label="1-sigma [m]")
    _axes(ax, "Elevation 1-sigma")
    return {"title": "Uncertainty", "src": _png(fig), "caption": caption}


def _fig_error(raster: DemRaster, truth: np.ndarray) -> dict[str, str]:
    plt = _plt()
    _, _, extent = _frame(raster)
    err = raster.elevation - truth
    vmax = float(np.nanpercentile(np.abs(err), 99)) or 1e-6
    fig, ax = plt.subplots(figsize=(6.4, 5.2), constrained_layout=True)
    im = ax.imshow(err, extent=extent, cmap="RdBu_r", vmin=-vmax, vmax=vmax)
    fig.colorbar(im, ax=ax, shrink=0.85, label="product - truth [m]")
    rmse = float(np.sqrt(np.nanmean(err**2)))
    _axes(ax, f"Error against truth (RMSE {rmse:.3f} m)")
    return {"title": "Error", "src": _png(fig), "caption": "colour range: 99th pct of |error|"}


def _fig_calibration(raster: DemRaster, truth: np.ndarray, cert: Mapping) -> dict[str, str]:
    plt = _plt()
    levels, observed = calibration_curve(raster.elevation, raster.elevation_std, truth)
    fig, ax = plt.subplots(figsize=(4.8, 4.4), constrained_layout=True)
    ax.plot([0, 1], [0, 1], "k--", lw=0.8, label="calibrated")
    ax.plot(levels, observed, "o-", label="all cells vs truth")
    cal = cert.get("calibration")
    if cal:
        ax.plot([0.6827, 0.95], [cal["coverage_68"], cal["coverage_95"]], "s", label="checkpoints")
    ax.set(xlim=(0, 1), ylim=(0, 1), xlabel="nominal level", ylabel="empirical coverage")
    ax.set_title("Calibration of the 1-sigma")
    ax.legend(loc="upper left")
    caption = "fraction inside the central Gaussian interval (terrain.metrics.calibration_curve)"
    return {"title": "Calibration", "src": _png(fig), "caption": caption}


def _fig_heldout(cert: Mapping) -> dict[str, str]:
    """The held-out calibration curve (certificate ``heldout_calibration``), axes as
    :func:`_fig_calibration`, with the checkpoint coverages beside it when there are some."""
    plt = _plt()
    block = cert["heldout_calibration"]
    curve = block.get("calibration") or {}
    fig, ax = plt.subplots(figsize=(4.8, 4.4), constrained_layout=True)
    ax.plot([0, 1], [0, 1], "k--", lw=0.8, label="calibrated")
    if curve.get("levels"):
        ax.plot(curve["levels"], curve["observed"], "o-", c="tab:purple", label="held-out samples")
    ax.plot(
        [0.6827, 0.95], [block["coverage_68"], block["coverage_95"]], "D", c="tab:purple", mfc="w"
    )
    cal = cert.get("calibration")
    if cal:
        ax.plot([0.6827, 0.95], [cal["coverage_68"], cal["coverage_95"]], "s", label="checkpoints")
    ax.set(xlim=(0, 1), ylim=(0, 1), xlabel="nominal level", ylabel="empirical coverage")
    ax.set_title("Held-out calibration of the 1-sigma")
    ax.legend(loc="upper left")
    caption = (
        f"spatial block {_fmt(block.get('n_folds'))}-fold cross-validation, blocks of "
        f"{_fmt(block.get('block_size_m'))} m; each held-out sample against "
        "N(mu, sd^2 + nugget + z_var) (terrain.cross_validate)"
    )
    return {"title": "Held-out calibration", "src": _png(fig), "caption": caption}


def _fig_histogram(hist: Mapping) -> dict[str, str]:
    plt = _plt()
    edges, counts = np.asarray(hist["edges_m"], float), np.asarray(hist["counts"], float)
    fig, ax = plt.subplots(figsize=(4.8, 3.6), constrained_layout=True)
    ax.bar(edges[:-1], counts, width=np.diff(edges), align="edge", edgecolor="k", lw=0.4)
    ax.axvline(0.0, color="k", lw=0.8)
    ax.set(xlabel="DEM - checkpoint [m]", ylabel="checkpoints", title="Checkpoint errors")
    return {"title": "Checkpoint errors", "src": _png(fig), "caption": "from the certificate"}


def _nice(x: float) -> float:
    """Smallest of 1, 2, 5 x 10^k that is >= x."""
    k = 10.0 ** math.floor(math.log10(x))
    return next(m * k for m in (1, 2, 5, 10) if m * k >= x * (1 - 1e-12))


def _arr(traj: Mapping, key: str, shape: tuple[int, ...]) -> np.ndarray | None:
    value = traj.get(key)
    if value is None:
        return None
    a = np.asarray(value, dtype=float)
    if a.ndim != len(shape) or any(s != -1 and a.shape[i] != s for i, s in enumerate(shape)):
        want = "(" + ", ".join("n" if s == -1 else str(s) for s in shape) + ")"
        raise bad_input(f"trajectory['{key}']", a.shape, f"shape {want}", "check the array")
    return a


def _fig_trajectory(raster: DemRaster, traj: Mapping) -> dict[str, str]:
    from matplotlib.patches import Ellipse

    plt = _plt()
    w, s, extent = _frame(raster)
    est = _arr(traj, "xy_est", (-1, 2))
    if est is None or not len(est):
        raise bad_input("trajectory['xy_est']", None, "(n, 2) estimated positions (m)", "")
    true, cov = _arr(traj, "xy_true", (-1, 2)), _arr(traj, "cov_xy", (-1, 2, 2))
    marks = _arr(traj, "landmarks_xy", (-1, 2))
    for name, a in (("xy_true", true), ("cov_xy", cov)):
        if a is not None and len(a) != len(est):
            raise bad_input(f"trajectory['{name}']", len(a), f"{len(est)} rows like xy_est", "")
    fig, ax = plt.subplots(figsize=(6.4, 5.2), constrained_layout=True)
    ax.imshow(raster.elevation, extent=extent, cmap="gray", alpha=0.35)
    if marks is not None and len(marks):
        pts = marks[:: max(1, len(marks) // _MAX_POINTS)]
        ax.scatter(pts[:, 0] - w, pts[:, 1] - s, s=1, c="tab:green", lw=0, label="landmarks")
    if true is not None:
        ax.plot(true[:, 0] - w, true[:, 1] - s, "k--", lw=0.8, label="true")
    ax.plot(est[:, 0] - w, est[:, 1] - s, "-", c="tab:blue", lw=1.0, label="estimated")
    caption = "no covariances given"
    if cov is not None:
        vals, vecs = np.linalg.eigh(cov)  # ascending eigenvalues, m^2
        semi = CHI2_2D_95 * np.sqrt(np.clip(vals, 0, None))  # 95 % semi-axes, m
        span = max(extent[1], extent[3])
        scale = _nice(0.005 * span / np.median(semi[:, 1])) if np.median(semi[:, 1]) > 0 else 1.0
        scale = max(scale, 1.0)
        for i in range(0, len(est), max(1, math.ceil(len(est) / _MAX_ELLIPSES))):
            angle = math.degrees(math.atan2(vecs[i, 1, 1], vecs[i, 0, 1]))
            ax.add_patch(
                Ellipse(
                    (est[i, 0] - w, est[i, 1] - s),
                    2 * scale * semi[i, 1],
                    2 * scale * semi[i, 0],
                    angle=angle,
                    fill=False,
                    ec="tab:red",
                    lw=0.7,
                )
            )
        caption = f"red: 95 % position ellipses, drawn x{scale:g}"
        caption += f"; median 95 % semi-major axis {np.median(semi[:, 1]):.3g} m"
    ax.legend(loc="upper right", fontsize="small")
    _axes(ax, "Trajectory")
    return {"title": "Trajectory", "src": _png(fig), "caption": caption}


def _fmt(value: Any) -> str:
    if value is None:
        return "—"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float | np.floating):
        return "NaN" if not math.isfinite(value) else f"{value:.4g}"
    if isinstance(value, list | tuple):
        return ", ".join(_fmt(v) for v in value)
    return str(value)


def _load_certificate(certificate: Any) -> dict[str, Any]:
    if isinstance(certificate, Mapping):
        return dict(certificate)
    path = Path(certificate)
    if not path.is_file():
        raise bad_input("certificate", str(path), "a certificate dict or JSON file", "certify")
    try:
        cert = json.loads(path.read_text(encoding="utf-8"))
    except (ValueError, UnicodeDecodeError) as exc:
        raise bad_input("certificate", path.name, "certificate JSON", str(exc)) from exc
    if not isinstance(cert, dict):
        raise bad_input("certificate", type(cert).__name__, "a JSON object", "re-run certify")
    return cert


def _truth(truth: Any, raster: DemRaster) -> np.ndarray | None:
    if truth is None:
        return None
    import xarray as xr

    if isinstance(truth, xr.Dataset):
        truth = truth["elevation"] if "elevation" in truth else next(iter(truth.data_vars.values()))
    values = np.asarray(getattr(truth, "values", truth), dtype=float)
    if values.shape != raster.grid.shape:
        fix = "pass the truth DEM on the product's grid"
        raise bad_input("truth", values.shape, f"shape {raster.grid.shape} (y, x)", fix)
    return values


def _warnings(cert: Mapping, raster: DemRaster) -> list[str]:
    out = []
    dem = cert.get("dem") or {}
    if dem.get("shape") not in (None, list(raster.grid.shape)):
        out.append(f"certificate DEM shape {dem['shape']} != product {list(raster.grid.shape)}")
    bounds = dem.get("bounds")
    if bounds is not None and not np.allclose(bounds, raster.grid.bounds, atol=1e-6):
        out.append(f"certificate DEM bounds {bounds} != product {list(raster.grid.bounds)}")
    return out


def write_report(
    path: str | os.PathLike,
    *,
    product: Any,
    certificate: Mapping[str, Any] | str | os.PathLike,
    truth: Any = None,
    samples: Any = None,
    trajectory: Mapping[str, Any] | None = None,
    coverage: Mapping[str, Any] | None = None,
    title: str = "glacimap accuracy certificate",
) -> Path:
    """Write a self-contained HTML report of a certified terrain product.

    Parameters
    ----------
    path : path-like
        Output ``.html`` file in an existing, writable folder; written atomically.
    product : xarray.Dataset or path-like
        Terrain product (``elevation``, ``elevation_std`` in m on ``(y, x)``), or a NetCDF /
        GeoTIFF file (:func:`toolkit.dem_io.read_dem`).
    certificate : dict or path-like
        Output of :func:`toolkit.certify.certify`, or its JSON file.
    truth : xarray.DataArray or ndarray of shape (ny, nx), optional
        True elevation (m) on the product's grid: adds the error map and calibration curve.
    samples : ElevationSamples or ndarray of shape (n, 2), optional
        Sample locations (easting/northing, m), drawn on the 1-sigma map.
    trajectory : mapping, optional
        ``{"xy_est": (n, 2), "xy_true": (n, 2) or None, "cov_xy": (n, 2, 2) or None,
        "landmarks_xy": (m, 2) or None}``: positions (m) and position covariances (m^2) in
        the product's CRS; draws the path with 95 % error ellipses.
    coverage : mapping of str to value, optional
        Survey coverage metrics (e.g. %SCC Eq 11, alpha Eq 12-13, beta Eq 14-16), shown as a
        table.
    title : str
        Page title.

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    terrain.errors.InputError
        Bad product, certificate, truth or trajectory shape; unwritable output.
    """
    import jinja2

    path = check_output_path(path, "report path")
    cert = _load_certificate(certificate)
    raster = read_dem(product)
    truth_v = _truth(truth, raster)
    if samples is not None:
        samples = np.asarray(getattr(samples, "xy", samples), dtype=float).reshape(-1, 2)
    interval = (cert.get("contour_interval") or {}).get("certified_m") or 1.0
    figures = [_fig_elevation(raster, float(interval), cert.get("breaklines") or [])]
    if raster.elevation_std is not None:
        figures.append(_fig_std(raster, samples))
    if truth_v is not None:
        figures.append(_fig_error(raster, truth_v))
        if raster.elevation_std is not None:
            figures.append(_fig_calibration(raster, truth_v, cert))
    if cert.get("heldout_calibration"):
        figures.append(_fig_heldout(cert))
    if cert.get("error_histogram"):
        figures.append(_fig_histogram(cert["error_histogram"]))
    if trajectory is not None:
        figures.append(_fig_trajectory(raster, trajectory))

    env = jinja2.Environment(
        loader=jinja2.PackageLoader("toolkit", "templates"),
        autoescape=True,
        undefined=jinja2.ChainableUndefined,
        keep_trailing_newline=True,
    )
    env.filters["fmt"] = _fmt
    html = env.get_template("report.html.j2").render(
        title=title,
        cert=cert,
        acc=cert.get("accuracy") or {},
        heldout=cert.get("heldout_calibration"),
        figures=figures,
        coverage=dict(coverage or {}),
        provenance=raster.provenance,
        grid=raster.grid,
        warnings=_warnings(cert, raster),
    )
    try:
        with atomic_path(path) as tmp:
            tmp.write_text(html, encoding="utf-8")
    except OSError as exc:
        raise bad_input("report path", str(path), "a writable file", str(exc)) from exc
    return path
