"""Where the held-out check and the truth part: coverage by distance to the nearest sample.

    python benchmarks/heldout_by_distance.py glacier 3000            # constant mean
    python benchmarks/heldout_by_distance.py glacier 3000 --dem      # 8 x 8 prior

Fits the default ``TerrainGP`` on a real-DEM site (``benchmarks/real_terrain.py``'s data),
runs ``terrain.cross_validate`` (5 folds, seed 0, blocks matched to the grid), and prints the
68 % coverage of the *true* errors (the samples' ``true_z``) at the held-out samples and over
the grid, by distance band (docs/terrain.md, "A wrong gradient for single kernels").
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))

BANDS = ((0, 2), (2, 5), (5, 10), (10, 20), (20, np.inf))  # m


def main() -> None:
    import real_terrain as bench

    from terrain import TerrainGP, coarse_dem, cross_validate
    from terrain.heldout_design import heldout_distances

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("site")
    ap.add_argument("n", type=int)
    ap.add_argument("--dem", action="store_true", help="the 8 x 8 block-average prior mean")
    a = ap.parse_args()
    warnings.simplefilter("ignore")
    truth, grid, s = bench._data(bench.parse_site(a.site), a.n)
    gp = TerrainGP(seed=0, **({"mean": coarse_dem(truth)} if a.dem else {})).fit(s)
    cv = cross_validate(gp, s, n_folds=5, seed=0, targets=grid)
    lat = np.maximum(cv.predictive_sd**2 - (gp.nugget_ + s.z_var), 1e-12)
    z_held = (s.extra["true_z"] - cv.prediction) / np.sqrt(lat)
    ds = gp.predict_grid(grid)
    z_grid = ((ds.elevation.values - truth.values) / ds.elevation_std.values).ravel()
    d_grid = cKDTree(s.xy).query(grid.xy())[0]
    d_held = heldout_distances(s.xy, cv.fold)
    p = cv.pooled
    print(f"{a.site} {a.n} {'8x8 prior' if a.dem else 'constant'}: {gp.kernel_}")
    held, grid68 = 100 * np.mean(np.abs(z_held) < 1), 100 * np.mean(np.abs(z_grid) < 1)
    print(
        f"68 %: held-out check {100 * p['map_coverage_68']:.1f}, true errors at the held-out"
        f" samples {held:.1f}, grid {grid68:.1f}"
    )
    print(f"{'band m':>10} {'grid %':>7} {'grid 68':>8} {'held %':>7} {'held 68':>8}")
    for lo, hi in BANDS:
        g, h = (d_grid >= lo) & (d_grid < hi), (d_held >= lo) & (d_held < hi)
        gc = 100 * np.mean(np.abs(z_grid[g]) < 1) if g.any() else np.nan
        hc = 100 * np.mean(np.abs(z_held[h]) < 1) if h.any() else np.nan
        print(f"{lo:>4}-{hi:<5} {100 * g.mean():7.1f} {gc:8.1f} {100 * h.mean():7.1f} {hc:8.1f}")


if __name__ == "__main__":
    main()
