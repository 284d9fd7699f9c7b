"""A GNSS profile survey over a noisy satellite DEM: does the prior help, and is its scale right?

    python benchmarks/profile_prior.py                    # the eleven real DEMs, table + JSON
    python benchmarks/profile_prior.py --sites olinda rm --dem-noise 0.5

Glaciologists map from kinematic GNSS lines (dense along each line, nothing between) with a
satellite DEM (SRTM / GLO-30 class: ~30 m cells, metres of noise) as the prior mean
``a + b * DEM`` (``RasterMean(offset="fit")``, what ``glacimap reconstruct --prior`` and
``run`` use). Each site is ``scripts/real_dems.glacier_site`` (600 m x 600 m at 2 m, 25 m of
real relief); the survey is ``--lines`` north-south lines, a fix every metre, ``--noise-sd``
m (RTK: 2 cm); the prior is the truth averaged into 30 m cells plus ``--dem-noise`` m of
white noise per cell, in the map's CRS. Every method maps the same cells:

``delaunay``      ``terrain.delaunay_linear``: the reference (RMSEs on its hull).
``constant``      ``TerrainGP(seed=0)``: no prior.
``dem_gls``       the prior with its scale by GLS always (``terrain.prior_scale``'s check off:
                  the behaviour before 0.42.0).
``dem``           the prior, the scale checked (the default since 0.42.0).
``dem_data``      the prior's cells as samples (``terrain.dem_as_data``; ``reconstruct
                  --prior-as data``), a constant mean.

Columns: RMSE / Delaunay's, the truth's coverage at 68 / 95 %, the fitted scale and the
check's Hausman z. Results: ``benchmarks/results/profile_prior.json``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent / "scripts"))
from _harness import table, write_json  # noqa: E402

SITES = ("olinda", "lux", "rm", "prism", "glacier", "bei", "gorillas", "clm", "volcano",
         "jacksboro", "topobathy")  # fmt: skip
METHODS = ("delaunay", "constant", "dem_gls", "dem", "dem_data")
DEM_CELL_M = 30.0


def survey(truth: Any, n_lines: int, noise_sd: float, seed: int):
    """Fixes every metre along ``n_lines`` north-south lines (+- 1 m of steering), noisy."""
    from terrain import ElevationSamples, Grid, sample_dem

    rng = np.random.default_rng(seed)
    g = Grid.from_dataarray(truth)
    w, s, e, n = g.bounds
    xs = w + (np.arange(n_lines) + 0.5) * (e - w) / n_lines
    y = np.arange(s + 2.0, n - 2.0, 1.0)
    xy = np.vstack([np.column_stack([np.full(y.size, x), y]) for x in xs])
    xy[:, 0] += rng.normal(0.0, 1.0, len(xy))
    z = sample_dem(truth, xy) + rng.normal(0.0, noise_sd, len(xy))
    return ElevationSamples(xy, z, noise_sd**2, crs=g.crs)


def satellite_dem(truth: Any, noise_sd: float, seed: int):
    """The truth averaged into 30 m cells plus white noise per cell (m), a DataArray."""
    from terrain import Grid

    g = Grid.from_dataarray(truth)
    k = int(round(DEM_CELL_M / g.resolution[0]))
    ny, nx = (g.ny // k) * k, (g.nx // k) * k
    blocks = np.asarray(truth.values)[:ny, :nx].reshape(ny // k, k, nx // k, k).mean(axis=(1, 3))
    blocks = blocks + np.random.default_rng(seed + 1).normal(0.0, noise_sd, blocks.shape)
    coarse = Grid(g.west, g.north, (k * g.resolution[0],) * 2, blocks.shape, g.crs)
    return coarse.data_array(blocks, "elevation")


def case(name: str, args: argparse.Namespace) -> list[dict[str, Any]]:
    import real_dems

    import terrain.prior_scale as prior_scale
    from terrain import Grid, RasterMean, TerrainGP, delaunay_linear
    from terrain.dem_as_data import dem_as_data

    truth = real_dems.glacier_site(name)
    grid = Grid.from_dataarray(truth)
    samples = survey(truth, args.lines, args.noise_sd, args.seed)
    dem = satellite_dem(truth, args.dem_noise, args.seed)
    t = np.asarray(truth.values)
    ref = delaunay_linear(samples, grid).elevation.values
    hull = np.isfinite(ref)
    rd = float(np.sqrt(np.mean((ref - t)[hull] ** 2)))
    rows = [{"site": name, "method": "delaunay", "rmse_m": rd, "ratio": 1.0}]
    threshold = prior_scale.HAUSMAN_Z
    for method in METHODS[1:]:
        prior_scale.HAUSMAN_Z = np.inf if method == "dem_gls" else threshold
        try:
            data = samples
            mean = "constant" if method in ("constant", "dem_data") else RasterMean(dem)
            if method == "dem_data":
                data = dem_as_data(dem, samples, grid.bounds)[0]
            gp = TerrainGP(mean=mean, seed=0).fit(data)
            ds = gp.predict_grid(grid)
        finally:
            prior_scale.HAUSMAN_Z = threshold
        e, s = (ds.elevation.values - t)[hull], ds.elevation_std.values[hull]
        check = getattr(gp.mean_, "scale_check_", None) or {}
        coef = getattr(gp.mean_, "coef_", None)
        rmse = float(np.sqrt(np.mean(e**2)))
        rows.append(
            {
                "site": name,
                "method": method,
                "rmse_m": rmse,
                "ratio": rmse / rd,
                "cov68": float(100 * np.mean(np.abs(e) <= s)),
                "cov95": float(100 * np.mean(np.abs(e) <= 1.96 * s)),
                "scale": None if coef is None or len(coef) < 2 else float(coef[1]),
                "hausman_z": check.get("z"),
                "scale_used": check.get("used"),
                "kernel": repr(gp.kernel_),
            }
        )
        print(f"{name} {method}: {rmse / rd:.3f} x Delaunay", flush=True)
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sites", nargs="+", default=list(SITES))
    p.add_argument("--lines", type=int, default=5, help="north-south lines over 600 m")
    p.add_argument("--noise-sd", type=float, default=0.02, help="the fixes' 1-sigma, m")
    p.add_argument("--dem-noise", type=float, default=1.0, help="the DEM's per-cell noise, m")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, default=HERE / "results" / "profile_prior.json")
    args = p.parse_args(argv)
    rows = [r for name in args.sites for r in case(name, args)]
    cols = [
        ("site", "site", ""),
        ("method", "method", ""),
        ("rmse_m", "RMSE m", ".3f"),
        ("ratio", "x Delaunay", ".3f"),
        ("cov68", "in 68 %", ".1f"),
        ("cov95", "in 95 %", ".1f"),
        ("scale", "scale b", ".3f"),
        ("hausman_z", "Hausman z", ".1f"),
        ("scale_used", "b by", ""),
    ]
    print(table(rows, cols))
    settings = {k: v for k, v in vars(args).items() if k != "out"}
    write_json(args.out, {"benchmark": "profile_prior", "settings": settings, "results": rows})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
