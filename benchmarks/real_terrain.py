"""Real terrain: glacimap vs Delaunay and peer gridders on sites shaped by real DEMs.

    python benchmarks/real_terrain.py --out benchmarks/results/real_terrain.json
    python benchmarks/real_terrain.py --sites olinda:1:60 --sizes 3000     # name:window:nodes
    python benchmarks/real_terrain.py --quick                               # olinda, n=3000
    python benchmarks/real_terrain.py --draw 1 --sizes 3000   # another draw of samples + noise
    python benchmarks/real_terrain.py --noise unstated        # samples without z_var (x, y, z)
    python benchmarks/real_terrain.py --resampling linear     # truth bilinear between nodes
    python benchmarks/real_terrain.py --noise-sd 0.05         # another signal-to-noise ratio
    python benchmarks/real_terrain.py --survey west-half      # east half on the prior alone
    python benchmarks/real_terrain.py --scattered 0.02        # the rover kept to its tracks
    python benchmarks/real_terrain.py --sites my_dem.tif --sizes 3000 50000   # a DEM of yours
    python benchmarks/real_terrain.py --feature scarp         # a 6 m scarp across the tracks
    python benchmarks/real_terrain.py --feature scarp-end     # the same, dying out inside

Sites: ``scripts/real_dems.glacier_site`` (a window of a real DEM — olinda, rm, glacier,
prism, lux, matplotlib's jacksboro and topobathy, spatstat's bei, gorillas and clm and R's
volcano — mapped onto 600 m x 600 m at 2 m, 25 m relief); samples: ``track_samples`` (8
rover tracks, ``--tracks``, + 10 % scattered, ``--scattered``; noise sd ``--noise-sd``, 0.2 m
by default, stated in ``z_var`` unless ``--noise unstated``; seed ``--draw``, 0 by default: every
site gets the same positions and noise, so the rows of one run share one noise draw). Every
method maps the truth's 300 x 300 cells from the same samples, each in its own process (wall
time and peak RSS are its own; one at a time: 2 cores):

``delaunay``      ``terrain.delaunay_linear`` — the reference: RMSEs are on its hull.
``glacimap``      ``terrain.TerrainGP(seed=0)``, the default estimator (constant mean).
``glacimap_dem``  the same with ``mean=terrain.coarse_dem(truth)`` (the 8 x 8 prior).
``glacimap_pycno`` the same 8 x 8 prior read as area means:
                  ``mean=terrain.PycnophylacticMean(coarse_dem(truth))``.
``glacimap_breakline`` the default estimator told the line of a ``--feature scarp``,
                  ``scarp-along`` or ``scarp-end``: ``mean=terrain.BreaklineMean([line])``
                  (a constant plus the step, its width and, where the line stops inside the
                  survey, its taper chosen by the fit, its height by GLS; the truth's step is
                  1.5 m wide; session 36's first runs gave ``width=1.0``).
``glacimap_breakline_across`` a ``--feature scarp-end``'s line run on across the site, as
                  0.36.0 required of every breakline (a step where the ground has none).
``glacimap_breakline_found`` the default estimator with the lines
                  ``terrain.find_breaklines`` finds in the samples (none: the plain map);
                  ``info.breakline_search`` says what it found, and how far the found lines'
                  vertices inside the survey lie from the feature's own line.
``glacimap_breakline_dem`` the feature's line on the 8 x 8 prior fitted as ``a + b * DEM``
                  (``RasterMean(coarse_dem(truth), offset="fit")``: as ``glacimap run`` and
                  ``--prior`` read a satellite DEM); the step counted once (terrain/dem_reading.py).
``rbf_tps64``     scipy ``RBFInterpolator``, thin-plate spline, 64 neighbours, smoothing 0.
``verde_knn``     ``verde.KNeighbors()`` defaults.
``verde_spline``  ``verde.BlockReduce(np.median, spacing=4)`` + ``verde.Spline()``; guarded:
                  skipped when its dense solve would pass the memory or time limit.
``pykrige_ok``    PyKrige ordinary kriging, spherical variogram on <= 3,000 samples (a
                  seeded subsample at n = 50,000), 64-point moving window, C backend.

Every glacimap row also runs the user's held-out check (``terrain.cross_validate``), timed
apart, and records the truth's coverage with its 1-sigma x sqrt(kappa), kappa the check's
one-scale ratio (``cov68_rescaled``: what a held-out recalibration would give; measured, not
the default).

Real DEMs come from Debian packages; when they cannot be fetched the benchmark prints why
and writes ``{"skipped": reason}``.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import multiprocessing as mp
import sys
import time
import traceback
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(ROOT / "scripts"))
from _harness import table, write_json  # noqa: E402
from real_dems import FEATURES, NAMES  # noqa: E402

SITES = NAMES  # every real DEM of scripts/real_dems.py
SIZES = (3000, 50_000)
METHODS = (
    "delaunay",
    "glacimap",
    "glacimap_dem",
    "glacimap_pycno",
    "glacimap_breakline",
    "glacimap_breakline_across",
    "glacimap_breakline_found",
    "glacimap_breakline_dem",
    "rbf_tps64",
    "verde_knn",
    "verde_spline",
    "pykrige_ok",
)
GLACIMAP = (
    "glacimap",
    "glacimap_dem",
    "glacimap_pycno",
    "glacimap_breakline",
    "glacimap_breakline_across",
    "glacimap_breakline_found",
    "glacimap_breakline_dem",
)
WITH_STD = (*GLACIMAP, "pykrige_ok")
SEED = 0
#: Samples' noise sd, m (``track_samples``' default; every result before session 21).
NOISE_SD = 0.2
#: The survey's shape (``track_samples``' defaults; every result before session 34): rover
#: tracks across the site and the fraction of samples scattered over it.
TRACKS = 8
SCATTERED = 0.1
#: Cells at least this far from every sample are scored apart (``rmse_far``...), m.
FAR_M = 50.0
# Guards: any case is killed past these; verde_spline is also skipped up front when its dense
# least-squares solve (~6 n x n float64 arrays) or its extrapolated time would pass them.
LIMIT_S = 1800.0
LIMIT_MB = 16_000.0
SPLINE_LIMIT_S = 600.0
SPLINE_LIMIT_MB = 12_000.0
SPLINE_COPIES = 6  # peak RSS of verde.Spline's fit ~ this many m x m float64 arrays
TARGETS = {"rmse_ratio": 0.8, "cov95": (92.0, 98.0), "cov68": (62.0, 76.0)}
HELDOUT_POINTS = 3.0  # held-out coverage within this many points of the truth's


def parse_site(spec: str) -> dict[str, Any]:
    """``name[:window[:nodes]]`` -> site dict (window 0, 40 nodes by default).

    ``name`` is one of ``real_dems.NAMES`` or the path of a DEM file (any raster GDAL reads),
    labelled by its stem: ``--sites ~/dems/my_glacier.tif:0:60``.
    """
    import real_dems

    parts = spec.split(":")
    if Path(spec).expanduser().is_file():  # a path that itself holds a colon
        parts = [spec]
    if len(parts) > 3 or not parts[0]:
        raise argparse.ArgumentTypeError(f"site: expected name[:window[:nodes]], got {spec!r}")
    name = parts[0] if parts[0] in real_dems.NAMES else str(Path(parts[0]).expanduser())
    if name not in real_dems.NAMES and not Path(name).is_file():
        raise argparse.ArgumentTypeError(
            f"site: {name!r} is neither a real DEM of scripts/real_dems.py "
            f"({', '.join(real_dems.NAMES)}) nor a DEM file"
        )
    try:
        window = int(parts[1]) if len(parts) > 1 else 0
        nodes = int(parts[2]) if len(parts) > 2 else 40
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"site: window and nodes are integers, got {spec!r}; e.g. olinda:1:60"
        ) from None
    short = name if name in real_dems.NAMES else Path(name).stem
    label = short if (window, nodes) == (0, 40) else f"{short}:{window}:{nodes}"
    return {"name": name, "window": window, "nodes": nodes, "label": label}


def _data(site: dict, n: int):
    import real_dems

    from terrain import Grid

    truth = real_dems.glacier_site(
        site["name"],
        nodes=site["nodes"],
        window=site["window"],
        resampling=site.get("resampling", "cubic"),
    )
    truth = real_dems.add_feature(truth, site.get("feature", "none"))
    samples = real_dems.track_samples(
        truth,
        n,
        n_tracks=site.get("tracks", TRACKS),
        scattered=site.get("scattered", SCATTERED),
        noise_sd=site.get("noise_sd", NOISE_SD),
        seed=site.get("draw", SEED),
        stated_var=site.get("noise", "stated") == "stated",
    )
    grid = Grid.from_dataarray(truth)
    if site.get("survey", "whole") == "west-half":  # the rover never reached the east half
        samples = samples.subset(np.flatnonzero(samples.xy[:, 0] < grid.xy()[:, 0].mean()))
    return truth, grid, samples


def _provenance() -> dict[str, Any]:
    """Which glacimap ran: the commit, and whether terrain/ or toolkit/ had local edits."""
    import subprocess

    import terrain

    out: dict[str, Any] = {"terrain": str(Path(terrain.__file__).resolve().parent)}
    try:
        git = ["git", "-C", str(ROOT)]
        out["commit"] = subprocess.run(
            [*git, "rev-parse", "HEAD"], capture_output=True, text=True, check=True
        ).stdout.strip()
        dirty = subprocess.run(
            [*git, "status", "--porcelain", "terrain", "toolkit"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout
        out["terrain_toolkit_edited"] = bool(dirty.strip())
    except (OSError, subprocess.CalledProcessError):
        out["commit"] = None
    return out


def _jsonable(v: Any) -> Any:
    if v is None or isinstance(v, (bool, int, str)):
        return v
    if isinstance(v, (float, np.floating)):
        return float(v)
    if isinstance(v, np.integer):
        return int(v)
    if isinstance(v, np.ndarray):
        return _jsonable(v.tolist())
    if isinstance(v, dict):
        return {str(k): _jsonable(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_jsonable(x) for x in v]
    return repr(v)


def _metrics(pred, std, truth, samples, grid) -> dict[str, Any]:
    """RMSE on Delaunay's hull and wherever defined; with ``std``: coverage (%), z, NLPD."""
    from scipy.spatial import Delaunay

    from terrain import evaluate

    off = samples.xy.mean(axis=0)  # as delaunay_linear: the hull of the centred samples
    hull = (Delaunay(samples.xy - off).find_simplex(grid.xy() - off) >= 0).reshape(grid.shape)
    t = truth.values
    ok = np.isfinite(pred)
    out: dict[str, Any] = {
        "rmse_hull": float(np.sqrt(np.mean((pred[hull] - t[hull]) ** 2))),
        "rmse_grid": float(np.sqrt(np.mean((pred[ok] - t[ok]) ** 2))),
        "defined_fraction": float(ok.mean()),
        "hull_fraction": float(hull.mean()),
        "hull_defined": bool(np.all(ok[hull])),
    }
    if std is not None:
        ok &= np.isfinite(std) & (std > 0)
        e = evaluate(pred[ok], t[ok], std[ok])
        eh = evaluate(pred[hull & ok], t[hull & ok], std[hull & ok])
        out.update(
            cov95=100 * e["coverage_95"],
            cov68=100 * e["coverage_68"],
            z_mean=e["z_mean"],
            z_std=e["z_std"],
            nlpd=e["nlpd"],
            cov95_hull=100 * eh["coverage_95"],
            cov68_hull=100 * eh["coverage_68"],
            median_std=float(np.median(std[ok])),
        )
    out.update(_far_metrics(pred, std, t, samples, grid))
    return out


