"""A lidar / drone cloud over real ground, through ``glacimap reconstruct CLOUD.laz``.

    python benchmarks/point_cloud.py               # table + benchmarks/results/point_cloud.json
    python benchmarks/point_cloud.py --density 2 --sites olinda:80 bei:80

Session 45's walk (docs/field-format.md "Survey points from GIS layers and point clouds"):
a real DEM's site (``scripts/real_dems.py``, 600 m at 1 m, the window's nodes carried by a
bicubic spline), a cloud of ``--density`` points per m² with 0.08 m of noise, 12 % of the
returns vegetation 0.3-4 m up (classes 3-5), 0.3 % low noise 2-20 m down (class 7), 0.1 %
withheld, and two holes of 40 m and 30 m radius without points (bright snow); a LAZ in
EPSG:32608. Each row: the cloud's read and reduction (``auto`` block samples), the map's
RMSE against the truth on the hull of the ground points, outside and inside the holes, the
truth inside the 68 / 95 % intervals there, the held-out check, wall seconds; beside it the
TIN of every ground point (scipy's ``LinearNDInterpolator``, the usual lidar DEM) in the same
run, and the map's RMSE over the TIN's. Seeded (7); the real DEMs come from Debian's
packages (skipped, with the reason, when they cannot be fetched).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent / "scripts"))
from _harness import real_dems_or_skip, table, write_json  # noqa: E402

HOLES = ((180.0, 400.0, 40.0), (430.0, 170.0, 30.0))  # (x, y from the site's corner, radius) m
NOISE_SD = 0.08


def make_cloud(site: str, density: float, path: Path, seed: int = 7):
    """The truth (a DataArray at 1 m) and a LAZ of the cloud over it at ``path``."""
    import laspy
    import real_dems
    from pyproj import CRS

    from terrain import sample_dem

    name, _, nodes = site.partition(":")
    truth = real_dems.glacier_site(name, nodes=int(nodes or 40), resolution=1.0)
    x0, y0 = float(truth.x.min()) - 0.5, float(truth.y.min()) - 0.5
    rng = np.random.default_rng(seed)
    xy = rng.uniform([x0 + 1, y0 + 1], [x0 + 599, y0 + 599], (int(density * 600 * 600), 2))
    for hx, hy, r in HOLES:
        xy = xy[np.hypot(xy[:, 0] - x0 - hx, xy[:, 1] - y0 - hy) > r]
    n = len(xy)
    z = sample_dem(truth, xy) + rng.normal(0, NOISE_SD, n)
    code = np.full(n, 2, np.uint8)
    veg = rng.random(n) < 0.12
    code[veg] = rng.choice([3, 4, 5], veg.sum())
    z[veg] += rng.uniform(0.3, 4, veg.sum())
    noise = rng.random(n) < 0.003
    code[noise] = 7
    z[noise] -= rng.uniform(2, 20, noise.sum())
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.offsets, header.scales = [x0, y0, 0.0], [0.001] * 3
    header.add_crs(CRS.from_user_input(truth.attrs.get("crs", "EPSG:32608")))
    las = laspy.LasData(header)
    las.x, las.y, las.z = xy[:, 0], xy[:, 1], z
    las.classification = code
    las.withheld = rng.random(n) < 0.001
    las.write(path)
    ground = (code == 2) & ~np.asarray(las.withheld, bool)
    return truth, (x0, y0), xy[ground], np.asarray(las.z)[ground]


def case(site: str, density: float) -> dict[str, Any]:
    """One site's row (module docstring)."""
    import xarray as xr
    from scipy.interpolate import LinearNDInterpolator, RectBivariateSpline
    from typer.testing import CliRunner

    from toolkit.cli import app

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        truth, (x0, y0), gxy, gz = make_cloud(site, density, folder / "cloud.laz")
        t0 = time.perf_counter()
        res = CliRunner().invoke(
            app, ["reconstruct", str(folder / "cloud.laz"), "--resolution", "2", "--out",
                  str(folder / "map")],
        )  # fmt: skip
        seconds = time.perf_counter() - t0
        if res.exit_code != 0:
            raise SystemExit(f"{site}: exit {res.exit_code}\n{res.output}\n{res.exception}")
        ds = xr.open_dataset(folder / "map" / "product.nc").load()
        cert = json.loads((folder / "map" / "certificate.json").read_text())
        n_samples = len((folder / "map" / "samples.csv").read_text().splitlines()) - 1
    spline = RectBivariateSpline(truth.x.values, truth.y.values[::-1], truth.values[::-1].T)
    xx, yy = np.meshgrid(ds["x"].values, ds["y"].values)
    t = spline.ev(xx, yy)
    mean, std = ds["elevation"].values, ds["elevation_std"].values
    hole = np.zeros(xx.shape, bool)
    for hx, hy, r in HOLES:
        hole |= np.hypot(xx - x0 - hx, yy - y0 - hy) <= r
    t1 = time.perf_counter()
    tin = LinearNDInterpolator(gxy, gz)(xx, yy)
    tin_s = time.perf_counter() - t1
    hull = np.isfinite(tin)
    row: dict[str, Any] = {"site": site, "density": density, "ground_points": int(gz.size)}
    row["samples"], row["seconds"], row["tin_seconds"] = n_samples, seconds, tin_s
    for part, mask in (("all", hull), ("out", hull & ~hole), ("hole", hull & hole)):
        err = mean[mask] - t[mask]
        row[f"rmse_{part}"] = float(np.sqrt(np.mean(err**2)))
        row[f"tin_{part}"] = float(np.sqrt(np.mean((tin[mask] - t[mask]) ** 2)))
        row[f"cov68_{part}"] = 100 * float(np.mean(np.abs(err) <= std[mask]))
        row[f"cov95_{part}"] = 100 * float(np.mean(np.abs(err) <= 1.96 * std[mask]))
    row["ratio_tin"] = row["rmse_all"] / row["tin_all"]
    held = cert.get("heldout_calibration", {})
    row["heldout68"] = 100 * float(held.get("map_coverage_68", np.nan))
    row["heldout95"] = 100 * float(held.get("map_coverage_95", np.nan))
    row["beyond_reach"] = 100 * float(held.get("map_beyond_reach", np.nan))
    return row


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sites", nargs="+", default=["olinda:80"])
    ap.add_argument("--density", type=float, default=4.0, help="points per m^2")
    ap.add_argument("--out", type=Path, default=HERE / "results" / "point_cloud.json")
    args = ap.parse_args(argv)

    if not real_dems_or_skip(args.out, "point_cloud"):
        return 0
    rows = [case(site, args.density) for site in args.sites]
    print(
        table(
            rows,
            [
                ("site", "site", "s"),
                ("ground_points", "ground pts", "d"),
                ("samples", "samples", "d"),
                ("rmse_all", "RMSE m", ".3f"),
                ("tin_all", "TIN m", ".3f"),
                ("ratio_tin", "x TIN", ".3f"),
                ("rmse_out", "out m", ".3f"),
                ("cov68_out", "68 % out", ".1f"),
                ("cov95_out", "95 % out", ".1f"),
                ("rmse_hole", "hole m", ".3f"),
                ("cov68_hole", "68 % hole", ".1f"),
                ("cov95_hole", "95 % hole", ".1f"),
                ("heldout68", "held-out 68", ".1f"),
                ("seconds", "s", ".1f"),
                ("tin_seconds", "TIN s", ".1f"),
            ],
        )
    )
    write_json(args.out, {"benchmark": "point_cloud", "density": args.density, "rows": rows})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
