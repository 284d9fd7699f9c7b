"""Landmark NEES over seeds, split into the shared offset and the relative part.

    python benchmarks/landmark_nees.py --seeds 0-9 --out benchmarks/results/landmark_nees.json
    python benchmarks/landmark_nees.py --config my.toml --seeds 0-2

For each seed: the scenario's truth, plan and log (ideal camera tracks), ``localize_log``,
then against the simulation's truth (docs/vision.md, "Landmark NEES: what the number
measures"):

* ``nees``: mean over landmarks of ``e^T P^-1 e`` with the full 3 x 3 marginal (expected 3);
* ``shared_chi2``: the mean keyframe error ``delta`` (the map-wide offset) against the stated
  ``shared_offset_cov`` (one 3-dof draw per run, expected 3);
* ``relative_nees``: ``e - delta`` against ``landmark_cov_relative`` (expected 3), and per
  axis (expected 1 each).

One run's NEES follows its one shared-offset draw; the mean over seeds is the test.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _harness import table, write_json  # noqa: E402


def _seeds(text: str) -> list[int]:
    if "-" in text:
        lo, hi = text.split("-")
        return list(range(int(lo), int(hi) + 1))
    return [int(v) for v in text.split(",")]


def _quad(e: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Per-row ``e_i^T cov_i^-1 e_i`` for e (n, 3) and cov (n, 3, 3)."""
    return np.einsum("ni,ni->n", e, np.linalg.solve(cov, e[..., None])[..., 0])


def one_seed(config: str | None, seed: int) -> dict:
    from toolkit.config import load_scenario
    from toolkit.pipeline import localize_log, make_plan, make_truth, simulate_log

    t0 = time.perf_counter()
    sc = load_scenario(config, overrides={"seed": seed})
    truth = make_truth(sc)
    log = simulate_log(sc, truth, make_plan(sc, truth))
    loc = localize_log(log, sc)
    e = loc.landmark_xyz - loc.true_landmarks()
    ok = np.isfinite(e).all(1)
    e, cov, rel = e[ok], loc.landmark_cov[ok], loc.landmark_cov_relative[ok]
    delta = (loc.keyframe_xyz - log.truth["xyz"]).mean(0)  # the map-wide offset, m
    er = e - delta
    shared = loc.shared_offset_cov
    per_axis = (er**2 / np.diagonal(rel, axis1=1, axis2=2)).mean(0)
    return {
        "seed": seed,
        "landmarks": int(ok.sum()),
        "nees": float(_quad(e, cov).mean()),
        "in_2sigma": float(np.mean(_quad(e, cov) <= 8.025)),  # chi2(3) 0.9545 quantile
        "shared_chi2": float(delta @ np.linalg.solve(shared, delta)),
        "shared_std_m": [float(v) for v in np.sqrt(np.diag(shared))],
        "shared_z": [float(v) for v in delta / np.sqrt(np.diag(shared))],
        "relative_nees": float(_quad(er, rel).mean()),
        "relative_x": float(per_axis[0]),
        "relative_y": float(per_axis[1]),
        "relative_z": float(per_axis[2]),
        "seconds": time.perf_counter() - t0,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default=None, help="scenario TOML (default: the embedded one)")
    ap.add_argument("--seeds", default="0-9", help="'0-9' or '0,3,5'")
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/landmark_nees.json"))
    a = ap.parse_args()
    warnings.simplefilter("ignore")
    rows = []
    cols = [
        ("seed", "seed", "d"),
        ("landmarks", "landmarks", "d"),
        ("nees", "NEES", ".2f"),
        ("in_2sigma", "in 2σ", ".3f"),
        ("shared_chi2", "shared chi2", ".2f"),
        ("relative_nees", "relative NEES", ".2f"),
        ("relative_x", "rel x", ".2f"),
        ("relative_y", "rel y", ".2f"),
        ("relative_z", "rel z", ".2f"),
        ("seconds", "s", ".0f"),
    ]
    for seed in _seeds(a.seeds):
        rows.append(one_seed(a.config, seed))
        print(table(rows[-1:], cols).splitlines()[-1] if len(rows) > 1 else table(rows, cols))
    keys = ["nees", "in_2sigma", "shared_chi2", "relative_nees", "relative_x", "relative_y"]
    keys.append("relative_z")
    mean = {
        "seed": None,
        "landmarks": None,
        **{k: float(np.mean([r[k] for r in rows])) for k in keys},
    }
    mean["shared_z2_per_axis"] = [
        float(v) for v in np.mean([np.square(r["shared_z"]) for r in rows], 0)
    ]
    print(f"mean over {len(rows)} seeds:")
    print(table([mean], cols))
    print("shared offset mean z^2 per axis (expected 1):", np.round(mean["shared_z2_per_axis"], 2))
    write_json(
        a.out,
        {
            "benchmark": "landmark_nees",
            "config": a.config,
            "seeds": a.seeds,
            "rows": rows,
            "mean": mean,
        },
    )


if __name__ == "__main__":
    main()
