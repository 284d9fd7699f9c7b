"""A DSM with voids over real ground, mapped with ``glacimap reconstruct DSM.tif``.

    python benchmarks/dsm_voids.py            # table + benchmarks/results/dsm_voids.json
    python benchmarks/dsm_voids.py --seeds 0 1 2 3 --out dsm_seeds.json   # the run's seeds

Session 45 (docs/field-format.md "A DSM with voids as the samples"): a real DEM's 80-node
site at 2 m (``scripts/real_dems.py``) with 0.05 m of noise and three voids (radius 40, 25,
15 m), written as a GeoTIFF with nodata; every valid cell is a sample (no noise stated: the
fitted nugget carries it). Rows: RMSE against the truth and the truth inside the 68 / 95 %
intervals in the voids and on the cells, beside the TIN of the valid cells across the voids
(scipy, same run), the map's nugget and, where no cell states its noise, what the
dense windows measured (session 46, terrain/unstated_noise.py). The noise is seeded (5);
``--seeds`` are the map's (``glacimap reconstruct --seed``: its fit subset and orders).
The real DEMs come from Debian's packages (skipped, with the
reason, when they cannot be fetched).
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

VOIDS = ((200.0, 200.0, 40.0), (420.0, 380.0, 25.0), (150.0, 480.0, 15.0))  # from the NW, m
NOISE_SD = 0.05


def case(site: str, seed: int = 0) -> dict[str, Any]:
    """One site's row (module docstring)."""
    import rasterio
    import real_dems
    import xarray as xr
    from rasterio.transform import from_origin
    from scipy.interpolate import griddata
    from typer.testing import CliRunner

    from toolkit.cli import app

    truth = real_dems.glacier_site(site, nodes=80, resolution=2.0)
    z = truth.values.astype(float)
    x0, y1 = float(truth.x.min()) - 1.0, float(truth.y.max()) + 1.0
    xx, yy = np.meshgrid(truth.x.values, truth.y.values)
    void = np.zeros(z.shape, bool)
    for dx, dy, r in VOIDS:
        void |= np.hypot(xx - x0 - dx, yy - y1 + dy) < r
    noisy = z + np.random.default_rng(5).normal(0, NOISE_SD, z.shape)
    band = np.where(void, -9999.0, noisy).astype("float32")
    with tempfile.TemporaryDirectory() as tmp:
        dsm = Path(tmp) / "dsm.tif"
        profile = dict(driver="GTiff", width=z.shape[1], height=z.shape[0], count=1,
                       dtype="float32", crs="EPSG:32608", nodata=-9999.0,
                       transform=from_origin(x0, y1, 2.0, 2.0))  # fmt: skip
        with rasterio.open(dsm, "w", **profile) as ds:
            ds.write(band, 1)
        t0 = time.perf_counter()
        res = CliRunner().invoke(app, ["reconstruct", str(dsm), "--resolution", "2", "--out",
                                       str(Path(tmp) / "map"), "--seed", str(seed)])  # fmt: skip
        seconds = time.perf_counter() - t0
        if res.exit_code != 0:
            raise SystemExit(f"{site}: exit {res.exit_code}\n{res.output}\n{res.exception}")
        ds = xr.open_dataset(Path(tmp) / "map" / "product.nc").load()
    err, std = ds["elevation"].values - z, ds["elevation_std"].values
    cells = np.column_stack([xx[~void], yy[~void]])
    tin = griddata(cells, noisy[~void], (xx[void], yy[void]), method="linear")
    row: dict[str, Any] = {"site": site, "seed": seed, "void_cells": int(void.sum()),
                           "seconds": seconds}  # fmt: skip
    hyper = json.loads(ds.attrs["hyperparameters"])
    row["nugget_sd_m"] = float(np.sqrt(hyper["nugget"]))
    noise = json.loads(ds.attrs.get("noise_estimate") or "{}")
    row["subset_nugget_sd_m"] = float(np.sqrt(noise.get("subset_nugget", hyper["nugget"])))
    for part, mask in (("void", void), ("cells", ~void)):
        row[f"rmse_{part}"] = float(np.sqrt(np.mean(err[mask] ** 2)))
        row[f"cov68_{part}"] = 100 * float(np.mean(np.abs(err[mask]) <= std[mask]))
        row[f"cov95_{part}"] = 100 * float(np.mean(np.abs(err[mask]) <= 1.96 * std[mask]))
    row["tin_void"] = float(np.sqrt(np.nanmean((tin - z[void]) ** 2)))
    return row


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sites", nargs="+", default=["olinda", "rm", "bei", "gorillas"])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0], help="the map's seeds")
    ap.add_argument("--out", type=Path, default=HERE / "results" / "dsm_voids.json")
    args = ap.parse_args(argv)

    if not real_dems_or_skip(args.out, "dsm_voids"):
        return 0
    rows = [case(site, seed) for site in args.sites for seed in args.seeds]
    print(
        table(
            rows,
            [
                ("site", "site", "s"),
                ("seed", "seed", "d"),
                ("rmse_void", "voids m", ".3f"),
                ("tin_void", "TIN m", ".3f"),
                ("cov68_void", "68 % voids", ".1f"),
                ("cov95_void", "95 % voids", ".1f"),
                ("rmse_cells", "cells m", ".3f"),
                ("cov68_cells", "68 % cells", ".1f"),
                ("cov95_cells", "95 % cells", ".1f"),
                ("nugget_sd_m", "noise m", ".4f"),
                ("subset_nugget_sd_m", "subset's m", ".4f"),
                ("seconds", "s", ".1f"),
            ],
        )
    )
    write_json(args.out, {"benchmark": "dsm_voids", "noise_sd": NOISE_SD, "rows": rows})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