def _far_metrics(pred, std, t, samples, grid) -> dict[str, Any]:
    """RMSE and coverage on the cells at least :data:`FAR_M` from every sample (where only
    the prior speaks: the unsurveyed half with ``--survey west-half``); ``None`` when no
    cell is that far."""
    from scipy.spatial import cKDTree

    from terrain import evaluate

    dist = cKDTree(samples.xy).query(grid.xy())[0].reshape(grid.shape)
    far = (dist >= FAR_M) & np.isfinite(pred)
    out: dict[str, Any] = {"far_fraction": float(far.mean()), "rmse_far": None}
    if not far.any():
        return out
    out["rmse_far"] = float(np.sqrt(np.mean((pred[far] - t[far]) ** 2)))
    if std is not None:
        ok = far & np.isfinite(std) & (std > 0)
        e = evaluate(pred[ok], t[ok], std[ok])
        out.update(cov95_far=100 * e["coverage_95"], cov68_far=100 * e["coverage_68"])
    return out


def _far_text(row: dict) -> str:
    """The far cells' scores for the progress line ('' when no cell is that far)."""
    if row.get("rmse_far") is None:
        return ""
    cov = f", {row['cov68_far']:.1f} / {row['cov95_far']:.1f} %" if "cov68_far" in row else ""
    share = f"{100 * row['far_fraction']:.0f} %"
    return f"; >= {FAR_M:g} m from data ({share}): RMSE {row['rmse_far']:.3f}{cov}"


