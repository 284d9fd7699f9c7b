"""Scalable GP (issue 3): fidelity to the exact GP, calibration, speed and memory, Dask,
and peers (scipy Delaunay, PyKrige moving-window kriging), all in one run.

    python benchmarks/gp_scalable.py --out benchmarks/results/gp_scalable.json
    python benchmarks/gp_scalable.py --cases fidelity calibration   # a subset

Every case runs in its own process (peak RSS is its own). Data: the default site
(600 m, 25 m relief, dunes, crevasses, a melt pool) or larger random glaciers, landmarks
beside a lawnmower path (`terrain.sample_along_path`), the 8 x 8 satellite prior. The maps
run each kernel (Matern 2.5 as in 0.3.0; SE, Eq 1, the default and the better by evidence)
without and with `TerrainGP(local_amplitude=True)`, so before/after are in the same run.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _harness import in_subprocess, table, write_json  # noqa: E402

KERNEL = (0.18, 15.0)  # start: variance m^2, length scale m
LONG = (1.0, 100.0)  # start of the long part of "se+long": variance m^2, length scale m
# "se": Eq 1, TerrainGP's default, and the family with the higher evidence on the default
# site (Eq 9 on the same 1,000-sample fit subset: printed as "lml"); "matern25": the kernel
# these benchmarks used before (0.3.0).
# "se+long": SE plus a long SE, for the prior mean's error at tens to hundreds of metres.
KERNEL_LABEL = {"se": "SE", "matern25": "Matern 2.5", "se+long": "SE + long SE"}


def _kernel(name: str):
    from terrain import Matern, SquaredExponential

    if name == "se+long":
        return SquaredExponential(*KERNEL) + SquaredExponential(*LONG)
    return SquaredExponential(*KERNEL) if name == "se" else Matern(*KERNEL, nu=2.5)


def _label(kernel: str, amp: bool) -> str:
    return KERNEL_LABEL[kernel] + (" + local amp" if amp else "")


def _site(n: int, resolution: float, swaths: int = 4, seed: int = 0):
    from terrain import Grid, TriangulatedMean, coarse_dem, default_site, sample_along_path
    from toolkit.demo import demo_path

    truth = default_site(resolution)
    grid = Grid.from_dataarray(truth)
    samples, _ = sample_along_path(truth, demo_path(grid, swaths), n, seed=seed)
    return truth, grid, samples, TriangulatedMean(coarse_dem(truth))


def _block_ci(az, mask, block: int = 50, reps: int = 2000) -> list[float]:
    """95 % block-bootstrap intervals of the 68 % and 95 % coverage over ``mask``: the cells'
    errors are correlated over tens of metres, so whole 50 m blocks are resampled."""
    by, bx = np.indices(mask.shape) // block
    ids = (by * (mask.shape[1] // block + 1) + bx)[mask]
    uniq, inv = np.unique(ids, return_inverse=True)
    cnt = np.bincount(inv)
    h68 = np.bincount(inv, weights=az[mask] <= 1.0)
    h95 = np.bincount(inv, weights=az[mask] <= 1.96)
    pick = np.random.default_rng(0).integers(0, uniq.size, (reps, uniq.size))
    c68 = h68[pick].sum(1) / cnt[pick].sum(1)
    c95 = h95[pick].sum(1) / cnt[pick].sum(1)
    return [float(np.percentile(c, q)) for c in (c68, c95) for q in (2.5, 97.5)]


def _scores(pred, std, truth, samples, grid) -> dict:
    from scipy.spatial import cKDTree

    from terrain import evaluate

    far = cKDTree(samples.xy).query(grid.xy())[0].reshape(grid.shape) > 20.0
    out = {k: v for k, v in evaluate(pred, truth, std).items()}
    f = evaluate(pred[far], truth[far], std[far])
    az = np.abs(pred - truth) / std

    def tail(a):  # |z| quantile ratio: 1.96 for Gaussian errors, larger for heavy tails
        return float(np.quantile(a, 0.95) / np.quantile(a, 0.683))

    out.update(
        z_q95_over_q68=tail(az),
        far_fraction=float(far.mean()),
        far_coverage_95=f["coverage_95"],
        far_coverage_68=f["coverage_68"],
        far_z_std=f["z_std"],
        far_z_q95_over_q68=tail(az[far]),
        coverage_ci=_block_ci(az, np.ones_like(far)),
        far_coverage_ci=_block_ci(az, far),
    )
    return out


def case_fidelity(n: int, kernel: str = "matern25") -> dict:
    from terrain import TerrainGP

    truth, grid, samples, prior = _site(n, 4.0)
    fit = TerrainGP(
        _kernel(kernel), mean=prior, n_restarts=0, max_fit_samples=1000, method="tiled"
    ).fit(samples)
    kw = dict(
        kernel=fit.kernel_, mean=prior, nugget=fit.nugget_, nugget_bounds="fixed", optimize=False
    )
    t0 = time.perf_counter()
    m1, s1 = TerrainGP(method="exact", **kw).fit(samples).predict(grid.xy(), return_std=True)
    t1 = time.perf_counter()
    m2, s2 = TerrainGP(method="tiled", **kw).fit(samples).predict(grid.xy(), return_std=True)
    t2 = time.perf_counter()
    tv = truth.values.ravel()
    r1, r2 = float(np.sqrt(np.mean((m1 - tv) ** 2))), float(np.sqrt(np.mean((m2 - tv) ** 2)))
    return {
        "case": f"fidelity n={n}" + ("" if kernel == "matern25" else f", {_label(kernel, False)}"),
        "kernel": repr(fit.kernel_),
        "n": n,
        "rmse_exact": r1,
        "rmse_tiled": r2,
        "rmse_ratio": r2 / r1,
        "median_rel_std_diff": float(np.median(np.abs(s2 - s1) / s1)),
        "exact_s": t1 - t0,
        "tiled_s": t2 - t1,
    }


SITES = {
    "default": "default site",
    "random1200": "1200 m random glacier",
    "gpdraw": "Eq 1 draw site",
    "gpdraw1200": "1200 m Eq 1 draw site, DEM beyond it",
}


def case_map(
    n: int,
    kernel: str,
    amp: bool,
    resolution: float = 1.0,
    site: str = "default",
    truth_seed: int = 3,
) -> dict:
    """Fit (hyperparameters on 1,000 samples) and map mean + std: calibration, peers, time.

    ``site``: "default" (600 m, dunes, crevasses, a melt pool), "random1200" (a 1200 m random
    glacier with features, 8 swaths) or "gpdraw" (600 m: a smooth trend plus a draw from Eq 1
    with variance 0.18 m^2 and length scale 15 m, ``terrain.gaussian_field_terrain``: the
    model the GP assumes, so calibration misses there are the estimator's, not the terrain's).
    """
    from terrain import (
        Grid,
        TerrainGP,
        TriangulatedMean,
        coarse_dem,
        gaussian_field_site,
        gaussian_field_terrain,
        random_terrain,
        sample_along_path,
    )
    from toolkit.demo import demo_path

    if site == "default":
        truth, grid, samples, prior = _site(n, resolution)
    elif site == "gpdraw1200":
        truth, dem = gaussian_field_site(1200.0, resolution, seed=truth_seed)
        grid = Grid.from_dataarray(truth)
        samples, _ = sample_along_path(truth, demo_path(grid, 4), n, seed=0)
        prior = TriangulatedMean(dem)
    else:
        size = 1200.0 if site == "random1200" else 600.0
        grid = Grid.from_bounds((0, 0, size, size), resolution)
        if site == "random1200":
            truth = random_terrain(grid, relief=25.0, seed=truth_seed, features=True)
        else:
            truth = gaussian_field_terrain(grid, 0.18, 15.0, relief=25.0, seed=truth_seed)
        samples, _ = sample_along_path(truth, demo_path(grid, int(size // 150)), n, seed=0)
        prior = TriangulatedMean(coarse_dem(truth))
    t0 = time.perf_counter()
    gp = TerrainGP(
        _kernel(kernel), mean=prior, n_restarts=0, max_fit_samples=1000, local_amplitude=amp
    ).fit(samples)
    t1 = time.perf_counter()
    ds = gp.predict_grid(grid)
    t2 = time.perf_counter()
    out = _scores(ds.elevation.values, ds.elevation_std.values, truth.values, samples, grid)
    from scipy.interpolate import LinearNDInterpolator

    off = samples.xy.mean(axis=0)  # the peer on the same samples and cells: its hull only
    dl = LinearNDInterpolator(samples.xy - off, samples.z)(grid.xy() - off).reshape(grid.shape)
    hull = np.isfinite(dl)
    err_gp = ds.elevation.values[hull] - truth.values[hull]
    out.update(
        rmse_delaunay_hull=float(np.sqrt(np.mean((dl[hull] - truth.values[hull]) ** 2))),
        rmse_gp_on_hull=float(np.sqrt(np.mean(err_gp**2))),
    )
    out["gp_over_delaunay_rmse"] = out["rmse_gp_on_hull"] / out["rmse_delaunay_hull"]
    out.update(
        case=f"{n // 1000}k -> {grid.ny}x{grid.nx}, {_label(kernel, amp)}"
        + ("" if not site.startswith("gpdraw") else f", {SITES[site]} {truth_seed}"),
        site=SITES[site],
        n=n,
        lml=gp.log_marginal_likelihood_value_,
        amplitudes=gp.tile_stats_.get("amplitudes"),
        fit_s=t1 - t0,
        predict_s=t2 - t1,
        total_s=t2 - t0,
        method=gp.method_,
        kernel=repr(gp.kernel_),
        nugget=gp.nugget_,
    )
    return out


def case_gpdraw(
    kernel: str,
    amp: bool,
    seeds: tuple[int, ...] = (3, 4, 5, 6, 7),
    site: str = "gpdraw",
    resolution: float = 1.0,
) -> dict:
    """Calibration on several independent Eq 1 draw sites, pooled: cells > 20 m from data are
    1-2 % of one 600 m site in a few blobs, so one truth's far coverage is a handful of
    correlated patches (its block-bootstrap 68 % interval spans ~0.4-0.7)."""
    rows = [case_map(50_000, kernel, amp, resolution, site, s) for s in seeds]
    w = np.array([r["far_fraction"] for r in rows])
    shape = "600x600" if site == "gpdraw" else "1200 m at 2 m"
    out: dict = {"case": f"50k -> {shape}, {_label(kernel, amp)}, Eq 1 draw x{len(seeds)}"}
    for k in ("rmse", "z_std"):  # pooled over equal-size grids: root mean square
        out[k] = float(np.sqrt(np.mean([r[k] ** 2 for r in rows])))
    for k in ("coverage_95", "coverage_68", "gp_over_delaunay_rmse", "fit_s", "predict_s"):
        out[k] = float(np.mean([r[k] for r in rows]))
    for k in ("far_coverage_95", "far_coverage_68"):
        out[k] = float(np.sum(w * [r[k] for r in rows]) / w.sum())
    out.update(
        far_fraction=float(w.mean()),
        per_truth={
            k: [r[k] for r in rows]
            for k in ("coverage_95", "coverage_68", "far_coverage_95", "far_coverage_68")
        },
        kernels=[r["kernel"] for r in rows],
        nuggets=[r["nugget"] for r in rows],
        truth_seeds=list(seeds),
    )
    return out


def case_dask(size: float = 5000.0, n: int = 200_000, chunks: int = 1000) -> dict:
    """A 5 km x 5 km, 1 m map through Dask; only block reductions are kept in memory."""
    import dask

    from terrain import ElevationSamples, Grid, Matern, TerrainGP, terrain_function
    from toolkit.demo import demo_path

    grid = Grid.from_bounds((0, 0, size, size), 1.0)
    surface = terrain_function(grid, relief=60.0, seed=9, features=True)
    path = demo_path(Grid.from_bounds((0, 0, size, size), 50.0), 3)
    rng = np.random.default_rng(0)
    s = rng.uniform(0, 1, n)
    seg = np.repeat(np.arange(len(path) - 1), 1)
    idx = rng.integers(0, len(seg), n)
    base = path[idx] + s[:, None] * (path[idx + 1] - path[idx])
    xy = np.clip(base + rng.normal(0, 20.0, (n, 2)), 1, size - 1)
    z = surface(xy) + rng.normal(0, 0.15, n)
    samples = ElevationSamples(xy, z, 0.15**2, crs=grid.crs, duplicates="average")
    t0 = time.perf_counter()
    gp = TerrainGP(Matern(*KERNEL, nu=2.5), n_restarts=0, max_fit_samples=1000).fit(samples)
    ds = gp.predict_grid(grid, chunks=chunks)
    with dask.config.set(scheduler="threads", num_workers=1):
        mean_elev, max_std = dask.compute(ds.elevation.mean(), ds.elevation_std.max())
    t1 = time.perf_counter()
    return {
        "case": f"dask {int(size)}x{int(size)} m @1 m",
        "n": n,
        "cells": grid.size,
        "total_s": t1 - t0,
        "chunks": chunks,
        "mean_elevation": float(mean_elev),
        "max_std": float(max_std),
        "method": gp.method_,
    }


def case_peers(n: int = 10_000, n_query: int = 10_000) -> dict:
    """Identical data and cells: TerrainGP vs scipy Delaunay vs PyKrige moving window."""
    from pykrige.ok import OrdinaryKriging
    from scipy.interpolate import LinearNDInterpolator

    from terrain import TerrainGP

    truth, grid, samples, prior = _site(n, 1.0)
    rng = np.random.default_rng(1)
    cells = rng.choice(grid.size, n_query, replace=False)
    q = grid.xy()[cells]
    tv = truth.values.ravel()[cells]
    variants = {}
    for kernel, amp in (("matern25", False), ("se", False), ("se", True)):
        t0 = time.perf_counter()
        gp = TerrainGP(
            _kernel(kernel), mean=prior, n_restarts=0, max_fit_samples=1000, local_amplitude=amp
        )
        variants[_label(kernel, amp)] = (gp.fit(samples).predict(q), time.perf_counter() - t0)
    m_gp, gp_s = variants[_label("se", True)]
    t1 = time.perf_counter()
    off = samples.xy.mean(axis=0)
    m_dl = LinearNDInterpolator(samples.xy - off, samples.z)(q - off)
    t2 = time.perf_counter()
    ok = OrdinaryKriging(
        samples.xy[:, 0] - off[0],
        samples.xy[:, 1] - off[1],
        samples.z,
        variogram_model="spherical",
        nlags=30,
    )
    m_ok, _ = ok.execute(
        "points", q[:, 0] - off[0], q[:, 1] - off[1], backend="loop", n_closest_points=64
    )
    t3 = time.perf_counter()
    hull = np.isfinite(m_dl)

    def r(m, sel=slice(None)):
        return float(np.sqrt(np.mean((np.asarray(m)[sel] - tv[sel]) ** 2)))

    return {
        "case": f"peers n={n}, {n_query} cells",
        "n": n,
        "gp": _label("se", True),
        "gp_variants": {
            k: {"rmse_on_hull": r(m, hull), "over_delaunay": r(m, hull) / r(m_dl, hull), "s": t}
            for k, (m, t) in variants.items()
        },
        "rmse_gp": r(m_gp),
        "rmse_gp_on_hull": r(m_gp, hull),
        "rmse_delaunay_hull": r(m_dl, hull),
        "rmse_pykrige": r(m_ok),
        "gp_s": gp_s,
        "delaunay_s": t2 - t1,
        "pykrige_s": t3 - t2,
        "gp_over_delaunay_rmse": r(m_gp, hull) / r(m_dl, hull),
        "gp_over_pykrige_rmse": r(m_gp) / r(m_ok),
        "gp_over_pykrige_time": gp_s / (t3 - t2),
    }


CASES = {
    "fidelity": [
        (case_fidelity, (2000,)),
        (case_fidelity, (8000,)),
        (case_fidelity, (8000, "se+long")),
    ],
    "calibration": [
        (case_map, (50_000, kernel, amp)) for kernel in ("matern25", "se") for amp in (False, True)
    ]
    + [(case_map, (50_000, "se+long", True))],
    "large": [(case_map, (500_000, "se", amp, 1.0, "random1200")) for amp in (False, True)]
    + [(case_map, (500_000, "se+long", True, 1.0, "random1200"))],
    "calibration_gpdraw": [(case_gpdraw, (k, False)) for k in ("se", "se+long")]
    + [(case_gpdraw, ("se+long", True))],
    "calibration_far": [
        (case_gpdraw, (k, False, (3, 4, 5), "gpdraw1200", 2.0)) for k in ("se", "se+long")
    ],
    "dask": [(case_dask, ())],
    "peers": [(case_peers, ())],
}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/gp_scalable.json"))
    args = ap.parse_args(argv)
    results: dict[str, list[dict]] = {}
    for name in args.cases:
        results[name] = []
        for func, fargs in CASES[name]:
            row = in_subprocess(func, *fargs)
            results[name].append(row)
            print(
                f"[{name}] {row['case']}: {row['wall_s']:.1f} s, peak {row['peak_rss_mb']:.0f} MB",
                flush=True,
            )
    if "fidelity" in results:
        print(
            "\nFidelity: tiled vs exact GP, same hyperparameters (targets: RMSE within 2 %,"
            " median relative std difference <= 5 %)"
        )
        print(
            table(
                results["fidelity"],
                [
                    ("n", "n", "d"),
                    ("rmse_exact", "RMSE exact", ".4f"),
                    ("rmse_tiled", "RMSE tiled", ".4f"),
                    ("rmse_ratio", "ratio", ".4f"),
                    ("median_rel_std_diff", "med rel dstd", ".1e"),
                    ("exact_s", "exact s", ".1f"),
                    ("tiled_s", "tiled s", ".1f"),
                ],
            )
        )
    maps = sum(
        (
            results.get(k, [])
            for k in ("calibration", "calibration_gpdraw", "calibration_far", "large")
        ),
        [],
    )
    if maps:
        print(
            "\nMaps: calibration (targets 95 %: 93-97, 68 %: 64-72, z spread 0.9-1.1; also"
            " > 20 m from data), speed (50k <= 30 s, 2 GB; 500k <= 300 s, 4 GB)"
        )
        print(
            table(
                maps,
                [
                    ("case", "case", ""),
                    ("rmse", "RMSE", ".3f"),
                    ("coverage_95", "in 95%", ".3f"),
                    ("coverage_68", "in 68%", ".3f"),
                    ("z_std", "z spread", ".2f"),
                    ("far_coverage_95", "far 95%", ".3f"),
                    ("far_coverage_68", "far 68%", ".3f"),
                    ("fit_s", "fit s", ".1f"),
                    ("predict_s", "pred s", ".1f"),
                    ("wall_s", "wall s", ".1f"),
                    ("peak_rss_mb", "peak MB", ".0f"),
                    ("gp_over_delaunay_rmse", "GP/Delaunay", ".3f"),
                ],
            )
        )
        print(
            "\n95 % block-bootstrap intervals (50 m blocks) of the coverages; |z| tail ratio"
            " q95/q68 (Gaussian 1.96); Eq 9 on the fit subset (same subset for every kernel)"
        )
        for r in maps:
            if "per_truth" in r:  # pooled over truths: the range over them instead
                pt = r["per_truth"]
                print(
                    f"  {r['case']:<36} per truth: 95 % {min(pt['coverage_95']):.3f}-"
                    f"{max(pt['coverage_95']):.3f}, 68 % {min(pt['coverage_68']):.3f}-"
                    f"{max(pt['coverage_68']):.3f}, far 95 % {min(pt['far_coverage_95']):.3f}-"
                    f"{max(pt['far_coverage_95']):.3f}, far 68 % "
                    f"{min(pt['far_coverage_68']):.3f}-{max(pt['far_coverage_68']):.3f}"
                )
                continue
            ci, fci = r["coverage_ci"], r["far_coverage_ci"]
            print(
                f"  {r['case']:<36} 68 % [{ci[0]:.3f}, {ci[1]:.3f}]  95 % [{ci[2]:.3f},"
                f" {ci[3]:.3f}]  far 68 % [{fci[0]:.3f}, {fci[1]:.3f}]  far 95 % [{fci[2]:.3f},"
                f" {fci[3]:.3f}]  tail {r['z_q95_over_q68']:.2f} / far"
                f" {r['far_z_q95_over_q68']:.2f}  lml {r['lml']:.1f}"
            )
    if "dask" in results:
        print("\nDask: whole map computed block by block (only reductions kept)")
        print(
            table(
                results["dask"],
                [
                    ("case", "case", ""),
                    ("cells", "cells", ",d"),
                    ("n", "samples", ",d"),
                    ("wall_s", "wall s", ".1f"),
                    ("peak_rss_mb", "peak MB", ".0f"),
                ],
            )
        )
    if "peers" in results:
        print(
            "\nPeers on identical data and cells (targets: RMSE <= 0.6 x Delaunay on its hull;"
            " better RMSE and shorter time than PyKrige)"
        )
        print(
            table(
                results["peers"],
                [
                    ("gp", "GP", ""),
                    ("rmse_gp", "GP RMSE", ".3f"),
                    ("rmse_delaunay_hull", "Delaunay", ".3f"),
                    ("gp_over_delaunay_rmse", "GP/Del", ".2f"),
                    ("rmse_pykrige", "PyKrige", ".3f"),
                    ("gp_over_pykrige_rmse", "GP/PyK", ".2f"),
                    ("gp_s", "GP s", ".1f"),
                    ("pykrige_s", "PyKrige s", ".1f"),
                    ("gp_over_pykrige_time", "time ratio", ".3f"),
                ],
            )
        )
        for r in results["peers"]:
            for k, v in r.get("gp_variants", {}).items():
                print(
                    f"  {k:<22} RMSE on hull {v['rmse_on_hull']:.3f},"
                    f" GP/Del {v['over_delaunay']:.3f}"
                )
    if args.out.exists():  # a subset of cases updates the stored run, keeping the others
        import json

        stored = json.loads(args.out.read_text()).get("results", {})
        results = {**stored, **results}
    write_json(args.out, {"benchmark": "gp_scalable", "results": results})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
