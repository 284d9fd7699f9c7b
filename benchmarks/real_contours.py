"""A real map's contours as the samples: how the default map and its 1-sigma do between them.

``glacier.rda`` of r-cran-fields (``scripts/real_dems.py``): 8,338 points digitised from the
contours of a real glacier, 30 levels 25 m apart (1,300-2,025 m) over 10 x 12 km, about
55 m apart along each contour. Old topographic maps give glaciologists exactly this as the
earlier epoch of a change. Every 4th level is held out (``--offsets``: which of the four),
the map is fitted on the rest, and the held-out contours are predicted: their elevation is
known exactly, so they are truth the project did not make. Each row: RMSE on Delaunay's
hull against Delaunay (linear) and scipy's thin-plate RBF (64 neighbours) in the same run,
the default ``TerrainGP(seed=0)``'s coverage of the held-out contours at 95 and 68 % by
their distance to the nearest fitted point, and what the user's own check says
(``cross_validate(gp, samples, n_folds=5, seed=0)``: its map-matched coverage). Session 42
(docs/terrain.md "A real map's contours as the samples").

    python benchmarks/real_contours.py                 # the four offsets, ~2 min
    python benchmarks/real_contours.py --horizontal-sd 10   # the contours' position error
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

#: Distance bins (m) from a held-out point to the nearest fitted point.
BINS = (0.0, 100.0, 200.0, 400.0, np.inf)


def contours() -> tuple[np.ndarray, np.ndarray, str]:
    """The glacier's contour points: ``xy`` (n, 2) m, ``z`` (n,) m, and their CRS."""
    import real_dems

    d = real_dems._read_rda(real_dems.fetch() / "glacier.rda", "glacier")
    xy = np.asarray(d["loc"], float) * 1000.0  # km -> m
    return xy, np.asarray(d["y"], float).ravel(), real_dems.LOCAL_TM