def rescaled_coverage(pred, std, truth, kappa: float | None) -> dict[str, Any]:
    """Truth coverage (%) of the 1-sigma rescaled by the held-out check's one-scale ratio
    (sigma x sqrt(kappa): the map's error variance over its stated variance, fitted on the
    held-out residuals; :func:`terrain.heldout_design.one_scale_ratio`). Measures what a
    held-out recalibration of the sigma would give (docs/terrain.md "The 1-sigma rescaled by
    the held-out check"); empty without a ratio."""
    if kappa is None or not kappa > 0 or std is None:
        return {}
    ok = np.isfinite(pred) & np.isfinite(std) & (std > 0)
    z = np.abs(pred[ok] - truth[ok]) / (std[ok] * np.sqrt(kappa))
    return {
        "cov68_rescaled": 100 * float(np.mean(z < 1.0)),
        "cov95_rescaled": 100 * float(np.mean(z < 1.96)),
    }


def _heldout(gp, samples, grid) -> dict[str, Any]:
    """The user's sigma check without truth: terrain.cross_validate (5 folds, seed 0, blocks
    matched to the grid's distances), timed apart from the method."""
    from terrain import cross_validate

    t = time.perf_counter()
    cv = cross_validate(gp, samples, n_folds=5, seed=0, targets=grid)
    p = cv.pooled
    keys = ("coverage_95", "coverage_68", "map_coverage_95", "map_coverage_68")
    out = {k: 100 * p[k] for k in keys if p.get(k) is not None}
    for k in ("map_coverage_95_interval", "map_coverage_68_interval"):
        out[k] = [100 * v for v in p[k]] if p.get(k) else None
    for k in ("distance_matched_coverage_68", "neighbourhood_matched_coverage_68"):
        out[k] = None if p.get(k) is None else 100 * p[k]
    out.update(
        variance_ratio=p.get("variance_ratio"),
        noise_share=p.get("noise_share"),
        matched_on=p.get("matched_on"),
        neighbourhood_difference_sd=p.get("neighbourhood_difference_sd"),
        local_fit_used=p.get("local_fit_used"),
        local_fit_q=p.get("local_fit_q"),
        local_fit_noise_kept=p.get("local_fit_noise_kept"),
        one_scale_ratio=p.get("one_scale_ratio"),
        heldout_reach_m=p.get("heldout_reach_m"),
        map_beyond_reach=p.get("map_beyond_reach"),
        block_m=cv.block_size,
        rule=cv.block_size_rule,
        verdict=cv.verdict(),
        seconds=time.perf_counter() - t,
    )
    return out


