"""Exact GP: glacimap's TerrainGP against scikit-learn's GaussianProcessRegressor.

Fit + predict (mean and std) for n = 1k, 2k, 5k noisy samples of a synthetic glacier onto a
300 x 300 grid, with identical data and fixed hyperparameters; each case runs in its own
process so its peak resident memory (ru_maxrss) is its own. Prints a table and writes JSON.

    python benchmarks/gp_exact.py --out benchmarks/results/gp_exact.json   (or: make bench)
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _harness import in_subprocess, write_json  # noqa: E402

VARIANCE, LENGTHSCALE, NOISE = 20.0, 25.0, 0.2**2  # m^2, m, m^2 (fixed, shared by both)


def _data(n: int, seed: int):
    from terrain import Grid
    from terrain.sampling import sample_dem
    from terrain.synthetic import random_terrain

    grid = Grid.from_bounds((0, 0, 600, 600), 2.0)  # 300 x 300 cells
    truth = random_terrain(grid, relief=25.0, seed=seed, features=True)
    rng = np.random.default_rng(seed)
    xy = rng.uniform(2.0, 598.0, (n, 2))
    z = sample_dem(truth, xy) + rng.normal(0.0, np.sqrt(NOISE), n)
    return grid, xy, z - z.mean()


def _case(impl: str, n: int, seed: int) -> dict:
    grid, xy, z = _data(n, seed)
    q = grid.xy()
    t0 = time.perf_counter()
    if impl == "glacimap":
        from terrain import ElevationSamples
        from terrain.gp import TerrainGP
        from terrain.kernels import SquaredExponential

        gp = TerrainGP(
            SquaredExponential(VARIANCE, LENGTHSCALE),
            mean=0.0,
            nugget=NOISE,
            nugget_bounds="fixed",
            optimize=False,
            method="exact",
        ).fit(ElevationSamples(xy, z))
    else:
        from sklearn.gaussian_process import GaussianProcessRegressor
        from sklearn.gaussian_process.kernels import RBF, ConstantKernel

        gp = GaussianProcessRegressor(
            ConstantKernel(VARIANCE) * RBF(LENGTHSCALE), alpha=NOISE, optimizer=None
        ).fit(xy, z)
    t1 = time.perf_counter()
    mean, std = gp.predict(q, return_std=True)
    t2 = time.perf_counter()
    return {
        "impl": impl,
        "n": n,
        "fit_s": t1 - t0,
        "predict_s": t2 - t1,
        "total_s": t2 - t0,
        "mean": mean,
        "std": std,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[1000, 2000, 5000])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/gp_exact.json"))
    args = ap.parse_args(argv)
    rows = []
    head = (
        f"{'n':>6} {'impl':>9} {'fit s':>7} {'pred s':>8} {'total s':>8} {'peak MB':>8} "
        f"{'time ratio':>10} {'mem ratio':>9} {'max|dmean|':>10} {'max|dstd|':>9}"
    )
    print("Exact GP onto a 300 x 300 grid (mean + std), fixed hyperparameters")
    print(head)
    for n in args.sizes:
        ours = in_subprocess(_case, "glacimap", n, args.seed)
        ref = in_subprocess(_case, "sklearn", n, args.seed)
        dmean = float(np.max(np.abs(ours.pop("mean") - ref.pop("mean"))))
        dstd = float(np.max(np.abs(ours.pop("std") - ref.pop("std"))))
        ratio_t = ours["total_s"] / ref["total_s"]
        ratio_m = ours["peak_rss_mb"] / ref["peak_rss_mb"]
        for r in (ours, ref):
            extra = (
                f"{ratio_t:>10.2f} {ratio_m:>9.2f} {dmean:>10.1e} {dstd:>9.1e}" if r is ours else ""
            )
            print(
                f"{n:>6} {r['impl']:>9} {r['fit_s']:>7.2f} {r['predict_s']:>8.2f} "
                f"{r['total_s']:>8.2f} {r['peak_rss_mb']:>8.0f} {extra}",
                flush=True,
            )
        rows.append(
            {
                "n": n,
                "glacimap": ours,
                "sklearn": ref,
                "time_ratio": ratio_t,
                "peak_memory_ratio": ratio_m,
                "max_abs_mean_diff_m": dmean,
                "max_abs_std_diff_m": dstd,
            }
        )
    write_json(
        args.out,
        {
            "benchmark": "gp_exact",
            "grid": [300, 300],
            "seed": args.seed,
            "hyperparameters": {"variance": VARIANCE, "lengthscale": LENGTHSCALE, "noise": NOISE},
            "rows": rows,
            "notes": "time ratio = glacimap / scikit-learn (< 1: glacimap faster); peak RSS per "
            "process includes the interpreter, libraries and the synthetic data.",
        },
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
