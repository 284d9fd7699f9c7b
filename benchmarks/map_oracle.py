"""What the map could reach with perfect landmarks: an oracle bound for a survey plan.

    python benchmarks/map_oracle.py --cases rtk rtk_prior0 --out benchmarks/results/map_oracle.json

For each case of ``benchmarks/ground_control.py`` (``--route process``: ``glacimap run``,
field files, ``process``), the run's selected landmark positions are given the truth's exact
elevation and mapped again by the same reconstruct stage (kernel by evidence, the same
satellite DEM file as the prior mean), twice: with a 1 cm sigma and with the samples' own
sigma. The map RMSE against the truth then measures what the *plan* and the *prior* allow,
whatever the GPS and the localizer: if it misses a target, no sensor meets it on that plan
(docs/ground-control.md, "What any localizer could reach on this plan").
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _harness import table, write_json  # noqa: E402
from ground_control import process_overrides  # noqa: E402


def _score(product: Any, truth: Any) -> tuple[float, float]:
    """Map RMSE against the truth (m) and the share of cells inside +-1.96 sigma."""
    err = product["elevation"].values - truth.interp(x=product.x, y=product.y).values
    sd = product["elevation_std"].values
    return float(np.sqrt(np.nanmean(err**2))), float(np.nanmean(np.abs(err) < 1.96 * sd))


def run_case(case: str, seed: int) -> dict[str, Any]:
    import xarray as xr

    from terrain import ElevationSamples, Grid
    from toolkit.config import DEFAULT_SCENARIO
    from toolkit.pipeline import run_scenario
    from toolkit.stages import reconstruct_stage

    with tempfile.TemporaryDirectory(prefix="map_oracle_") as tmp:
        res = run_scenario(None, out=tmp, overrides=process_overrides(case, seed))
    rec, truth = res.objects["reconstruction"], res.objects["truth"]
    s = rec.samples
    z_true = truth.interp(x=xr.DataArray(s.xy[:, 0]), y=xr.DataArray(s.xy[:, 1])).values
    inside = np.isfinite(z_true)  # samples beyond the truth DEM's last cell centres: counted
    s = ElevationSamples(s.xy[inside], s.z[inside], s.z_var[inside], crs=s.crs)
    z_true = z_true[inside]
    grid = Grid.from_dataarray(rec.product["elevation"])
    settings = {"reconstruct": DEFAULT_SCENARIO["reconstruct"]}
    row: dict[str, Any] = {
        "case": case,
        "seed": seed,
        "samples": int(s.n),
        "samples_outside_truth": int((~inside).sum()),
        "sample_z_rmse_m": float(np.sqrt(np.mean((s.z - z_true) ** 2))),
    }
    row["map_rmse_m"], row["map_cov95"] = _score(rec.product, truth)
    for name, z_var in (("exact_1cm", np.full(s.n, 1e-4)), ("exact_own_sigma", s.z_var)):
        oracle = ElevationSamples(s.xy, z_true, z_var, crs=s.crs)
        r = reconstruct_stage(oracle, grid, rec.gp.mean, settings, seed, heldout_folds=0)
        row[f"{name}_rmse_m"], row[f"{name}_cov95"] = _score(r.product, truth)
        row[f"{name}_kernel"] = str(r.gp.kernel_)
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", nargs="+", default=["rtk", "rtk_prior0"])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/map_oracle.json"))
    args = ap.parse_args()
    cols = [
        ("case", "case", ""),
        ("samples", "samples", "d"),
        ("sample_z_rmse_m", "sample z RMSE", ".3f"),
        ("map_rmse_m", "map RMSE", ".3f"),
        ("exact_1cm_rmse_m", "exact z, 1 cm", ".3f"),
        ("exact_own_sigma_rmse_m", "exact z, own sigma", ".3f"),
    ]
    rows = []
    for case in args.cases:
        rows.append(run_case(case, args.seed))
        print(table(rows[-1:], cols), flush=True)
    print(table(rows, cols))
    write_json(args.out, {"command": " ".join(sys.argv), "rows": rows})


if __name__ == "__main__":
    main()
