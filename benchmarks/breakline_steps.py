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


def case(name: str, feature: str, n: int, base: str) -> dict[str, Any]:
    """One site, feature, sample count and base: the fitted step's row."""
    import real_dems
    from real_terrain import _data

    from terrain import BreaklineMean, RasterMean, TerrainGP, coarse_dem

    truth, _, samples = _data({"name": name, "window": 0, "nodes": 40, "feature": feature}, n)
    line = real_dems.feature_line(truth, feature)
    kw = {} if base == "constant" else {"base": RasterMean(coarse_dem(truth), offset="fit")}
    t0 = time.perf_counter()
    gp = TerrainGP(seed=0, mean=BreaklineMean([line], **kw)).fit(samples)
    k = gp.mean_.coef_names.index("step1_m")
    step, sd = float(gp.mean_.coef_[k]), float(np.sqrt(gp.mean_.coef_cov_[k, k]))
    z = (step - STEP_M) / sd
    return {
        "site": name,
        "feature": feature,
        "n": n,
        "base": base,
        "step_m": step,
        "step_sd_m": sd,
        "width_m": float(gp.mean_.widths_[0]),
        "z": z,
        "pass": bool(abs(z) <= Z_PASS),
        "fit_s": time.perf_counter() - t0,
    }


def main(argv: list[str] | None = None) -> int:
    import real_dems

    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--feature", choices=("scarp", "scarp-end"), default="scarp")
    p.add_argument("--sizes", nargs="+", type=int, default=[3000])
    p.add_argument("--sites", nargs="+", default=list(real_dems.NAMES))
    p.add_argument("--out", type=Path, default=HERE / "results" / "breakline_steps.json")
    args = p.parse_args(argv)
    rows = [
        case(name, args.feature, n, base)
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
        ("z", "z", "+.1f"),
        ("pass", "|z|<=2", ""),
    ]
    print(table(rows, cols))
    z = np.array([r["z"] for r in rows])
    within = int(np.sum(np.abs(z) <= Z_PASS))
    print(f"within {Z_PASS:g} sd: {within} / {len(rows)}; rms z {np.sqrt(np.mean(z**2)):.2f}")
    write_json(args.out, {"benchmark": "breakline_steps", "truth_step_m": STEP_M, "rows": rows})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
