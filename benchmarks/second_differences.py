"""How rough the fitted kernel says the ground is, against the truth, lag by lag.

For each real-DEM site (``real_terrain``'s data: same truth, samples and seed) this fits the
default ``TerrainGP`` and prints, at lags s = 2 ... 64 m, the variance of the second
difference ``f(x - s) - 2 f(x) + f(x + s)`` along x and y:

* of the truth grid (after the fitted prior mean), and
* as the fitted kernel states it, ``6 k(0) - 8 k(s) + 2 k(2 s)``.

A second difference does not see a plane, so it measures what an interpolator must guess
between samples. Where the kernel states more than the truth has at the lags between the
map's samples, its 1-sigma runs wide there (docs/terrain.md "Evidence of the samples the fit
subset left out"). It also prints every candidate's BIC, window likelihood and score.

    python benchmarks/second_differences.py --n 50000 --sites bei glacier rm olinda
    python benchmarks/second_differences.py --n 50000 --mean dem --out lags.json
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))

import real_terrain as rt  # noqa: E402

from terrain import TerrainGP, coarse_dem  # noqa: E402

LAGS_M = (2, 4, 8, 16, 32, 64)


def truth_second_differences(field: np.ndarray, res: float) -> list[float]:
    """Mean square second difference along x and y of a grid (ny, nx) at each lag, m^2."""
    out = []
    for s in LAGS_M:
        j = int(round(s / res))
        dx = field[:, 2 * j :] - 2 * field[:, j:-j] + field[:, : -2 * j]
        dy = field[2 * j :, :] - 2 * field[j:-j, :] + field[: -2 * j, :]
        out.append(0.5 * float(np.mean(dx**2) + np.mean(dy**2)))
    return out


def kernel_second_differences(kernel) -> list[float]:
    """``6 k(0) - 8 k(s) + 2 k(2 s)`` at each lag, m^2."""
    origin = np.zeros((1, 2))

    def k(r: float) -> float:
        return float(np.asarray(kernel(origin, np.array([[r, 0.0]]))).ravel()[0])

    return [6 * k(0.0) - 8 * k(s) + 2 * k(2.0 * s) for s in LAGS_M]


def row(spec: str, n: int, mean: str) -> dict:
    site = rt.parse_site(spec)
    truth, grid, samples = rt._data(site, n)
    kw = {} if mean == "constant" else {"mean": coarse_dem(truth)}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        gp = TerrainGP(seed=0, **kw).fit(samples)
    field = truth.values.astype(float)
    if mean != "constant":
        xx, yy = np.meshgrid(grid.x, grid.y)
        xy = np.column_stack([xx.ravel(), yy.ravel()])
        field = field - np.asarray(gp.mean_(xy), float).reshape(field.shape)
    res = abs(float(truth.x[1] - truth.x[0]))
    cands = [
        {k: r.get(k) for k in ("name", "bic", "window_lml", "score", "selected")}
        for r in gp.kernel_scores_
    ]
    return {
        "site": site["label"],
        "n": n,
        "mean": mean,
        "kernel": repr(gp.kernel_),
        "lags_m": list(LAGS_M),
        "truth_m2": truth_second_differences(field, res),
        "kernel_m2": kernel_second_differences(gp.kernel_),
        "candidates": cands,
        "windows": gp.provenance()["kernel_windows"],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=50_000, help="samples (real_terrain's draw 0)")
    ap.add_argument("--mean", choices=("constant", "dem"), default="constant")
    ap.add_argument("--sites", nargs="+", default=["bei", "glacier", "rm", "olinda"])
    ap.add_argument("--out", type=Path, help="JSON of every row")
    args = ap.parse_args()
    rows = []
    for spec in args.sites:
        r = row(spec, args.n, args.mean)
        rows.append(r)
        print(f"{r['site']} {r['mean']} n={r['n']}: {r['kernel']}")
        print("  lag, m          " + "".join(f"{s:9d}" for s in LAGS_M))
        print("  truth, m^2      " + "".join(f"{v:9.4f}" for v in r["truth_m2"]))
        print("  kernel, m^2     " + "".join(f"{v:9.4f}" for v in r["kernel_m2"]))
        pairs = zip(r["kernel_m2"], r["truth_m2"], strict=True)
        ratio = [a / b if b > 0 else float("nan") for a, b in pairs]
        print("  kernel / truth  " + "".join(f"{v:9.2f}" for v in ratio))
        top = min(c["score"] for c in r["candidates"] if c["score"] is not None)
        low = min(c["bic"] for c in r["candidates"] if c["bic"] is not None)
        for c in r["candidates"]:
            if c["bic"] is None:
                continue
            w = "" if c["window_lml"] is None else f"{c['window_lml']:10.1f}"
            print(
                f"    {c['name']:18s} dBIC {c['bic'] - low:7.1f}  window lml {w:>10s}"
                f"  d score {c['score'] - top:8.1f}{'  <- kept' if c['selected'] else ''}"
            )
        sys.stdout.flush()
    if args.out:
        tmp = args.out.with_suffix(args.out.suffix + ".tmp")
        tmp.write_text(json.dumps(rows, indent=1))
        tmp.replace(args.out)
        print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