def case(site: dict, n: int, method: str, spline_pred_s: float | None = None) -> dict:
    """One method on one site and size; runs in a child process."""
    import _peers

    truth, grid, samples = _data(site, n)
    q = grid.xy()
    info: dict[str, Any] = {}
    std = None
    method_end = None
    t0 = time.perf_counter()
    if method == "delaunay":
        from terrain import delaunay_linear

        pred = delaunay_linear(samples, grid).elevation.values
    elif method in GLACIMAP:
        import real_dems

        from terrain import BreaklineMean, PycnophylacticMean, RasterMean, TerrainGP, coarse_dem

        feature = site.get("feature", "none")
        line = real_dems.feature_line(truth, feature)
        if method in ("glacimap_breakline", "glacimap_breakline_dem") and line is None:
            why = "no breakline: --feature scarp, scarp-along or scarp-end"
            return {"skipped": why, "method_s": None}
        if method == "glacimap_breakline_across":  # a scarp-end's line run on across
            if feature != "scarp-end":
                return {"skipped": "only for --feature scarp-end", "method_s": None}
            line = real_dems.feature_line(truth, "scarp")
        search_info = None
        if method == "glacimap_breakline_found":  # the search is part of the method's time
            found, search_info = _found_lines(samples, line)
        means = {  # built for the method asked only (a plain site has no feature line)
            "glacimap": lambda: "constant",
            "glacimap_dem": lambda: coarse_dem(truth),
            "glacimap_pycno": lambda: PycnophylacticMean(coarse_dem(truth)),
            "glacimap_breakline": lambda: BreaklineMean([line]),  # width="auto"
            "glacimap_breakline_across": lambda: BreaklineMean([line]),
            "glacimap_breakline_found": lambda: BreaklineMean(found) if found else "constant",
            # the line on the 8 x 8 prior read as the pipeline reads a satellite DEM: a + b * DEM
            "glacimap_breakline_dem": lambda: BreaklineMean(
                [line], base=RasterMean(coarse_dem(truth), offset="fit")
            ),
        }
        kw = {"mean": means[method]()}
        gp = TerrainGP(seed=0, **kw)
        tf = time.perf_counter()
        gp.fit(samples)
        fit_s = getattr(gp, "fit_seconds_", None)
        tp = time.perf_counter()
        ds = gp.predict_grid(grid)
        pred, std = ds.elevation.values, ds.elevation_std.values
        method_end = time.perf_counter()  # the held-out check below is timed apart
        info = {
            "fit_s": float(fit_s) if fit_s is not None else tp - tf,
            "predict_s": time.perf_counter() - tp,
            "kernel": repr(getattr(gp, "kernel_", None)),
            "kernel_scores": _jsonable(getattr(gp, "kernel_scores_", None)),
            "nugget": _jsonable(getattr(gp, "nugget_", None)),
            "gp_method": _jsonable(getattr(gp, "method_", None)),
            "lml": _jsonable(getattr(gp, "log_marginal_likelihood_value_", None)),
        }
        if search_info is not None:
            info["breakline_search"] = search_info
        info["heldout"] = _heldout(gp, samples, grid)
    elif method == "rbf_tps64":
        pred, std, info = _peers.rbf_tps(samples, q, neighbors=64)
    elif method == "verde_knn":
        pred, std, info = _peers.verde_knn(samples, q)
    elif method == "verde_spline":
        m = _peers.spline_blocks(samples)
        need_mb = SPLINE_COPIES * m * m * 8 / 2**20
        reason = None
        if need_mb > SPLINE_LIMIT_MB:
            reason = f"{m} blocks: dense solve needs ~{need_mb:,.0f} MB > {SPLINE_LIMIT_MB:,.0f}"
        elif spline_pred_s is not None and spline_pred_s > 1.5 * SPLINE_LIMIT_S:
            reason = (
                f"{m} blocks: extrapolated (m^3 from n=3000) {spline_pred_s:,.0f} s"
                f" > 1.5 x {SPLINE_LIMIT_S:.0f} s"
            )
        if reason:
            return {"skipped": reason, "blocks": m, "est_mb": need_mb, "method_s": None}
        pred, std, info = _peers.verde_spline(samples, q)
        info["est_mb"] = need_mb
    elif method == "pykrige_ok":
        pred, std, info = _peers.pykrige_ok(samples, q, seed=SEED)
    else:
        raise ValueError(f"method: expected one of {METHODS}, got {method!r}")
    method_s = (method_end or time.perf_counter()) - t0
    pred = np.asarray(pred, float).reshape(grid.shape)
    std = None if std is None else np.asarray(std, float).reshape(grid.shape)
    out = _metrics(pred, std, truth, samples, grid)
    kappa = (info.get("heldout") or {}).get("one_scale_ratio")
    out.update(rescaled_coverage(pred, std, truth.values, kappa))
    out.update(method_s=method_s, n_samples=samples.n, info=_jsonable(info))
    return out


