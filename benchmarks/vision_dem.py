"""A survey over a real DEM (``[site] kind = "dem"``), rendered and run through the image
chain against the ideal-track simulation of the same traverse (docs/vision.md, "A survey over
your own DEM").

    python benchmarks/vision_dem.py                                  # every DEM, both sites
    python benchmarks/vision_dem.py --dems olinda lux --sites coarse --size 240

DEMs: ``scripts/real_dems.py`` (``olinda`` UTM 25S 90 m, ``rm`` / ``prism`` lon/lat 2.5',
``lux`` lon/lat 30" with nodata, ``glacier`` 100 m local TM, matplotlib's ``jacksboro`` 3"
and ``topobathy`` 1' lon/lat). Each is written as a GeoTIFF in
its own CRS (nodata -9999) under ``--work`` and two sites are made from it:

``coarse``
    The DEM file itself as ``site.dem``; ``site.bounds`` a ``--size`` m square (site CRS:
    the DEM's, or the UTM zone of its centre for lon/lat) centred on the steepest valid spot
    of the DEM (largest 3 x 3 relief at the DEM's own cell): the coarse DEM cubic-resampled to
    2 m, the steepest terrain it offers a rover.
``site``
    ``real_dems.glacier_site(name)`` (a window of the DEM mapped onto the 600 m glacier-sized
    square at 2 m, 25 m relief) written as a GeoTIFF in EPSG:32608; ``site.bounds`` its
    south-west ``--size`` m part (as ``chain_sunny_part`` of benchmarks/vision.py), or
    omitted (the file's extent) when ``--size`` is 600. (``glacier_site(size_m=240)`` would
    squeeze the same 40 nodes into 240 m: median slopes of 28 deg on olinda, 67 deg at most.)

Everything else is the embedded default scenario (seed, sensors, vision camera preset,
sunny snow), except ``[plan] n_swaths`` (``--swaths``, 2: two swaths over a 240 m site, 281
keyframes). Per row (benchmarks/vision.py ``_chain_row``): landmarks in the graph and per
keyframe, landmark NEES, keyframe RMSE, map RMSE and 95 % coverage (the satellite-mean GP map
of ``glacimap run``), kept-track reprojection median (ground truth from the renderer), wall
time of render + track, localize and reconstruct. Results: ``--out`` (JSON).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
for p in (ROOT, ROOT / "benchmarks", ROOT / "scripts"):
    if str(p) not in sys.path:
        sys.path.insert(0, str(p))

from _harness import in_subprocess, table, write_json  # noqa: E402
from real_dems import NAMES  # noqa: E402

DEMS = NAMES  # every real DEM of scripts/real_dems.py
NODATA = -9999.0


def write_geotiff(da, path: Path) -> Path:
    """Write a north-up DataArray (dims y, x; regular cell centres; ``crs_wkt`` or a Grid's
    CRS attribute) as a float32 GeoTIFF with nodata -9999 (NaN cells)."""
    import rasterio
    from rasterio.transform import from_origin

    from terrain.grid import dataarray_crs

    x, y = np.asarray(da["x"].values, float), np.asarray(da["y"].values, float)
    dx, dy = float(x[1] - x[0]), float(y[0] - y[1])
    z = np.where(np.isfinite(da.values), da.values, NODATA).astype("float32")
    path.parent.mkdir(parents=True, exist_ok=True)
    part = path.with_suffix(".part.tif")
    with rasterio.open(
        part,
        "w",
        driver="GTiff",
        height=z.shape[0],
        width=z.shape[1],
        count=1,
        dtype="float32",
        crs=dataarray_crs(da).to_wkt(),
        transform=from_origin(x[0] - dx / 2, y[0] + dy / 2, dx, dy),
        nodata=NODATA,
    ) as ds:
        ds.write(z, 1)
    part.replace(path)
    return path


def steepest_window(dem_path: Path, size: float) -> list[float]:
    """``[w, s, e, n]`` of a ``size`` m square (site CRS as ``kind = "dem"`` resolves it)
    centred on the DEM's steepest valid spot, inside the DEM's valid data."""
    from toolkit.config import load_scenario
    from toolkit.pipeline import make_site
    from toolkit.site_dem import _cell_size_m, _open, _utm_of_centre

    src = _open(dem_path)
    res = _cell_size_m(src, src.crs if src.crs.is_projected else _utm_of_centre(src))
    probe = {"site": {"kind": "dem", "dem": str(dem_path), "truth_resolution_m": res}}
    site = make_site(load_scenario(None, probe))  # the DEM at its own cell, site CRS
    z = site.values
    from scipy.ndimage import maximum_filter, minimum_filter

    relief = maximum_filter(z, 3) - minimum_filter(z, 3)
    m = int(np.ceil(size / 2 / res)) + 2  # stay inside by half a window plus the kernel
    relief[:m], relief[-m:], relief[:, :m], relief[:, -m:] = -1, -1, -1, -1
    if relief.max() < 0:
        raise ValueError(f"{dem_path.name}: no {size} m window inside the DEM")
    i, j = np.unravel_index(np.argmax(relief), relief.shape)
    cx, cy = float(site.x[j]), float(site.y[i])
    h = size / 2
    return [round(cx - h), round(cy - h), round(cx - h) + size, round(cy - h) + size]


def site_configs(name: str, size: float, work: Path) -> dict[str, Path]:
    """Scenario TOML files (``coarse`` and ``site``, see the module docstring) for DEM
    ``name`` under ``work``; the GeoTIFFs beside them. Paths in the TOML are relative."""
    import real_dems

    work.mkdir(parents=True, exist_ok=True)
    raw = write_geotiff(real_dems.load(name), work / f"{name}.tif")
    bounds = steepest_window(raw, size)
    coarse = work / f"{name}_coarse_{size:g}.toml"
    coarse.write_text(
        f'[site]\nkind = "dem"\ndem = "{raw.name}"\nbounds = {bounds}\ntruth_resolution_m = 2.0\n'
    )
    tif = write_geotiff(real_dems.glacier_site(name), work / f"{name}_site_600.tif")
    site = work / f"{name}_site_{size:g}.toml"
    text = f'[site]\nkind = "dem"\ndem = "{tif.name}"\n'
    if size < 600.0:
        w, s = 500_000.0, 6_800_000.0  # glacier_site's south-west corner
        text += f"bounds = {[w, s, w + size, s + size]}\n"
    site.write_text(text)
    return {"coarse": coarse, "site": site}


def case_dem(config: str, swaths: int, scene: str, frames: str) -> dict[str, Any]:
    """Ideal tracks and rendered images (default front-end) over the site of ``config``."""
    import json

    from vision import _chain_row

    from factorgraph import SensorSuite
    from factorgraph.vision import SCENES, TrackParams, simulate_images, vision_sensors
    from toolkit.config import load_scenario
    from toolkit.pipeline import make_plan, make_truth

    scenario = load_scenario(config, {"plan": {"n_swaths": swaths}})
    truth = make_truth(scenario)
    plan = make_plan(scenario, truth)
    sensors = vision_sensors(SensorSuite.from_dict(scenario["sensors"]))
    seed = int(scenario["seed"])
    t0 = time.perf_counter()
    run = simulate_images(truth, plan, sensors, seed, SCENES[scene], TrackParams(), frames)
    chain_s = time.perf_counter() - t0
    rows = [_chain_row("ideal tracks", run.ideal, truth, scenario)]
    row = _chain_row(f"{scene} SIFT", run.log, truth, scenario)
    row.update(run.timings)
    e = run.reprojection_px[np.isfinite(run.reprojection_px) & (run.reprojection_px > 0)]
    row["err_median_px"], row["err_p95_px"] = float(np.median(e)), float(np.percentile(e, 95))
    row["render_track_s"] = chain_s
    row["filled_cells"] = int(getattr(run.renderer, "filled_cells", 0))
    rows.append(row)
    for r in rows:
        r["map_vs_ideal"] = r["map_rmse_m"] / rows[0]["map_rmse_m"]
    z = truth.values
    slope = np.degrees(np.arctan(np.hypot(*np.gradient(z, float(truth.x[1] - truth.x[0])))))
    return {
        "rows": rows,
        "config": config,
        "site": json.loads(truth.attrs["site_dem"]),
        "relief_m": float(np.ptp(z)),
        "max_slope_deg": float(slope.max()),
        "p95_slope_deg": float(np.percentile(slope, 95)),
        "keyframes": run.log.n_keyframes,
        "scene": scene,
        "seed": seed,
    }


def _guarded(*args: Any) -> dict[str, Any]:
    """:func:`case_dem`, with an exception returned (a dead child would hang the parent)."""
    import traceback

    try:
        return case_dem(*args)
    except Exception as exc:  # recorded in the results, never hidden
        return {"error": repr(exc), "traceback": traceback.format_exc(), "rows": []}


COLS = [
    ("case", "case", ""),
    ("landmarks_in_graph", "in graph", "d"),
    ("graph_landmarks_per_keyframe", "lm/kf", ".1f"),
    ("err_median_px", "err med px", ".2f"),
    ("landmark_nees", "NEES", ".2f"),
    ("landmark_in_2sigma", "in 2sig", ".3f"),
    ("horizontal_rmse_m", "horiz m", ".2f"),
    ("gps_only_horizontal_rmse_m", "GPS-only m", ".2f"),
    ("map_rmse_m", "map RMSE", ".3f"),
    ("map_vs_ideal", "x ideal", ".2f"),
    ("map_coverage_95", "cov95", ".3f"),
    ("render_track_s", "render+track s", ".0f"),
    ("localize_s", "localize s", ".0f"),
]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--dems", nargs="+", default=list(DEMS), choices=DEMS)
    ap.add_argument("--sites", nargs="+", default=["coarse", "site"], choices=["coarse", "site"])
    ap.add_argument("--size", type=float, default=240.0, help="site side (m)")
    ap.add_argument("--swaths", type=int, default=2)
    ap.add_argument("--scene", default="sunny_snow")
    ap.add_argument("--work", type=Path, default=Path("out/bench_vision_dem"))
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/vision_dem.json"))
    args = ap.parse_args()
    import json

    results: dict[str, Any] = {}
    if args.out.exists():
        results = json.loads(args.out.read_text()).get("cases", {})
    for name in args.dems:
        configs = site_configs(name, args.size, args.work)
        for kind in args.sites:
            key = f"{name}_{kind}_{args.size:g}"
            t0 = time.perf_counter()
            frames = str(args.work / f"frames_{key}")
            res = in_subprocess(_guarded, str(configs[kind]), args.swaths, args.scene, frames)
            if "error" in res:  # a crash is a result too: recorded, and the next case runs
                print(f"\n{key}: FAILED {res['error']}", flush=True)
                results[key] = res
                write_json(args.out, {"cases": results, "command": " ".join(sys.argv)})
                continue
            res["case_wall_s"] = time.perf_counter() - t0
            print(
                f"\n{key}: {res['keyframes']} keyframes, relief {res['relief_m']:.1f} m, "
                f"slope max {res['max_slope_deg']:.1f} deg (p95 {res['p95_slope_deg']:.1f}), "
                f"site CRS {res['site']['site_crs']} ({res['site']['site_crs_from']}), "
                f"nodata filled {res['site']['nodata_cells_filled']}, "
                f"wall {res['case_wall_s']:.0f} s"
            )
            print(table(res["rows"], COLS), flush=True)
            results[key] = res
            write_json(args.out, {"cases": results, "command": " ".join(sys.argv)})


if __name__ == "__main__":
    main()
