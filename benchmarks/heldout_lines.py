"""The held-out check on line surveys of a real DEM: where it reads the map's coverage, and
where its held-out samples sit in gaps no map cell has.

    python benchmarks/heldout_lines.py [--out benchmarks/results/heldout_lines.json]

The Olinda DEM (Debian's r-cran-stars, UTM 25S, 90 m cells; ``scripts/real_dems.py``) as a
bicubic surface over 3 km x 3 km, surveyed along 10 lines 300 m apart (a sample every 1 m),
with and without 2,000 scattered samples, 0.3 m of noise the CSV does not state (left to the
fitted nugget, as ``glacimap reconstruct`` does with an x, y, z file). Each survey is mapped
at 5 m by ``toolkit.stages.reconstruct_stage`` (the model of ``glacimap reconstruct`` /
``process``: kernel by evidence, spatial-block held-out check) with a constant mean and
with the DEM itself, reprojected to EPSG:4326, as the prior (``RasterMean``). Reported per
case: the map's truth coverage over its grid, the held-out check's map coverage and
verdict, and the *true* errors at the held-out samples, on the lines and on the scattered
samples apart (docs/terrain.md "Held-out samples in gaps along dense lines").
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))

SIDE_M, LINES, LINE_GAP_M, SCATTERED, NOISE_M, RES_M = 3000.0, 10, 300.0, 2000, 0.3, 5.0
CASES = (("lines+scattered", "prior"), ("lines+scattered", "constant"), ("lines", "prior"))


def _surface():
    """The Olinda DEM as a bicubic spline, its CRS and the 3 km window's south-west corner."""
    import real_dems
    from scipy.interpolate import RectBivariateSpline

    dem = real_dems.load("olinda")
    x, y, z = dem.x.values, dem.y.values[::-1], dem.values[::-1]  # y ascending
    spline = RectBivariateSpline(y, x, z, kx=3, ky=3)
    return dem, spline, (float(x[40]), float(dem.y.values[70]))


def _survey(kind: str, corner, spline, rng):
    """Samples (n, 2), their true and observed z, and a mask of the scattered ones."""
    x0, y0 = corner
    t = np.arange(0.0, SIDE_M, 1.0)
    parts = [
        np.column_stack([x0 + 150 + LINE_GAP_M * i + 8 * np.sin(t / 120 + i), y0 + t])
        for i in range(LINES)
    ]
    if kind == "lines+scattered":
        parts.append(rng.uniform([x0, y0], [x0 + SIDE_M, y0 + SIDE_M], (SCATTERED, 2)))
    xy = np.vstack(parts)
    true_z = spline.ev(xy[:, 1], xy[:, 0])
    scattered = np.arange(len(xy)) >= LINES * t.size
    return xy, true_z, true_z + rng.normal(0.0, NOISE_M, len(xy)), scattered


def _prior_file(dem, folder: Path) -> Path:
    """The DEM reprojected to EPSG:4326 (bilinear) as a GeoTIFF: a user's satellite prior."""
    import rasterio
    from rasterio.transform import from_origin
    from rasterio.warp import Resampling, calculate_default_transform, reproject

    z = dem.values.astype("float32")
    dx = float(dem.x.values[1] - dem.x.values[0])
    src_t = from_origin(dem.x.values[0] - dx / 2, dem.y.values[0] + dx / 2, dx, dx)
    crs = dem.attrs["crs_wkt"]
    bounds = rasterio.transform.array_bounds(*z.shape, src_t)
    dst_t, w, h = calculate_default_transform(crs, "EPSG:4326", z.shape[1], z.shape[0], *bounds)
    out = np.full((h, w), -9999.0, dtype="float32")
    reproject(z, out, src_transform=src_t, src_crs=crs, dst_transform=dst_t,
              dst_crs="EPSG:4326", resampling=Resampling.bilinear, dst_nodata=-9999.0)  # fmt: skip
    path = folder / "olinda_4326.tif"
    with rasterio.open(path, "w", driver="GTiff", width=w, height=h, count=1, dtype="float32",
                       crs="EPSG:4326", transform=dst_t, nodata=-9999.0) as ds:  # fmt: skip
        ds.write(out, 1)
    return path


def _coverage(err: np.ndarray, sd: np.ndarray) -> tuple[float, float]:
    t = np.abs(err) / sd
    return 100.0 * float(np.mean(t <= 1.0)), 100.0 * float(np.mean(t <= 1.96))


