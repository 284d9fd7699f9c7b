"""Glacier change: co-registration against xDEM, the volume-change 1-sigma by Monte Carlo, and
the time of a 1 m change map.

Parts, one JSON each run (``benchmarks/results/change.json``; the calibration and the chain
parts are run on their own, JSON files below):

``coreg``  Two copies of a real DEM (the olinda-shaped 640 m site of scripts/real_dems.py at
           1 m, sampled on two 2 m lattices 3 m east / 2 m north apart, +1 m vertical, with
           and without 0.1 m independent noise): glacimap's ``terrain.coregister`` and
           ``xdem.coreg.NuthKaab`` on the same pair, shift errors and seconds in one run.
``mc``     Monte Carlo over seeded epoch pairs on the default site: each epoch surveyed along
           the same lawnmower tracks (``terrain.sample_along_path``: range-dependent noise)
           with its own shared vertical offset draw, reconstructed with ``TerrainGP()``
           (default constructor), differenced, integrated over the glacier outline. The
           volume error over sigma_dV: glacimap (GP posterior + shared offsets) against the
           negative controls (per-cell independent sigma; the variogram of stable dh).
``calib``  The along-track error model's calibration (benchmarks/_change_chain.py): surveys of
           the chain plan with seeds disjoint from the Monte Carlo's, the realised relative
           errors of the selected landmarks against the time lag, (fraction, tau) fitted.
``chain``  The Monte Carlo through the real chain on a smaller plan (benchmarks/_change_chain.py):
           each epoch simulated (GPS with its Gauss-Markov bias, odometry, camera tracks), with
           4 ground-control corner stops (``--no-control``: none), localized by iSAM2,
           selected and reconstructed as ``glacimap run`` does; no drawn offsets: the surveys'
           offsets and along-track errors are what the localization leaves. sigma_dV with and
           without the along-track term.
``speed``  ``difference`` + ``volume_change`` (GP route and variogram route) for two 600 m x
           600 m products at 1 m (the two reconstructions excluded, timed separately).

    python benchmarks/change.py --pairs 50 --out benchmarks/results/change.json
    python benchmarks/change.py --parts calib --calib-surveys 24 \
        --out benchmarks/results/change_along_track_calib.json
    python benchmarks/change.py --parts chain --chain-pairs 100 \
        --out benchmarks/results/change_chain_control.json
    python benchmarks/change.py --parts chain --chain-pairs 50 --no-control \
        --out benchmarks/results/change_chain.json
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT / "scripts"))
sys.path.insert(0, str(ROOT))
from _harness import table, write_json  # noqa: E402

#: Shared vertical offset 1-sigma of one survey, m: the default scenario with 4 ground control
#: corners at 2 cm (commit cdf1945: 0.085 m).
SHARED_OFFSET_SD = 0.085
N_SAMPLES = 1500  # landmarks per epoch (exact GP)
MC_RESOLUTION = 4.0  # m, reconstruction grid of the Monte Carlo (150 x 150 cells)
CONTROL = {"n_targets": 4, "mode": "stops"}  # the chain's ground control (_change_chain)
#: Stable ground = the site outside the outline grown by this much, m: the GP maps smear the
#: glacier's thinning over ~1-2 length scales onto the ground next to the outline.
STABLE_BUFFER_M = 40.0


def shifted_pair(noise: float, seed: int = 0):
    """Reference and a copy displaced 3 m east, 2 m north, +1 m, from a real-DEM site."""
    from real_dems import glacier_site

    from terrain import Grid

    fine = glacier_site("olinda", size_m=640.0, resolution=1.0)
    g = Grid.from_dataarray(fine)
    z = fine.values
    rng = np.random.default_rng(seed)
    ref_v = z[10:610:2, 10:610:2]
    dem_v = z[12:612:2, 7:607:2] + 1.0  # each label sees the truth 3 m west, 2 m south
    gr = Grid(g.west + 10, g.north - 10, (2.0, 2.0), ref_v.shape, g.crs)
    ref = gr.data_array(ref_v + rng.normal(0, noise, ref_v.shape), "elevation")
    dem = gr.data_array(dem_v + rng.normal(0, noise, dem_v.shape), "elevation")
    return ref, dem


def coreg_part() -> list[dict]:
    import rasterio.crs
    import xdem

    from terrain import Grid, coregister

    rows = []
    for noise in (0.0, 0.1):
        ref, dem = shifted_pair(noise)
        t = time.perf_counter()
        r = coregister(ref, dem)
        tg = time.perf_counter() - t
        g = Grid.from_dataarray(ref)
        t = time.perf_counter()
        nk = xdem.coreg.NuthKaab().fit(
            ref.values,
            dem.values,
            transform=g.transform,
            crs=rasterio.crs.CRS.from_wkt(g.crs.to_wkt()),
            random_state=0,
        )
        tx = time.perf_counter() - t
        a = nk.meta["outputs"]["affine"]  # xDEM reports the correction: minus the shift
        for name, e, n, v, sec in (
            ("glacimap", r.shift_east_m, r.shift_north_m, r.vertical_bias_m, tg),
            ("xdem NuthKaab", -a["shift_x"], -a["shift_y"], -a["shift_z"], tx),
        ):
            rows.append(
                {
                    "noise_m": noise,
                    "impl": name,
                    "east_m": float(e),
                    "north_m": float(n),
                    "vertical_m": float(v),
                    "horiz_err_m": float(np.hypot(e - 3.0, n - 2.0)),
                    "vert_err_m": float(abs(v - 1.0)),
                    "seconds": sec,
                }
            )
        rows[-2].update(
            east_sd_m=r.shift_east_std_m,
            north_sd_m=r.shift_north_std_m,
            vertical_sd_m=r.vertical_bias_std_m,
            iterations=r.iterations,
        )
    return rows


def _epoch(truth, path, rng, seed: int, grid):
    from terrain import ElevationSamples, TerrainGP, sample_along_path

    s, _ = sample_along_path(truth, path, N_SAMPLES, seed=rng)
    offset = rng.normal(0.0, SHARED_OFFSET_SD)
    s = ElevationSamples(s.xy, s.z + offset, s.z_var, crs=s.crs)
    gp = TerrainGP(seed=seed).fit(s)
    product = gp.predict_grid(grid)
    product.attrs["shared_vertical_offset_std_m"] = SHARED_OFFSET_SD
    return gp, product, offset


def mc_pair(seed: int) -> dict:
    from shapely.geometry import box

    from survey.lawnmower import lawnmower
    from terrain import Grid, default_outline, default_site, difference, second_epoch
    from terrain.coregister import stable_mask
    from terrain.synthetic import DEFAULT_SITE_BOUNDS
    from terrain.volume import outline_weights, volume_change

    t0 = time.perf_counter()
    truth = default_site(resolution=2.0)
    outline = default_outline(DEFAULT_SITE_BOUNDS)
    path = lawnmower(DEFAULT_SITE_BOUNDS, 8, margin=20.0).waypoints
    grid = Grid.from_bounds(DEFAULT_SITE_BOUNDS, MC_RESOLUTION)
    rng = np.random.default_rng(seed)
    after_truth = second_epoch(truth, outline, seed=seed)
    gp_b, prod_b, off_b = _epoch(truth, path, rng, seed, grid)
    gp_a, prod_a, off_a = _epoch(after_truth, path, rng, seed, grid)
    diff = difference(prod_b, prod_a, coregister=False)
    W = outline_weights(grid, outline)
    true_dh = (after_truth - truth).interp(x=grid.x, y=grid.y).values
    true_v = float(np.sum(W * true_dh))
    gpv = volume_change(diff, outline, models=(gp_b, gp_a))
    stable_geom = box(*DEFAULT_SITE_BOUNDS).difference(outline.buffer(STABLE_BUFFER_M))
    stable = stable_mask(grid, stable_geom)[0] & np.isfinite(diff["dh"].values)
    var = volume_change(diff, outline, stable=stable)
    # xDEM practice: remove the median dh of stable ground (its vertical shift) first
    shift = float(np.median(diff["dh"].values[stable]))
    d2 = diff.copy()
    d2["dh"] = diff["dh"] - shift
    var2 = volume_change(d2, outline, stable=stable)
    # glacimap with stable ground: co-registered (offsets estimated away), GP + bias sigma
    dco = difference(prod_b, prod_a, coregister=True, stable=stable_geom)
    gco = volume_change(dco, outline, models=(gp_b, gp_a))
    return {
        "seed": seed,
        "true_volume_m3": true_v,
        "volume_m3": gpv.volume_m3,
        "volume_shifted_m3": var2.volume_m3,
        "sigma_glacimap_m3": gpv.volume_std_m3,
        "sigma_independent_m3": gpv.independent_std_m3,
        "sigma_variogram_m3": var.volume_std_m3,
        "sigma_variogram_shifted_m3": var2.volume_std_m3,
        "volume_coreg_m3": gco.volume_m3,
        "sigma_glacimap_coreg_m3": gco.volume_std_m3,
        "budget_coreg_m3": gco.budget_m3,
        "budget_m3": gpv.budget_m3,
        "offsets_m": [off_b, off_a],
        "kernels": [repr(gp_b.kernel_), repr(gp_a.kernel_)],
        "seconds": time.perf_counter() - t0,
    }


def z_rows(pairs: list[dict], methods) -> list[dict]:
    """One row per ``(name, sigma key, errors)``: z = error / sigma, its mean, spread and
    95 % coverage, the median sigma and the RMS error (m^3)."""
    rows = []
    for name, key, e in methods:
        s = np.array([p[key] for p in pairs])
        z = e / s
        rows.append(
            {
                "method": name,
                "n": len(pairs),
                "median_sigma_m3": float(np.median(s)),
                "rms_error_m3": float(np.sqrt(np.mean(e**2))),
                "z_mean": float(np.mean(z)),
                "z_spread": float(np.std(z, ddof=1)) if len(z) > 1 else float("nan"),
                "coverage_95": float(np.mean(np.abs(z) <= 1.959964)),
            }
        )
    return rows


def summarize(pairs: list[dict]) -> list[dict]:
    err = np.array([p["volume_m3"] - p["true_volume_m3"] for p in pairs])
    err2 = np.array([p["volume_shifted_m3"] - p["true_volume_m3"] for p in pairs])
    err3 = np.array([p["volume_coreg_m3"] - p["true_volume_m3"] for p in pairs])
    return z_rows(
        pairs,
        (
            ("glacimap (GP posterior + offsets)", "sigma_glacimap_m3", err),
            ("glacimap, co-registered on stable", "sigma_glacimap_coreg_m3", err3),
            ("per-cell independent (control)", "sigma_independent_m3", err),
            ("variogram of stable dh (control)", "sigma_variogram_m3", err),
            ("variogram, stable median removed", "sigma_variogram_shifted_m3", err2),
        ),
    )


def speed_part(n_samples: int = 1500) -> dict:
    from survey.lawnmower import lawnmower
    from terrain import (
        ElevationSamples,
        Grid,
        TerrainGP,
        default_outline,
        default_site,
        difference,
        sample_along_path,
        second_epoch,
    )
    from terrain.synthetic import DEFAULT_SITE_BOUNDS
    from terrain.volume import volume_change

    truth = default_site(resolution=2.0)
    outline = default_outline(DEFAULT_SITE_BOUNDS)
    path = lawnmower(DEFAULT_SITE_BOUNDS, 8, margin=20.0).waypoints
    grid = Grid.from_bounds(DEFAULT_SITE_BOUNDS, 1.0)  # 600 x 600 cells
    out: dict = {"grid": list(grid.shape), "n_samples": n_samples}
    gps, prods = [], []
    t = time.perf_counter()
    for k, tr in enumerate((truth, second_epoch(truth, outline, seed=0))):
        s, _ = sample_along_path(tr, path, n_samples, seed=k)
        gp = TerrainGP(seed=0).fit(ElevationSamples(s.xy, s.z, s.z_var, crs=s.crs))
        gps.append(gp)
        prods.append(gp.predict_grid(grid))
    out["reconstruct_two_epochs_s"] = time.perf_counter() - t
    t = time.perf_counter()
    diff = difference(prods[0], prods[1], coregister=False)
    vc = volume_change(diff, outline, models=tuple(gps), shared_offset_std=(0.085, 0.085))
    out["change_gp_route_s"] = time.perf_counter() - t
    t = time.perf_counter()
    diff = difference(prods[0], prods[1], coregister=True, outline=outline)
    vv = volume_change(diff, outline)
    out["change_coreg_variogram_route_s"] = time.perf_counter() - t
    out["volume_m3"], out["sigma_gp_m3"] = vc.volume_m3, vc.volume_std_m3
    out["sigma_variogram_m3"] = vv.volume_std_m3
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--pairs", type=int, default=50)
    ap.add_argument(
        "--parts",
        default="coreg,mc,speed",
        help="coreg, mc, calib, calib-pool, chain, chain-summary, speed",
    )
    ap.add_argument("--chain-pairs", type=int, default=20)
    ap.add_argument("--chain-seed0", type=int, default=0, help="first pair seed of the chain")
    ap.add_argument("--no-control", action="store_true", help="chain / calib without control")
    ap.add_argument("--calib-surveys", type=int, default=8)
    ap.add_argument("--calib-seed0", type=int, default=1000)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks/results/change.json")
    args = ap.parse_args()
    parts = args.parts.split(",")
    payload: dict = {
        "command": "python benchmarks/change.py " + " ".join(sys.argv[1:]),
        "caveat": "timings on a shared 2-core machine (other jobs running): inflated",
    }
    if "coreg" in parts:
        rows = coreg_part()
        payload["coregistration"] = rows
        cols = [("noise_m", "noise m", ".2f"), ("impl", "impl", "")]
        cols += [(k, k, ".4f") for k in ("east_m", "north_m", "vertical_m")]
        cols += [("horiz_err_m", "horiz err m", ".4f"), ("vert_err_m", "vert err m", ".4f")]
        print(table(rows, cols + [("seconds", "s", ".2f")]))
    if "mc" in parts:
        pairs = []
        for seed in range(args.pairs):
            pairs.append(mc_pair(seed))
            p = pairs[-1]
            z = (p["volume_m3"] - p["true_volume_m3"]) / p["sigma_glacimap_m3"]
            print(f"pair {seed}: z {z:+.2f}  ({p['seconds']:.1f} s)", flush=True)
        summary = summarize(pairs)
        payload["monte_carlo"] = {
            "pairs": pairs,
            "summary": summary,
            "settings": {
                "site": "terrain.default_site(2.0), outline terrain.default_outline",
                "plan": "survey.lawnmower 8 swaths, margin 20 m (the same tracks both epochs)",
                "n_samples_per_epoch": N_SAMPLES,
                "grid_resolution_m": MC_RESOLUTION,
                "shared_offset_sd_m": SHARED_OFFSET_SD,
                "stable_ground": f"outside the outline grown by {STABLE_BUFFER_M} m",
                "gp": "TerrainGP(seed=seed) default constructor (kernel='auto', exact)",
            },
        }
        cols = [
            ("method", "method", ""),
            ("n", "n", "d"),
            ("median_sigma_m3", "med sigma m3", ".0f"),
        ]
        cols += [("rms_error_m3", "rms err m3", ".0f"), ("z_mean", "z mean", "+.2f")]
        cols += [("z_spread", "z spread", ".2f"), ("coverage_95", "in 95%", ".2f")]
        print(table(summary, cols))
    if "chain-summary" in parts:  # recompute the summary of an earlier chain run (its --out)
        import json

        from _change_chain import summarize_chain

        payload = json.loads(args.out.read_text())
        block = payload["chain_monte_carlo"]
        block["summary"] = summarize_chain(block["pairs"])
        for r in block["summary"]:
            print(
                f"{r['method']:48s} {r['n']:3d} {r['median_sigma_m3']:8.0f} "
                f"{r['rms_error_m3']:8.0f} {r['z_mean']:+.2f} {r['z_spread']:.2f} "
                f"{r['coverage_95']:.2f}"
            )
    if "calib-pool" in parts:  # re-pool the epochs of an earlier calib run (its --out JSON)
        import json

        from _change_chain import pool_calibration

        payload = json.loads(args.out.read_text())
        block = payload["along_track_calibration"]
        block["pooled"] = pool_calibration(block["epochs"])
        print(block["pooled"]["fit"])
    if "calib" in parts:
        from _change_chain import LAG_EDGES_S, calib_epoch, pool_calibration
        from threadpoolctl import threadpool_limits

        epochs: list[dict] = []
        block = {"epochs": epochs, "lag_edges_s": LAG_EDGES_S.tolist(), "control": CONTROL}
        payload["along_track_calibration"] = block
        with threadpool_limits(1):
            for seed in range(args.calib_seed0, args.calib_seed0 + args.calib_surveys):
                epochs.append(calib_epoch(seed, control=not args.no_control))
                e = epochs[-1]
                print(
                    f"calib survey {seed}: n {e['n']}, nees {e['nees']:.2f}, "
                    f"offset {e['offset_realised_m']:+.3f} m ({e['seconds']:.1f} s)",
                    flush=True,
                )
                write_json(args.out, payload)
        block["pooled"] = pool_calibration(epochs)
        print(block["pooled"]["fit"])
        pooled = block["pooled"]
        for lag, c, n in zip(pooled["lag_s"], pooled["corr"], pooled["pairs"], strict=True):
            print(f"  lag {lag:8.1f} s  corr {c:+.3f}  pairs {n:.0f}")
    if "chain" in parts:
        from _change_chain import CHAIN_BOUNDS, CHAIN_SWATHS, chain_pair, summarize_chain
        from threadpoolctl import threadpool_limits

        pairs, failures = [], []
        block = {
            "pairs": pairs,
            "failures": failures,
            "settings": {
                "site": "terrain.default_site(2.0); plan and outline on the square "
                f"{CHAIN_BOUNDS} (terrain.default_outline of it)",
                "plan": f"survey.lawnmower {CHAIN_SWATHS} swaths, margin 10 m (both epochs)",
                "chain": "factorgraph.simulate_traverse (default sensors, seed 2k / 2k+1) -> "
                "toolkit.stages.localize_stage -> select_stage -> reconstruct_stage (75 m "
                "simulated prior DEM as the mean)",
                "control": "none" if args.no_control else f"{CONTROL} (2 cm)",
                "grid_resolution_m": MC_RESOLUTION,
            },
        }
        payload["chain_monte_carlo"] = block
        with threadpool_limits(1):
            for seed in range(args.chain_seed0, args.chain_seed0 + args.chain_pairs):
                try:
                    pairs.append(chain_pair(seed, control=not args.no_control))
                except Exception as exc:  # noqa: BLE001 - a failed pair is counted, not fatal
                    failures.append({"seed": seed, "error": f"{type(exc).__name__}: {exc}"})
                    print(f"chain pair {seed}: failed ({failures[-1]['error']})", flush=True)
                    continue
                p = pairs[-1]
                z = (p["volume_m3"] - p["true_volume_m3"]) / p["sigma_glacimap_m3"]
                print(f"chain pair {seed}: z {z:+.2f}  ({p['seconds']:.1f} s)", flush=True)
                block["summary"] = summarize_chain(pairs)
                write_json(args.out, payload)  # after every pair: a cut-short run keeps them
        cols = [("method", "method", ""), ("n", "n", "d")]
        cols += [("median_sigma_m3", "med sigma m3", ".0f"), ("rms_error_m3", "rms err m3", ".0f")]
        cols += [("z_mean", "z mean", "+.2f"), ("z_spread", "z spread", ".2f")]
        cols += [("coverage_95", "in 95%", ".2f")]
        if pairs:
            print(table(block["summary"], cols))
        print(f"{len(pairs)} pairs, {len(failures)} failed")
    if "speed" in parts:
        payload["speed"] = speed_part()
        print(payload["speed"])
    write_json(args.out, payload)


if __name__ == "__main__":
    main()
