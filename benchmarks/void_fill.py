"""Voids in a glacier's elevation change filled by elevation band or by the glacier's mean.

    python benchmarks/void_fill.py                # table + benchmarks/results/void_fill.json
    python benchmarks/void_fill.py --trials 10    # quicker

Each of the real DEMs (``scripts/real_dems.py``) shapes a valley-glacier-sized site (3 km,
600 m of relief, 20 m cells) with the default outline; the change is a thinning that
depends on elevation, 4 m at the lowest point to 0.5 m at the highest, plus a correlated
field (0.5 m, ~100 m: ``--field-scale-m``) and 0.2 m of white noise, all seeded. Each trial
cuts 1-4 circular voids (radius 100-300 m: ``--void-radius-m``) inside the outline, anywhere
or in its highest third (optical DEMs' saturated accumulation areas), and fills them:

* ``mean``: every void the mean dh of the glacier's valid cells, its 1-sigma the glacier's
  spread of dh times the void area (glacimap up to 0.46.0);
* ``band``: ``terrain.void_fill.hypsometric_fill`` (mean hypsometric, McNabb et al. 2019).

Rows per site and design: the volume error of the fill against the truth (mean and RMS over
the trials, % of the true volume change), and its error over its own 1-sigma (RMS, and the
share within 1 and 2). The real DEMs come from Debian's packages (skipped, with the reason,
when they cannot be fetched).
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
import real_dems  # noqa: E402
from _harness import real_dems_or_skip, table, write_json  # noqa: E402

SITES = real_dems.NAMES  # the eleven real DEMs
DESIGNS = ("anywhere", "high")


def _field(shape: tuple[int, int], scale_cells: float, rng: np.random.Generator) -> np.ndarray:
    """A unit-variance Gaussian field smoothed over ``scale_cells`` (FFT, seeded)."""
    white = rng.standard_normal(shape)
    ky = np.fft.fftfreq(shape[0])[:, None]
    kx = np.fft.fftfreq(shape[1])[None, :]
    f = np.real(np.fft.ifft2(np.fft.fft2(white) * np.exp(-2 * (np.pi * scale_cells) ** 2
                                                          * (kx**2 + ky**2))))  # fmt: skip
    return f / f.std()


def site_case(
    name: str, trials: int, seed: int, scale_m: float = 100.0, radius_m=(100.0, 300.0)
) -> list[dict[str, Any]]:
    from terrain import Grid, default_outline
    from terrain.void_fill import hypsometric_fill
    from terrain.volume import outline_weights

    truth = real_dems.glacier_site(name, size_m=3000.0, relief_m=600.0, resolution=20.0)
    g = Grid.from_dataarray(truth)
    z = np.asarray(truth.values, float)
    outline = default_outline(g.bounds)
    W = outline_weights(g, outline)
    inside = W > 0
    rng = np.random.default_rng(seed)
    lo, hi = float(z[inside].min()), float(z[inside].max())
    dh_true = -4.0 + 3.5 * (z - lo) / (hi - lo)
    dh_true = dh_true + 0.5 * _field(z.shape, scale_m / 20.0, rng) + rng.normal(0.0, 0.2, z.shape)
    true_v = float(np.sum(W * dh_true))
    xy = g.xy().reshape(*g.shape, 2)
    rows = []
    for design in DESIGNS:
        allowed = inside & (z >= lo + 2 * (hi - lo) / 3 if design == "high" else inside)
        cand = np.argwhere(allowed)
        errs: dict[str, list[float]] = {"mean": [], "band": []}
        zs: dict[str, list[float]] = {"mean": [], "band": []}
        shares = []
        for _ in range(trials):
            dh = dh_true.copy()
            for _k in range(int(rng.integers(1, 5))):
                i, j = cand[rng.integers(len(cand))]
                r = rng.uniform(*radius_m)
                dh[np.hypot(*(xy - xy[i, j]).transpose(2, 0, 1)) <= r] = np.nan
            valid = inside & np.isfinite(dh)
            void = inside & ~valid
            shares.append(float(W[void].sum() / W[inside].sum()))
            known = float(np.sum(W[valid] * dh[valid]))
            mean_dh = known / float(W[valid].sum())
            v_mean = known + mean_dh * float(W[void].sum())
            sd_mean = float(np.std(dh[valid])) * float(W[void].sum())
            filled, rec = hypsometric_fill(dh, z, W, inside)
            v_band = float(np.sum(W[inside] * filled[inside]))
            for key, v, sd in (("mean", v_mean, sd_mean), ("band", v_band, rec["fill_std_m3"])):
                errs[key].append(v - true_v)
                zs[key].append((v - true_v) / sd if sd > 0 else np.nan)
        for key in ("mean", "band"):
            e = np.array(errs[key])
            zz = np.array(zs[key])
            rows.append(
                {
                    "site": name,
                    "design": design,
                    "fill": key,
                    "void_share": float(np.mean(shares)),
                    "bias_pct": float(100 * e.mean() / abs(true_v)),
                    "rms_pct": float(100 * np.sqrt(np.mean(e**2)) / abs(true_v)),
                    "z_rms": float(np.sqrt(np.nanmean(zz**2))),
                    "within_1": float(np.nanmean(np.abs(zz) <= 1)),
                    "within_2": float(np.nanmean(np.abs(zz) <= 2)),
                    "true_volume_m3": true_v,
                    "trials": trials,
                }
            )
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=HERE / "results" / "void_fill.json")
    ap.add_argument("--sites", nargs="+", default=list(SITES))
    ap.add_argument("--trials", type=int, default=40)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--field-scale-m", type=float, default=100.0, help="scale of the correlated part of dh, m"
    )
    ap.add_argument(
        "--void-radius-m",
        type=float,
        nargs=2,
        default=(100.0, 300.0),
        help="the voids' radii are drawn between these, m",
    )
    args = ap.parse_args(argv)
    if not real_dems_or_skip(args.out, "void_fill"):
        return 0
    rows = []
    for k, name in enumerate(args.sites):
        rows += site_case(
            name, args.trials, args.seed + k, args.field_scale_m, tuple(args.void_radius_m)
        )
    cols = [("site", "site", "s"), ("design", "voids", "s"), ("fill", "fill", "s"),
            ("void_share", "void share", ".3f"), ("bias_pct", "bias %", "+.2f"),
            ("rms_pct", "rms %", ".2f"), ("z_rms", "z rms", ".2f"),
            ("within_1", "|z|<=1", ".2f"), ("within_2", "|z|<=2", ".2f")]  # fmt: skip
    print(table(rows, cols))
    for design in DESIGNS:
        for key in ("mean", "band"):
            sel = [r for r in rows if r["design"] == design and r["fill"] == key]
            rms = np.mean([r["rms_pct"] for r in sel])
            bias = np.mean([abs(r["bias_pct"]) for r in sel])
            z = np.median([r["z_rms"] for r in sel])
            within = np.mean([r["within_2"] for r in sel])
            print(
                f"{design:>8} {key:>4}: rms error {rms:.2f} % of the volume (mean over sites), "
                f"|bias| {bias:.2f} %, z rms {z:.2f} (median), |z| <= 2 on {100 * within:.0f} %"
            )
    write_json(args.out, {"benchmark": "void_fill", "settings": vars(args) | {"out": str(args.out)},
                          "rows": rows})  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