def run_case(kind: str, mean_name: str, prior_path: Path | None) -> dict:
    from terrain import ElevationSamples, RasterMean
    from toolkit.config import load_scenario
    from toolkit.stages import map_grid, reconstruct_stage

    dem, spline, corner = _surface()
    xy, true_z, z, scattered = _survey(kind, corner, spline, np.random.default_rng(42))
    samples = ElevationSamples(xy, z, 0.0, crs=dem.attrs["crs_wkt"])
    grid = map_grid(None, RES_M, samples.crs, samples)
    mean = RasterMean(str(prior_path)) if mean_name == "prior" else "constant"
    settings = load_scenario(None, {"seed": 0})
    t0 = time.perf_counter()
    rec = reconstruct_stage(samples, grid, mean, settings, 0, heldout_folds=5)
    seconds = time.perf_counter() - t0
    gxy = grid.xy()
    ds = rec.gp.predict_grid(grid)  # the map's own 1-sigma (no survey-wide terms)
    err = ds.elevation.values.ravel() - spline.ev(gxy[:, 1], gxy[:, 0])
    truth68, truth95 = _coverage(err, ds.elevation_std.values.ravel())
    cv = rec.heldout
    p = cv.pooled
    # true errors at the held-out samples over the fold map's own sd (noise variance removed)
    noise_var = float(rec.gp.nugget_)
    sd_f = np.sqrt(np.maximum(cv.predictive_sd**2 - noise_var, 1e-12))
    true_err = cv.prediction - true_z
    lines68, lines95 = _coverage(true_err[~scattered], sd_f[~scattered])
    row = {
        "case": f"{kind}, {mean_name}",
        "n": int(samples.n),
        "kernel": rec.gp.kernel_name_,
        "truth68": truth68,
        "truth95": truth95,
        "heldout68": 100.0 * p["map_coverage_68"],
        "heldout95": 100.0 * p["map_coverage_95"],
        "heldout68_interval": [100.0 * v for v in p["map_coverage_68_interval"]],
        "matched_on": p.get("matched_on"),
        "difference_sd": p.get("neighbourhood_difference_sd"),
        "local_fit_used": p.get("local_fit_used"),
        "local_fit_q": p.get("local_fit_q"),
        "distance_matched68": 100.0 * p["distance_matched_coverage_68"],
        "distance_matched95": 100.0 * p["distance_matched_coverage_95"],
        "true_at_lines68": lines68,
        "true_at_lines95": lines95,
        "true_at_scattered68": None,
        "true_at_scattered95": None,
        "block_m": cv.block_size,
        "verdict": cv.verdict(),
        "seconds": seconds,
    }
    if scattered.any():
        row["true_at_scattered68"], row["true_at_scattered95"] = _coverage(
            true_err[scattered], sd_f[scattered]
        )
    return row


def main() -> None:
    from _harness import in_subprocess, table, write_json

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/heldout_lines.json"))
    a = ap.parse_args()
    warnings.simplefilter("ignore")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        prior = _prior_file(_surface()[0], Path(tmp))
        for kind, mean_name in CASES:
            rows.append(in_subprocess(run_case, kind, mean_name, prior))
            print(f"{rows[-1]['case']}: {rows[-1]['seconds']:.0f} s", flush=True)
    cols = [
        ("case", "case", ""),
        ("kernel", "kernel", ""),
        ("truth68", "truth 68", ".1f"),
        ("truth95", "truth 95", ".1f"),
        ("heldout68", "held-out 68", ".1f"),
        ("heldout95", "held-out 95", ".1f"),
        ("matched_on", "matched on", ""),
        ("distance_matched68", "dist-matched 68", ".1f"),
        ("distance_matched95", "dist-matched 95", ".1f"),
        ("difference_sd", "diff / sd", ".1f"),
        ("true_at_lines68", "true@lines 68", ".1f"),
        ("true_at_lines95", "true@lines 95", ".1f"),
        ("true_at_scattered68", "true@scat 68", ".1f"),
        ("true_at_scattered95", "true@scat 95", ".1f"),
    ]
    print(table(rows, cols))
    for r in rows:
        for sentence in r["verdict"]:
            print(f"{r['case']}: {sentence}")
    settings = {
        "side_m": SIDE_M,
        "lines": LINES,
        "line_gap_m": LINE_GAP_M,
        "scattered": SCATTERED,
        "noise_m": NOISE_M,
        "resolution_m": RES_M,
        "seed": 42,
    }
    write_json(a.out, {"benchmark": "heldout_lines", "settings": settings, "results": rows})


if __name__ == "__main__":
    main()
