"""Landmark marginals where adjacent swaths share landmarks: keyframes in time order against
the reverse Cuthill-McKee renumbering (``factorgraph.marginals``), same graph, same run.

    python benchmarks/marginals_order.py --out benchmarks/results/marginals_order.json

Traverses on ``terrain.synthetic.default_site(2.0)`` (``simulate_traverse``, seed 4, default
sensors), localized with ``LocalizeParams(refine=False)``; then ``landmark_marginals`` on the
final graph with ``reorder=False`` (time order) and ``reorder=True`` (the default):

``line``     one 200 m leg (the order is kept: nothing to gain);
``two_legs`` two 180 m legs 30 m apart (landmarks seen from both legs span a leg in time).

Printed: the band ``W`` (keyframes) and seconds of each order, their ratio, and the largest
difference of the covariances relative to their largest entry (the same matrices: rounding).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from _harness import table, write_json  # noqa: E402

W0, N0 = 526000.0, 6475600.0
PATHS = {
    "line": [[W0 + 20, N0 - 300], [W0 + 220, N0 - 300]],
    "two_legs": [
        [W0 + 20, N0 - 300],
        [W0 + 200, N0 - 300],
        [W0 + 200, N0 - 270],
        [W0 + 20, N0 - 270],
    ],
}
FIELDS = ("landmark_cov", "landmark_cov_relative", "shared_cov", "pose_cov_xyz")


def case(name: str) -> dict:
    import numpy as np

    from factorgraph.localize import LocalizeParams, localize
    from factorgraph.marginals import landmark_marginals
    from factorgraph.simulate import simulate_traverse
    from terrain.synthetic import default_site

    log = simulate_traverse(default_site(2.0), np.array(PATHS[name]), seed=4)
    res = localize(log, LocalizeParams(refine=False))
    args = (res.graph, res.estimate, log.n_keyframes, [int(i) for i in res.landmark_id], True)
    out = {"case": name, "keyframes": log.n_keyframes, "landmarks": int(res.landmark_id.size)}
    got = {}
    for reorder in (False, True):
        t0 = time.perf_counter()
        got[reorder] = landmark_marginals(*args, drift_model=True, reorder=reorder)
        key = "rcm" if reorder else "time"
        out[f"{key}_s"] = time.perf_counter() - t0
        out[f"{key}_W"] = got[reorder].bandwidth
    out["speedup"] = out["time_s"] / out["rcm_s"]
    out["max_rel_diff"] = max(
        float(np.abs(getattr(got[True], f) - getattr(got[False], f)).max())
        / float(np.abs(getattr(got[False], f)).max())
        for f in FIELDS
    )
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="+", default=list(PATHS), choices=list(PATHS))
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/marginals_order.json"))
    a = ap.parse_args(argv)
    rows = [case(name) for name in a.cases]
    cols = [
        ("case", "case", ""),
        ("keyframes", "keyframes", "d"),
        ("landmarks", "landmarks", "d"),
        ("time_W", "W time", "d"),
        ("rcm_W", "W rcm", "d"),
        ("time_s", "time order s", ".2f"),
        ("rcm_s", "rcm s", ".2f"),
        ("speedup", "time / rcm", ".1f"),
        ("max_rel_diff", "max rel diff", ".1e"),
    ]
    print(table(rows, cols))
    write_json(a.out, {"benchmark": "marginals_order", "results": rows})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
