"""Survey planners: lawnmower on a region with holes, piecewise continuous on a 1000 x 1000 prior.

Times ``survey.lawnmower.lawnmower`` for N in (1, 10, 100) swaths over a 600 m x 600 m site
with two holes, and ``survey.piecewise.piecewise_continuous`` over the same region with a
1000 x 1000-cell prior (0.6 m cells); each case is the median of ``--repeats`` runs after one
warm-up. Prints a table with the targets (<= 25 ms, <= 2 s) and writes JSON atomically.

    python benchmarks/planners.py --out benchmarks/results/planners.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

LAWNMOWER_TARGET_S = 0.025
PIECEWISE_TARGET_S = 2.0
HOLES = [[(100, 100), (200, 100), (200, 200), (100, 200)], [(300, 300), (400, 320), (350, 450)]]


def _median_time(fn, repeats: int) -> tuple[float, object]:
    out = fn()  # warm-up (imports, caches)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/planners.json"))
    args = ap.parse_args(argv)

    from shapely.geometry import Polygon

    from survey.lawnmower import lawnmower
    from survey.piecewise import piecewise_continuous
    from terrain import Grid, random_terrain

    region = Polygon([(0, 0), (600, 0), (600, 600), (0, 600)], HOLES)
    prior = random_terrain(Grid.from_bounds((0, 0, 600, 600), 0.6), 25.0, seed=args.seed)
    assert prior.shape == (1000, 1000)

    rows = []
    print(f"{'planner':>22} {'N':>4} {'median ms':>10} {'target ms':>10} {'ok':>3} "
          f"{'waypoints':>9} {'samples':>8} {'path m':>9}")  # fmt: skip
    cases = [("lawnmower", n, LAWNMOWER_TARGET_S) for n in (1, 10, 100)]
    cases += [("piecewise_continuous", n, PIECEWISE_TARGET_S) for n in (2, 10, 100)]
    for name, n, target in cases:
        if name == "lawnmower":

            def fn(n=n):
                return lawnmower(region, n, heading=30.0)
        else:

            def fn(n=n):
                return piecewise_continuous(region, n, prior, seed=args.seed)

        t, plan = _median_time(fn, args.repeats)
        row = {
            "planner": name,
            "n_swaths": n,
            "median_s": t,
            "target_s": target,
            "meets_target": bool(t <= target),
            "waypoints": int(plan.waypoints.shape[0]),
            "samples": int(plan.samples.shape[0]),
            "path_length_m": plan.path_length,
        }
        rows.append(row)
        print(
            f"{name:>22} {n:>4} {1e3 * t:>10.2f} {1e3 * target:>10.0f} "
            f"{'yes' if row['meets_target'] else 'NO':>3} {row['waypoints']:>9} "
            f"{row['samples']:>8} {row['path_length_m']:>9.0f}",
            flush=True,
        )
    result = {
        "benchmark": "planners",
        "region": "600 m x 600 m square with a 100 m square hole and a triangular hole",
        "prior_shape": list(prior.shape),
        "repeats": args.repeats,
        "seed": args.seed,
        "python": sys.version.split()[0],
        "numpy": np.__version__,
        "machine": platform.machine(),
        "cpu_count": os.cpu_count(),
        "rows": rows,
        "notes": "median wall time of repeats after one warm-up; piecewise time includes the "
        "prior gradient (np.gradient on the 1000 x 1000 grid), computed once per call.",
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.out.with_suffix(args.out.suffix + ".tmp")
    tmp.write_text(json.dumps(result, indent=2))
    tmp.replace(args.out)  # atomic on POSIX: readers never see a half-written file
    print(f"wrote {args.out}")
    return 0 if all(r["meets_target"] for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