def case(offset: int, check: bool, horizontal_sd: float = 0.0) -> dict[str, Any]:
    """Levels ``offset``, ``offset + 4``... held out; the row of scores. ``horizontal_sd``
    (m): the samples' horizontal 1-sigma through the map's slope in the 1-sigma and the
    check, as ``glacimap reconstruct --horizontal-sd`` adds it
    (:func:`toolkit.error_budget.heldout_slope_term`, the slope from the map on 100 m
    cells)."""
    from scipy.interpolate import LinearNDInterpolator, RBFInterpolator
    from scipy.spatial import cKDTree

    from terrain import ElevationSamples, TerrainGP, cross_validate

    xy, z, crs = contours()
    held = np.isin(z, np.unique(z)[offset::4])
    fit, test = xy[~held], xy[held]
    truth = z[held]
    t0 = time.perf_counter()
    delaunay = LinearNDInterpolator(fit, z[~held])(test)
    t_delaunay = time.perf_counter() - t0
    hull = np.isfinite(delaunay)
    t0 = time.perf_counter()
    rbf = RBFInterpolator(fit, z[~held], neighbors=64, kernel="thin_plate_spline")(test)
    t_rbf = time.perf_counter() - t0
    samples = ElevationSamples(fit, z[~held], 0.0, crs=crs)  # no noise stated: the nugget
    t0 = time.perf_counter()
    gp = TerrainGP(seed=0).fit(samples)
    mu, sd = gp.predict(test, return_std=True)
    t_gp = time.perf_counter() - t0
    extra = None
    if horizontal_sd:
        from terrain import Grid
        from toolkit.error_budget import heldout_slope_term

        lo, hi = fit.min(axis=0), fit.max(axis=0)
        box = (lo[0], lo[1], hi[0], hi[1])
        coarse = gp.predict_grid(Grid.from_bounds(box, 100.0, crs=crs))
        extra = heldout_slope_term(gp, coarse, horizontal_sd)
        sd = np.sqrt(sd**2 + extra(None, test, sd**2))

    def rmse(p: np.ndarray) -> float:
        return float(np.sqrt(np.mean((p[hull] - truth[hull]) ** 2)))

    zs = np.abs(mu - truth)[hull] / sd[hull]
    row: dict[str, Any] = {
        "offset": offset,
        "horizontal_sd_m": horizontal_sd,
        "n_fit": int(fit.shape[0]),
        "n_held": int(hull.sum()),
        "rmse_delaunay_m": rmse(delaunay),
        "rmse_rbf_m": rmse(rbf),
        "rmse_glacimap_m": rmse(mu),
        "over_delaunay": rmse(mu) / rmse(delaunay),
        "over_rbf": rmse(mu) / rmse(rbf),
        "cov95": 100.0 * float(np.mean(zs < 1.959964)),
        "cov68": 100.0 * float(np.mean(zs < 1.0)),
        "z_sd": float(np.std(((mu - truth) / sd)[hull])),
        "kernel": repr(gp.kernel_),
        "seconds": {"delaunay": t_delaunay, "rbf": t_rbf, "glacimap": t_gp},
    }
    dist = cKDTree(fit).query(test[hull])[0]
    row["by_distance"] = []
    for lo, hi in zip(BINS[:-1], BINS[1:], strict=True):
        m = (dist >= lo) & (dist < hi)
        if m.any():
            row["by_distance"].append(
                {
                    "from_m": lo,
                    "to_m": hi,
                    "n": int(m.sum()),
                    "cov95": 100.0 * float(np.mean(zs[m] < 1.959964)),
                    "cov68": 100.0 * float(np.mean(zs[m] < 1.0)),
                    "rmse_m": float(np.sqrt(np.mean((mu - truth)[hull][m] ** 2))),
                    "median_sd_m": float(np.median(sd[hull][m])),
                }  # fmt: skip
            )
    if check:
        cv = cross_validate(gp, samples, n_folds=5, seed=0, extra_variance=extra)
        row["check_cov95"] = 100.0 * float(cv.pooled["map_coverage_95"])
        row["check_cov68"] = 100.0 * float(cv.pooled["map_coverage_68"])
    return row


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--offsets", nargs="+", type=int, default=[0, 1, 2, 3])
    p.add_argument("--no-check", action="store_true", help="skip cross_validate (~15 s a row)")
    p.add_argument("--horizontal-sd", type=float, default=0.0,
                   help="the samples' horizontal 1-sigma, m (glacimap reconstruct's)")  # fmt: skip
    p.add_argument("--out", type=Path, default=HERE / "results" / "real_contours.json")
    args = p.parse_args(argv)
    rows = [case(k, not args.no_check, args.horizontal_sd) for k in args.offsets]
    cols = [
        ("offset", "held out", "d"),
        ("n_held", "points", "d"),
        ("rmse_delaunay_m", "Delaunay m", ".2f"),
        ("rmse_rbf_m", "RBF m", ".2f"),
        ("rmse_glacimap_m", "glacimap m", ".2f"),
        ("over_delaunay", "/Delaunay", ".3f"),
        ("over_rbf", "/RBF", ".3f"),
        ("cov95", "in 95%", ".1f"),
        ("cov68", "in 68%", ".1f"),
    ]
    if not args.no_check:
        cols += [("check_cov95", "check 95", ".1f"), ("check_cov68", "check 68", ".1f")]
    print(table(rows, cols))
    print("coverage of the held-out contours by distance to the nearest fitted point:")
    for r in rows:
        parts = [
            f"{b['from_m']:.0f}-{b['to_m']:.0f} m: {b['cov95']:.1f} / {b['cov68']:.1f} % "
            f"(n {b['n']}, RMSE {b['rmse_m']:.1f}, sd {b['median_sd_m']:.1f})"
            for b in r["by_distance"]
        ]
        print(f"  offset {r['offset']}: " + "; ".join(parts))
    write_json(args.out, {"benchmark": "real_contours", "rows": rows})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
