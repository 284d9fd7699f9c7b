"""How honest a drawn breakline's fitted step is on real ground: step, 1-sigma, width, z.

Each real DEM of ``scripts/real_dems.py`` (the benchmark's 600 m, 25 m relief site) gets a
feature of ``scripts/ground_features.py`` (``scarp``: a 6 m step 1.5 m wide across the
tracks; ``scarp-end``: the same dying out inside the site), is sampled as in
``benchmarks/real_terrain.py``, and is mapped by the default ``TerrainGP`` with the
feature's own line drawn (``BreaklineMean([line])``, width chosen by the fit) on a constant
base and on the 8 x 8 prior fitted as ``a + b * DEM``. Printed per row: the fitted step and
its GLS 1-sigma, the fitted width, and ``z = (step - truth) / sd``; a row passes when
``|z| <= 2``. Session 41 (docs/terrain.md "The step's width by the map's evidence"): 16 / 22
scarp rows at 3,000 samples, against 2 / 22 with the width from the local planes alone.

    python benchmarks/breakline_steps.py                      # scarp, 3,000 samples
    python benchmarks/breakline_steps.py --feature scarp-end --sizes 3000 50000
    python benchmarks/breakline_steps.py --change 1.0   # and a second survey, the step 1 m higher

Session 42: each width's own uncertainty carried into the step's 1-sigma (21 / 22 within
2 sd at 3k, 22 / 22 at 50k), and the step's change between two surveys of a site
(``--change``: the rule of ``toolkit.breakline_record.step_changes``, each map at its own
width, and ``terrain.breakline_change.shared_width_change``, both at one shared width).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent / "scripts"))
from _harness import table, write_json  # noqa: E402

#: The features' true step, in units of the site's 25 m relief (scripts/ground_features.py).
STEP_M = 0.24 * 25.0
#: Widths (true 1.5 m) and steps are read from a row within this many sd of the truth.
Z_PASS = 2.0


def fit_step(truth: Any, samples: Any, line: np.ndarray, base: str) -> tuple[dict, Any]:
    """The default map with ``line`` drawn: its step, 1-sigma, width and width's 1-sigma;
    and the fitted GP."""
    from terrain import BreaklineMean, RasterMean, TerrainGP, coarse_dem

    kw = {} if base == "constant" else {"base": RasterMean(coarse_dem(truth), offset="fit")}
    gp = TerrainGP(seed=0, mean=BreaklineMean([line], **kw)).fit(samples)
    k = gp.mean_.coef_names.index("step1_m")
    row = {
        "step_m": float(gp.mean_.coef_[k]),
        "step_sd_m": float(np.sqrt(gp.mean_.coef_cov_[k, k])),
        "width_m": float(gp.mean_.widths_[0]),
        "width_sd_m": float((getattr(gp.mean_, "widths_sd_", None) or [np.nan])[0]),
    }
    return row, gp


def second_epoch(name: str, feature: str, n: int, growth: float) -> tuple[Any, Any]:
    """The same site surveyed again (the survey's draw 1: the same tracks, other scattered
    samples and noise) after the step grew by ``growth`` m (the feature scaled by
    ``1 + growth / STEP_M``): ``(truth, samples)``."""
    from real_terrain import _data

    from terrain.sampling import sample_dem

    site = {"name": name, "window": 0, "nodes": 40, "feature": feature, "draw": 1}
    truth, _, samples = _data(site, n)
    plain = _data({**site, "feature": "none"}, n)[0]
    grown = plain + (1.0 + growth / STEP_M) * (truth - plain)
    z = samples.z - sample_dem(truth, samples.xy) + sample_dem(grown, samples.xy)
    return grown, type(samples)(samples.xy, z, samples.z_var, crs=samples.crs)


def case(name: str, feature: str, n: int, base: str, growth: float | None) -> dict[str, Any]:
    """One site, feature, sample count and base: the fitted step's row; with ``growth``
    (m), also the step's change to a second survey of the site after it grew by that."""
    import real_dems
    from real_terrain import _data

    truth, _, samples = _data({"name": name, "window": 0, "nodes": 40, "feature": feature}, n)
    line = real_dems.feature_line(truth, feature)
    t0 = time.perf_counter()
    row = {"site": name, "feature": feature, "n": n, "base": base}
    before, gp = fit_step(truth, samples, line, base)
    row.update(before)
    row["z"] = (row["step_m"] - STEP_M) / row["step_sd_m"]
    row["pass"] = bool(abs(row["z"]) <= Z_PASS)
    row["fit_s"] = time.perf_counter() - t0
    if growth is not None:  # toolkit.breakline_record.step_changes' rule, then at one width
        from terrain.breakline_change import shared_width_change

        after, gp_after = fit_step(*second_epoch(name, feature, n, growth), line, base)
        row["change_m"] = after["step_m"] - row["step_m"]
        row["change_sd_m"] = float(np.hypot(after["step_sd_m"], row["step_sd_m"]))
        row["z_change"] = (row["change_m"] - growth) / row["change_sd_m"]
        row["detected"] = bool(row["change_m"] > Z_PASS * row["change_sd_m"])
        shared = shared_width_change(gp, gp_after, 0)
        row["shared_width_m"] = shared["width_m"]
        row["shared_change_m"] = shared["change_m"]
        row["shared_change_sd_m"] = shared["change_sd_m"]
        row["z_shared"] = (shared["change_m"] - growth) / shared["change_sd_m"]
        row["detected_shared"] = bool(shared["change_m"] > Z_PASS * shared["change_sd_m"])
    return row