def _found_lines(samples, truth_line) -> tuple[list, dict[str, Any]]:
    """``terrain.find_breaklines`` on the samples: the lines, and what was found (with the
    found vertices' distances, inside the samples' box, to the feature's line when known)."""
    from terrain import find_breaklines

    search = find_breaklines(samples)
    info: dict[str, Any] = {
        "summary": search.summary(),
        "n_lines": len(search.lines),
        "steps_m": search.steps_m,
        "dropped": search.dropped,
    }
    if truth_line is not None and search.lines:
        from shapely import LineString, Point

        ref = LineString(truth_line)
        lo, hi = samples.xy.min(axis=0), samples.xy.max(axis=0)
        d = [
            ref.distance(Point(v))
            for line in search.lines
            for v in line
            if np.all(v >= lo) and np.all(v <= hi)
        ]
        if d:
            info["vertex_offset_median_m"] = float(np.median(d))
            info["vertex_offset_max_m"] = float(np.max(d))
    return search.lines, info


def _safe_child(func, args, queue) -> None:
    import resource

    t0 = time.perf_counter()
    try:
        out = func(*args)
    except Exception as exc:  # a broken method is a row with its error, not a hung run
        out = {"error": f"{type(exc).__name__}: {exc}", "traceback": traceback.format_exc()}
    out["wall_s"] = time.perf_counter() - t0
    out["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    queue.put(out)


def _rss_mb(pid: int) -> float:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return 0.0


def guarded(func, *args, limit_s: float = LIMIT_S, limit_mb: float = LIMIT_MB) -> dict:
    """``_harness.in_subprocess`` with a watchdog: the child is killed past ``limit_s``
    seconds or ``limit_mb`` MB resident, and the row says so; a crash is a row too."""
    import queue as queue_mod

    ctx = mp.get_context("spawn")
    q = ctx.Queue()
    proc = ctx.Process(target=_safe_child, args=(func, args, q))
    t0 = time.perf_counter()
    proc.start()
    peak = 0.0
    while True:
        try:
            out = q.get(timeout=0.5)
            proc.join()
            return out
        except queue_mod.Empty:
            pass
        peak = max(peak, _rss_mb(proc.pid))
        wall = time.perf_counter() - t0
        reason = None
        if wall > limit_s:
            reason = f"killed: over {limit_s:.0f} s"
        elif peak > limit_mb:
            reason = f"killed: resident {peak:,.0f} MB > {limit_mb:,.0f} MB"
        elif not proc.is_alive() and q.empty():
            reason = f"child died (exit code {proc.exitcode})"
        if reason:
            proc.kill()
            proc.join()
            return {"skipped": reason, "wall_s": wall, "peak_rss_mb": peak, "method_s": None}


def _ratios(rows: list[dict]) -> None:
    """Per site and size: RMSE and time relative to Delaunay and RBF of the same run."""
    by = {}
    for r in rows:
        by.setdefault((r["site"], r["n"]), {})[r["method"]] = r
    for group in by.values():
        dl, rbf = group.get("delaunay", {}), group.get("rbf_tps64", {})
        for r in group.values():
            for ref, key in ((dl, "delaunay"), (rbf, "rbf")):
                if r.get("rmse_hull") is not None and ref.get("rmse_hull"):
                    r[f"rmse_over_{key}"] = r["rmse_hull"] / ref["rmse_hull"]
                if r.get("method_s") is not None and ref.get("method_s"):
                    r[f"time_over_{key}"] = r["method_s"] / ref["method_s"]


def _heldout_gap(r: dict) -> dict[str, Any]:
    """Held-out map coverage (noise removed) against the truth's, points; target: within 3."""
    h = (r.get("info") or {}).get("heldout") or {}
    if h.get("map_coverage_95") is None:
        return {}
    d95 = h["map_coverage_95"] - r["cov95"]
    d68 = h["map_coverage_68"] - r["cov68"]
    return {
        "cv95": h["map_coverage_95"],
        "cv68": h["map_coverage_68"],
        "d95": d95,
        "d68": d68,
        "cv_ok": "PASS" if max(abs(d95), abs(d68)) <= HELDOUT_POINTS else "MISS",
    }


def _rescaled_verdict(r: dict) -> dict[str, Any]:
    """Both coverages in their bands once the sigma is rescaled by the held-out check."""
    if r.get("cov68_rescaled") is None:
        return {}
    lo95, hi95 = TARGETS["cov95"]
    lo68, hi68 = TARGETS["cov68"]
    ok = lo68 <= r["cov68_rescaled"] <= hi68 and lo95 <= r["cov95_rescaled"] <= hi95
    return {
        "cov68_rescaled": r["cov68_rescaled"],
        "cov95_rescaled": r["cov95_rescaled"],
        "rescaled_ok": "PASS" if ok else "MISS",
    }


def _verdicts(rows: list[dict]) -> list[dict]:
    """The targets for the glacimap rows: PASS / MISS (— when not measured)."""
    out = []
    rbf = {(r["site"], r["n"]): r for r in rows if r["method"] == "rbf_tps64"}
    for r in rows:
        if not r["method"].startswith("glacimap") or r.get("rmse_hull") is None:
            continue

        def pf(ok):
            return None if ok is None else ("PASS" if ok else "MISS")

        peer = rbf.get((r["site"], r["n"]), {}).get("rmse_hull")
        ratio = r.get("rmse_over_delaunay")
        lo95, hi95 = TARGETS["cov95"]
        lo68, hi68 = TARGETS["cov68"]
        out.append(
            {
                "site": r["site"],
                "n": r["n"],
                "method": r["method"],
                "rmse_over_delaunay": ratio,
                "rmse_ok": pf(None if ratio is None else ratio <= TARGETS["rmse_ratio"]),
                "cov95": r.get("cov95"),
                "cov95_ok": pf(lo95 <= r["cov95"] <= hi95),
                "cov68": r.get("cov68"),
                "cov68_ok": pf(lo68 <= r["cov68"] <= hi68),
                "rmse_over_rbf": r.get("rmse_over_rbf"),
                "rbf_ok": pf(None if peer is None else r["rmse_hull"] <= peer),
                **_heldout_gap(r),
                **_rescaled_verdict(r),
            }
        )
    return out


def report(rows: list[dict]) -> list[dict]:
    _ratios(rows)
    for r in rows:
        r["case"] = f"{r['site']} {r['n'] // 1000}k"
        r["note"] = r.get("skipped") or r.get("error")
    print(
        "\nReal terrain: 600 m x 600 m at 2 m (300 x 300 cells), 25 m relief; RMSE on Delaunay's"
        " hull (m); coverage over the grid (%); times: the method itself (s, data making"
        " excluded), ratios to Delaunay and RBF of the same run; wall and peak RSS per process"
    )
    wc = max(len(r["case"]) for r in rows)
    wm = max(len(r["method"]) for r in rows)
    print(
        table(
            rows,
            [
                ("case", "case".rjust(wc), ""),
                ("method", "method".rjust(wm), ""),
                ("rmse_hull", "RMSE hull", ".3f"),
                ("rmse_over_delaunay", "/Delaunay", ".3f"),
                ("rmse_grid", "RMSE grid", ".3f"),
                ("defined_fraction", "defined", ".3f"),
                ("cov95", "in 95%", ".1f"),
                ("cov68", "in 68%", ".1f"),
                ("z_mean", "z mean", ".2f"),
                ("z_std", "z std", ".2f"),
                ("nlpd", "NLPD", ".2f"),
                ("method_s", "time s", ".2f"),
                ("time_over_delaunay", "t/Delaunay", ".1f"),
                ("time_over_rbf", "t/RBF", ".2f"),
                ("wall_s", "wall s", ".1f"),
                ("peak_rss_mb", "peak MB", ".0f"),
            ],
        )
    )
    notes = [r for r in rows if r["note"]]
    for r in notes:
        print(f"  {r['case']} {r['method']}: {r['note']}")
    print("\nglacimap: fit / predict seconds, chosen kernel, selection scores (kernel_scores_)")
    for r in rows:
        info = r.get("info") or {}
        if r["method"].startswith("glacimap") and "kernel" in info:
            print(
                f"  {r['case']:<12} {r['method']:<13} fit {info['fit_s']:.1f} s, predict"
                f" {info['predict_s']:.1f} s, {info.get('gp_method')}, nugget"
                f" {info.get('nugget')}: {info['kernel']}"
            )
            if info.get("kernel_scores") is not None:
                print(f"  {'':<26} scores: {json.dumps(info['kernel_scores'])[:300]}")
    for r in rows:
        info = r.get("info") or {}
        if r["method"] == "pykrige_ok" and "variogram_model" in info:
            print(
                f"  {r['case']:<12} pykrige_ok    {info['variogram_model']} on"
                f" {info['samples_used']} samples"
                + (" (seeded subsample)" if info["subsampled"] else "")
                + f", {info['n_closest_points']}-point window, {info['backend']} backend"
            )
        if r["method"] == "verde_spline" and "blocks" in info:
            print(
                f"  {r['case']:<12} verde_spline  {info['blocks']} blocks of"
                f" {info['block_spacing_m']:g} m: fit {info['fit_s']:.1f} s, predict"
                f" {info['predict_s']:.1f} s"
            )
    verdicts = _verdicts(rows)
    if verdicts:
        print(
            f"\nTargets: RMSE <= {TARGETS['rmse_ratio']} x Delaunay (on its hull), 95 % coverage"
            f" {TARGETS['cov95'][0]:.0f}-{TARGETS['cov95'][1]:.0f}, 68 % coverage"
            f" {TARGETS['cov68'][0]:.0f}-{TARGETS['cov68'][1]:.0f}, RMSE <= RBF's (on the hull);"
            " held-out map coverage (cross_validate, noise removed) within"
            f" {HELDOUT_POINTS:g} points of the truth's (d = CV - truth); 'xk': the truth's"
            " coverages with the 1-sigma x sqrt(held-out one-scale ratio), measured, not the"
            " default"
        )
        print(
            table(
                verdicts,
                [
                    ("site", "site".rjust(max(len(v["site"]) for v in verdicts)), ""),
                    ("n", "n", "d"),
                    ("method", "method".rjust(max(len(v["method"]) for v in verdicts)), ""),
                    ("rmse_over_delaunay", "/Delaunay", ".3f"),
                    ("rmse_ok", "<=0.8", ""),
                    ("cov95", "in 95%", ".1f"),
                    ("cov95_ok", "92-98", ""),
                    ("cov68", "in 68%", ".1f"),
                    ("cov68_ok", "62-76", ""),
                    ("rmse_over_rbf", "/RBF", ".3f"),
                    ("rbf_ok", "<=RBF", ""),
                    ("cv95", "CV 95%", ".1f"),
                    ("cv68", "CV 68%", ".1f"),
                    ("d95", "d95", "+.1f"),
                    ("d68", "d68", "+.1f"),
                    ("cv_ok", "|d|<=3", ""),
                    ("cov95_rescaled", "95% xk", ".1f"),
                    ("cov68_rescaled", "68% xk", ".1f"),
                    ("rescaled_ok", "xk in", ""),
                ],
            )
        )
    return verdicts


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/real_terrain.json"))
    ap.add_argument(
        "--sites", nargs="+", type=parse_site, default=None, help="name[:window[:nodes]]"
    )
    ap.add_argument("--sizes", nargs="+", type=int, default=None)
    ap.add_argument("--methods", nargs="+", choices=METHODS, default=list(METHODS))
    ap.add_argument("--quick", action="store_true", help="olinda only, n = 3000")
    ap.add_argument(
        "--draw",
        type=int,
        default=SEED,
        help="seed of the sample positions and noise (track_samples); 0: every result so far",
    )
    ap.add_argument(
        "--noise",
        choices=("stated", "unstated"),
        default="stated",
        help="whether the samples state their noise variance (z_var); unstated: z_var = 0, "
        "as in a CSV of x, y, z, and the nugget must find the noise",
    )
    ap.add_argument(
        "--noise-sd",
        type=float,
        default=NOISE_SD,
        help="sd of the samples' noise, m (0.2: every result so far; the relief stays 25 m, "
        "so this sets the survey's signal-to-noise ratio)",
    )
    ap.add_argument(
        "--tracks",
        type=int,
        default=TRACKS,
        help="rover tracks across the site (8: every result so far)",
    )
    ap.add_argument(
        "--scattered",
        type=float,
        default=SCATTERED,
        help="fraction of the samples scattered uniformly over the site instead of on the "
        "tracks (0.1: every result so far)",
    )
    ap.add_argument(
        "--survey",
        choices=("whole", "west-half"),
        default="whole",
        help="where the rover went: the whole site (every result so far) or the west half "
        "only, the map's east half then resting on its prior (scored as rmse_far, "
        "cov68_far, cov95_far: cells at least FAR_M = 50 m from every sample)",
    )
    ap.add_argument(
        "--resampling",
        choices=("cubic", "linear"),
        default="cubic",
        help="truth between the DEM's nodes: bicubic (every result so far) or bilinear facets",
    )
    ap.add_argument(
        "--feature",
        choices=FEATURES,
        default="none",
        help="a sharp ground feature added to every site (real_dems.add_feature): a scarp "
        "crossed by the tracks, lying between them or dying out inside the site, a flat lake, "
        "terraces (none: every "
        "result before session 36)",
    )
    args = ap.parse_args(argv)
    if args.tracks < 1:
        ap.error(f"--tracks: expected at least 1 rover track, got {args.tracks}")
    if not 0.0 <= args.scattered < 1.0:
        ap.error(f"--scattered: expected a fraction in [0, 1), got {args.scattered}; e.g. 0.02")
    sites = args.sites or [parse_site(s) for s in (("olinda",) if args.quick else SITES)]
    for site in sites:
        site["draw"] = args.draw
        site["noise"] = args.noise
        site["resampling"] = args.resampling
        site["noise_sd"] = args.noise_sd
        site["survey"] = args.survey
        site["tracks"] = args.tracks
        site["scattered"] = args.scattered
        site["feature"] = args.feature
    sizes = sorted(args.sizes or ((3000,) if args.quick else SIZES))
    import real_dems

    prov = _provenance()

    def payload(rows, **extra):
        return {
            "benchmark": "real_terrain",
            "settings": {
                "sites": sites,
                "sizes": sizes,
                "methods": args.methods,
                "seed": SEED,
                "draw": args.draw,
                "noise": args.noise,
                "resampling": args.resampling,
                "noise_sd_m": args.noise_sd,
                "survey": args.survey,
                "far_m": FAR_M,
                "grid": "truth's 2 m grid, 300 x 300 cells",
                "tracks": args.tracks,
                "scattered": args.scattered,
                "feature": args.feature,
                "samples": "real_dems.track_samples: `tracks` tracks + a `scattered` fraction "
                "uniformly over the site, sd noise_sd_m",
                "targets": TARGETS,
                "guards": {
                    "limit_s": LIMIT_S,
                    "limit_mb": LIMIT_MB,
                    "spline_limit_s": SPLINE_LIMIT_S,
                    "spline_limit_mb": SPLINE_LIMIT_MB,
                },
            },
            "provenance": prov,
            "results": rows,
            **extra,
        }

    try:
        if any(s["name"] in real_dems.FILES for s in sites):  # not matplotlib's, not a file
            real_dems.fetch()
        for s in sites:
            real_dems.glacier_site(
                s["name"], nodes=s["nodes"], window=s["window"], resampling=s["resampling"]
            )
    except real_dems.RealDataUnavailable as exc:
        print(f"skipped: {exc}")
        write_json(args.out, payload([], skipped=str(exc)))
        return 0
    rows: list[dict] = []
    for site in sites:
        spline_3k: dict | None = None
        for n in sizes:
            for method in args.methods:
                extra = ()
                limits = {}
                if method == "verde_spline":
                    limits = {"limit_s": SPLINE_LIMIT_S, "limit_mb": SPLINE_LIMIT_MB}
                    info = (spline_3k or {}).get("info") or {}
                    if info.get("blocks") and n > spline_3k["n"]:
                        m_small = info["blocks"]
                        from _peers import spline_blocks

                        _, _, samples = _data(site, n)
                        m = spline_blocks(samples)
                        extra = (info["fit_s"] * (m / m_small) ** 3,)
                row = guarded(case, site, n, method, *extra, **limits)
                row.update(site=site["label"], n=n, method=method)
                if method == "verde_spline" and row.get("rmse_hull") is not None:
                    spline_3k = spline_3k or row
                rows.append(row)
                note = row.get("skipped") or row.get("error") or ""
                print(
                    f"[{site['label']} n={n}] {method}: {row['wall_s']:.1f} s, peak"
                    f" {row['peak_rss_mb']:.0f} MB"
                    + (f", RMSE hull {row['rmse_hull']:.3f}" if "rmse_hull" in row else "")
                    + _far_text(row)
                    + (f"  ({note[:160]})" if note else ""),
                    flush=True,
                )
                with contextlib.redirect_stdout(io.StringIO()):  # a killed run keeps its rows
                    write_json(args.out, payload(rows, partial=True))
    verdicts = report(rows)
    write_json(args.out, payload(rows, verdicts=verdicts))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
