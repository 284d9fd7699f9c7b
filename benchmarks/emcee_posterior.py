"""Bayesian GP hyperparameters (emcee) vs the plug-in ML estimate on the default site.

5,000 landmarks beside the demo's 2-swath rover path, the 64-value coarse DEM as prior mean,
one Matern(nu=2.5) kernel. The posterior over (variance, length scale, nugget, offset a,
scale b) of ``mean = a + b DEM`` is sampled with :func:`terrain.posterior.sample_hyperparameters`
(time, autocorrelation, effective samples); then the interval coverage of the truth by the
plug-in GP (``TerrainGP(optimize=True)``, mean = DEM) and by the posterior-averaged GP is
scored overall and on cells more than 20 m from any sample. Prints a table, writes JSON.

    python benchmarks/emcee_posterior.py --out benchmarks/results/emcee_posterior.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

FAR_M = 20.0  # "far from data": cell centre more than this from every sample, m


def _coverage(mean, std, truth, mask) -> dict[str, float]:
    err = np.abs(mean - truth)[mask]
    s = std[mask]
    return {
        "n_cells": int(mask.sum()),
        "coverage_68": float(np.mean(err <= s)),
        "coverage_95": float(np.mean(err <= 1.96 * s)),
        "rmse_m": float(np.sqrt(np.mean(err**2))),
        "mean_std_m": float(np.mean(s)),
    }


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/emcee_posterior.json"))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--walkers", type=int, default=32)
    ap.add_argument("--steps", type=int, default=1200)
    ap.add_argument("--burn", type=int, default=200)
    ap.add_argument("--max-samples", type=int, default=500)
    ap.add_argument("--draws", type=int, default=16)
    ap.add_argument("--pred-resolution", type=float, default=8.0)
    args = ap.parse_args(argv)

    from scipy.spatial import cKDTree

    from terrain import Grid, Matern, TerrainGP, coarse_dem, default_site, sample_along_path
    from terrain.atomic import atomic_path
    from terrain.posterior import sample_hyperparameters
    from terrain.prior import TriangulatedMean
    from terrain.synthetic import DEFAULT_SITE_BOUNDS, default_site_function
    from toolkit.demo import demo_path

    truth = default_site(resolution=4.0)
    grid = Grid.from_dataarray(truth)
    samples, _ = sample_along_path(
        truth, demo_path(grid, 2), 5000, seed=np.random.default_rng(args.seed)
    )
    coarse = coarse_dem(truth, cells=(8, 8))
    kernel = Matern(10.0, 50.0, nu=2.5)

    post = sample_hyperparameters(
        samples,
        kernel,
        coarse,
        n_walkers=args.walkers,
        n_steps=args.steps,
        burn=args.burn,
        max_samples=args.max_samples,
        seed=args.seed,
    )
    summary = post.summary()

    # Coverage on a coarser grid, truth = the same continuous surface as the 4 m site.
    pgrid = Grid.from_bounds(DEFAULT_SITE_BOUNDS, args.pred_resolution, grid.crs)
    ptruth = default_site_function(4.0)(pgrid.xy()).reshape(pgrid.shape)
    dist, _ = cKDTree(samples.xy).query(pgrid.xy())
    far = (dist > FAR_M).reshape(pgrid.shape)
    everywhere = np.ones(pgrid.shape, dtype=bool)

    t = time.perf_counter()
    plug = TerrainGP(
        kernel,
        mean=TriangulatedMean(coarse),
        optimize=True,
        max_fit_samples=1000,
        n_restarts=1,
        method="exact",
        seed=args.seed,
    ).fit(samples)
    plug_ds = plug.predict_grid(pgrid)
    plug_s = time.perf_counter() - t
    t = time.perf_counter()
    avg_ds = post.predict_grid(samples, pgrid, n_draws=args.draws, method="exact")
    avg_s = time.perf_counter() - t

    # Isolates hyperparameter averaging from the a + b DEM mean: one GP at the posterior median.
    median_theta = np.median(post.chain.reshape(-1, post.chain.shape[-1]), axis=0)
    med_ds = post.gp(median_theta, samples, method="exact").predict_grid(pgrid)

    rows = []
    maps = (
        ("plug-in (ML-II)", plug_ds),
        ("posterior median", med_ds),
        ("posterior-averaged", avg_ds),
    )
    for name, ds in maps:
        mean, std = ds["elevation"].values, ds["elevation_std"].values
        for region, mask in (("all cells", everywhere), (f"> {FAR_M:g} m from data", far)):
            rows.append({"map": name, "region": region, **_coverage(mean, std, ptruth, mask)})

    result = {
        "benchmark": "emcee_posterior",
        "site": "terrain.default_site(resolution=4.0), 5000 landmarks, 2 swaths, 8x8 DEM prior",
        "kernel": "Matern(nu=2.5), one isotropic length scale",
        "parameters": post.param_names,
        "sampler": {
            "n_walkers": args.walkers,
            "n_steps": args.steps,
            "burn": args.burn,
            "max_samples": args.max_samples,
            "moves": "DEMove 0.8 + DESnookerMove 0.2",
            "seconds": post.seconds,
            "tau": summary["tau"],
            "ess": post.ess,
            "acceptance_fraction": summary["acceptance_fraction"],
            "ess_at_least_1000": bool(post.ess >= 1000),
            "within_10_min": bool(post.seconds <= 600),
        },
        "posterior": summary["parameters"],
        "priors": {k: list(v) for k, v in post.priors.items()},
        "plug_in_hyperparameters": json.loads(plug.provenance()["hyperparameters"]),
        "prediction": {
            "grid_resolution_m": args.pred_resolution,
            "grid_shape": list(pgrid.shape),
            "note": "prediction grid coarser than the 4 m truth to keep the run short; truth "
            "at its cell centres from the same continuous surface",
            "n_draws": args.draws,
            "plug_in_seconds": plug_s,
            "posterior_averaged_seconds": avg_s,
            "far_threshold_m": FAR_M,
        },
        "coverage": rows,
        "machine": {
            "cpus": os.cpu_count(),
            "load_average_at_end": list(os.getloadavg()),
            "python": sys.version.split()[0],
            "platform": platform.platform(),
        },
    }

    s = result["sampler"]
    print(f"emcee: {len(post.param_names)} parameters, {args.walkers} walkers x {args.steps} steps")
    print(
        f"  {s['seconds']:.0f} s, ESS {s['ess']:.0f}, acceptance {s['acceptance_fraction']:.2f},"
        " tau " + ", ".join(f"{k} {v:.1f}" for k, v in s["tau"].items())
    )
    for k, v in summary["parameters"].items():
        print(f"  {k:12s} {v['median']:10.4g}  [{v['p16']:.4g}, {v['p84']:.4g}]")
    print(
        f"prediction on a {args.pred_resolution:g} m grid {pgrid.shape} (coarser than the 4 m"
        f" truth, to keep the run short), {args.draws} draws; load {os.getloadavg()[0]:.1f}"
    )
    print(f"{'map':20s} {'region':18s} {'cells':>6s} {'cov68':>6s} {'cov95':>6s} {'std':>6s} rmse")
    for r in rows:
        print(
            f"{r['map']:20s} {r['region']:18s} {r['n_cells']:6d} {r['coverage_68']:6.3f} "
            f"{r['coverage_95']:6.3f} {r['mean_std_m']:6.3f} {r['rmse_m']:.3f}"
        )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(args.out) as tmp:
        tmp.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.out}")
    return result


if __name__ == "__main__":
    main()