def main(argv: list[str] | None = None) -> int:
    import real_dems

    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--feature", choices=("scarp", "scarp-end", "scarp-along"), default="scarp")
    p.add_argument("--sizes", nargs="+", type=int, default=[3000])
    p.add_argument("--sites", nargs="+", default=list(real_dems.NAMES))
    p.add_argument("--out", type=Path, default=HERE / "results" / "breakline_steps.json")
    p.add_argument("--change", type=float, default=None, metavar="GROWTH_M",
                   help="also survey each site again after the step grew by GROWTH_M m "
                   "(0: unchanged) and report the step's change")  # fmt: skip
    args = p.parse_args(argv)
    rows = [
        case(name, args.feature, n, base, args.change)
        for n in args.sizes
        for name in args.sites
        for base in ("constant", "8x8")
    ]
    cols = [
        ("site", "site", "s"),
        ("n", "n", "d"),
        ("base", "base", "s"),
        ("step_m", "step m", ".2f"),
        ("step_sd_m", "1-sigma m", ".2f"),
        ("width_m", "width m", ".2f"),
        ("width_sd_m", "1-sigma m", ".2f"),
        ("z", "z", "+.1f"),
        ("pass", "|z|<=2", ""),
    ]
    if args.change is not None:
        cols += [("change_m", "change m", "+.2f"), ("change_sd_m", "1-sigma m", ".2f"),
                 ("z_change", "z", "+.1f"), ("detected", "> 2 sd", ""),
                 ("shared_change_m", "shared m", "+.2f"),
                 ("shared_change_sd_m", "1-sigma m", ".2f"),
                 ("z_shared", "z", "+.1f"), ("detected_shared", "> 2 sd", "")]  # fmt: skip
    print(table(rows, cols))
    for key in ("z", "z_change", "z_shared") if args.change is not None else ("z",):
        z = np.array([r[key] for r in rows])
        within = int(np.sum(np.abs(z) <= Z_PASS))
        rms = float(np.sqrt(np.mean(z**2)))
        print(f"{key}: within {Z_PASS:g} sd {within} / {len(rows)}; rms {rms:.2f}")
    if args.change is not None:
        for key in ("detected", "detected_shared"):
            print(f"{key}: change beyond 2 sd of zero {sum(r[key] for r in rows)} / {len(rows)}")
    out = {"benchmark": "breakline_steps", "truth_step_m": STEP_M, "growth_m": args.change}
    write_json(args.out, {**out, "rows": rows})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
