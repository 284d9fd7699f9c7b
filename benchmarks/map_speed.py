"""Map speed on real terrain: 50,000 samples -> 600 x 600 cells at 1 m, fit included.

    python benchmarks/map_speed.py --out benchmarks/results/map_speed.json
    python benchmarks/map_speed.py --sites olinda rm --methods glacimap delaunay

Issue 16's speed targets, on the sites of ``benchmarks/real_terrain.py`` (a window of a real
DEM mapped onto 600 m x 600 m, 25 m relief; ``track_samples``: 8 rover tracks + 10 %
scattered, noise sd 0.2 m, seed 0), mapped onto the same bounds at 1 m (360,000 cells).
Each method runs in its own process, one at a time (wall time and peak RSS are its own):

``glacimap``   ``TerrainGP(seed=0)`` (the default: kernel by evidence, constant mean)
               ``.fit(samples)`` then ``.predict_grid(grid_1m)``: mean and 1-sigma.
``delaunay``   ``terrain.delaunay_linear`` on the same grid (no 1-sigma).
``rbf_tps64``  scipy ``RBFInterpolator``, thin-plate spline, 64 neighbours (no 1-sigma).

Targets: hyperparameter fit <= 5 s; fit + predict <= 15 s and <= 2 GB. Times are printed with
their ratio to the peers measured in the same run, since machines here are noisy. The
accuracy of these maps is ``benchmarks/real_terrain.py``'s (2 m, the truth's own cells).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from _harness import table, write_json  # noqa: E402
from real_terrain import _data, _provenance, guarded, parse_site  # noqa: E402

SITES = ("olinda", "rm", "glacier")
METHODS = ("glacimap", "delaunay", "rbf_tps64")
N = 50_000
RESOLUTION_M = 1.0
TARGETS = {"fit_s": 5.0, "total_s": 15.0, "peak_mb": 2048.0}


def case(site: dict, method: str) -> dict[str, Any]:
    """One method on one site: seconds (fit, predict, total) in a child process."""
    import numpy as np

    from terrain import Grid

    _, grid2, samples = _data(site, N)
    grid = Grid.from_bounds(grid2.bounds, RESOLUTION_M, grid2.crs)
    out: dict[str, Any] = {"cells": int(np.prod(grid.shape))}
    t0 = time.perf_counter()
    c0 = time.process_time()
    if method == "glacimap":
        from terrain import TerrainGP

        gp = TerrainGP(seed=0).fit(samples)
        t1 = time.perf_counter()
        ds = gp.predict_grid(grid)
        finite = np.isfinite(ds.elevation_std.values).mean()
        out.update(
            fit_s=t1 - t0,
            predict_s=time.perf_counter() - t1,
            kernel=repr(gp.kernel_),
            route=gp.predict_route_,
            std_defined=float(finite),
        )
    elif method == "delaunay":
        from terrain import delaunay_linear

        delaunay_linear(samples, grid)
    elif method == "rbf_tps64":
        import _peers

        _peers.rbf_tps(samples, grid.xy(), neighbors=64)
    else:
        raise ValueError(f"method: expected one of {METHODS}, got {method!r}")
    out.update(total_s=time.perf_counter() - t0, cpu_s=time.process_time() - c0)
    return out


def report(rows: list[dict]) -> list[dict]:
    """Ratios to the peers of the same site, the table and the verdicts."""
    by: dict[str, dict[str, dict]] = {}
    for r in rows:
        by.setdefault(r["site"], {})[r["method"]] = r
    verdicts = []
    for site, group in by.items():
        g = group.get("glacimap")
        for r in group.values():
            for ref in ("delaunay", "rbf_tps64"):
                peer = group.get(ref, {}).get("total_s")
                if r.get("total_s") is not None and peer:
                    r[f"over_{ref}"] = r["total_s"] / peer
        if g and g.get("total_s") is not None:
            verdicts.append(
                {
                    "site": site,
                    "fit_ok": "PASS" if g["fit_s"] <= TARGETS["fit_s"] else "MISS",
                    "total_ok": "PASS" if g["total_s"] <= TARGETS["total_s"] else "MISS",
                    "memory_ok": "PASS" if g["peak_rss_mb"] <= TARGETS["peak_mb"] else "MISS",
                }
            )
    print(
        f"\n{N:,} samples -> 600 x 600 cells at {RESOLUTION_M:g} m; seconds in the process"
        " (fit included), CPU seconds over both cores, peak RSS; ratios: total over the peer's"
        " total in the same run"
    )
    print(
        table(
            rows,
            [
                ("site", "site", ""),
                ("method", "method", ""),
                ("fit_s", "fit s", ".1f"),
                ("predict_s", "predict s", ".1f"),
                ("total_s", "total s", ".1f"),
                ("cpu_s", "CPU s", ".1f"),
                ("over_delaunay", "/Delaunay", ".1f"),
                ("over_rbf_tps64", "/RBF", ".2f"),
                ("peak_rss_mb", "peak MB", ".0f"),
            ],
        )
    )
    for r in rows:
        if r.get("skipped") or r.get("error"):
            print(f"  {r['site']} {r['method']}: {r.get('skipped') or r.get('error')}")
        if r.get("kernel"):
            print(f"  {r['site']}: {r['kernel']}; {r['route'][:90]}")
    print(
        f"\nTargets: fit <= {TARGETS['fit_s']:g} s, fit + predict <= {TARGETS['total_s']:g} s,"
        f" peak <= {TARGETS['peak_mb']:,.0f} MB"
    )
    if verdicts:
        print(
            table(
                verdicts,
                [("site", "site", ""), ("fit_ok", "fit", ""), ("total_ok", "total", "")]
                + [("memory_ok", "memory", "")],
            )
        )
    return verdicts


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/map_speed.json"))
    ap.add_argument("--sites", nargs="+", type=parse_site, default=None)
    ap.add_argument("--methods", nargs="+", choices=METHODS, default=list(METHODS))
    args = ap.parse_args(argv)
    sites = args.sites or [parse_site(s) for s in SITES]
    import real_dems

    settings = {
        "sites": sites,
        "n": N,
        "resolution_m": RESOLUTION_M,
        "methods": args.methods,
        "targets": TARGETS,
    }
    try:
        real_dems.fetch()
    except real_dems.RealDataUnavailable as exc:
        print(f"skipped: {exc}")
        write_json(args.out, {"benchmark": "map_speed", "settings": settings, "skipped": str(exc)})
        return 0
    rows = []
    for site in sites:
        for method in args.methods:
            r = guarded(case, site, method)
            rows.append({"site": site["name"], "method": method, **r})
    verdicts = report(rows)
    write_json(
        args.out,
        {
            "benchmark": "map_speed",
            "settings": settings,
            "provenance": _provenance(),
            "results": rows,
            "verdicts": verdicts,
        },
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
