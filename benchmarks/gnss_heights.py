"""A GNSS survey in two height datums over real ground: the map, its 1-sigma and its time.

    python benchmarks/gnss_heights.py            # table + benchmarks/results/gnss_heights.json

The walk of session 44 (docs/field-format.md "Which surface the heights are above"), as files
a field team brings home: olinda's real DEM (``scripts/real_dems.py``) read as heights above
EGM96 over a 3 km square, 10 north-south lines 300 m apart, a fix every 5 m, antenna 1.8 m;
day 1 an RTKLIB ``.pos`` of RTK fixes in ellipsoidal heights (2 cm), day 2 a GPX in the
logger's sea-level heights (5 cm); a 90 m SRTM-like prior with 1.5 m of noise per cell in
``EPSG:32725+5773`` (UTM 25S + EGM96 height); 60 GNSS checkpoints as ``lon, lat, h`` with
``crs = EPSG:4979``. Each row runs ``glacimap reconstruct day1.pos day2.gpx --antenna-height
1.8 --checkpoints ... --resolution 20`` with:

``auto``            the GPX read as above EGM96 (the default), the prior as the mean;
``ellipsoidal``     ``--gnss-heights ellipsoidal`` (how 0.42.0 read every GPX);
``no_prior``        no ``--prior``;
``prior_as_data``   ``--prior-as data``;
``prior_as_auto``   ``--prior-as auto`` (the reading the held-out fixes map better:
                    ``terrain.dem_choice``).

Columns: RMSE against the truth (carried to the ellipsoid) and Delaunay's on its hull, the
truth in the 68 / 95 % intervals, the held-out check, the checkpoints' RMSE and bias, wall
seconds. Seeded (44); the real DEM comes from Debian's packages (skipped, with the reason,
when they cannot be fetched).
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent / "scripts"))
from _harness import real_dems_or_skip, table, write_json  # noqa: E402

CASES = {
    "auto": ["--prior", "{prior}"],
    "ellipsoidal": ["--prior", "{prior}", "--gnss-heights", "ellipsoidal"],
    "no_prior": [],
    "prior_as_data": ["--prior", "{prior}", "--prior-as", "data"],
    "prior_as_auto": ["--prior", "{prior}", "--prior-as", "auto"],
}
MAP_CRS = "EPSG:32725"  # olinda's UTM zone (WGS 84); the DEM's own is GRS 80, the same to mm


def _pos(path: Path, lon, lat, h, t0) -> None:
    head = [
        "% program   : RTKLIB ver.2.4.3",
        "% (lat/lon/height=WGS84/ellipsoidal,Q=1:fix,2:float,3:sbas,4:dgps,5:single,6:ppp)",
        "%  GPST                  latitude(deg) longitude(deg)  height(m)   Q  ns   sdn(m)   "
        "sde(m)   sdu(m)  sdne(m)  sdeu(m)  sdun(m) age(s)  ratio",
    ]
    rows = [
        f"{t0 + dt.timedelta(seconds=k + 18):%Y/%m/%d %H:%M:%S}.000 {lat[k]:14.9f} "
        f"{lon[k]:14.9f} {h[k]:10.4f}   1  12   0.0100   0.0100   0.0200   0.0000   0.0000"
        "   0.0000   1.00   50.0"
        for k in range(len(h))
    ]
    path.write_text("\n".join(head + rows) + "\n")


def _gpx(path: Path, lon, lat, ele, t0) -> None:
    import gpxpy.gpx

    doc = gpxpy.gpx.GPX()
    trk, seg = gpxpy.gpx.GPXTrack(), gpxpy.gpx.GPXTrackSegment()
    doc.tracks.append(trk)
    trk.segments.append(seg)
    for k in range(len(ele)):
        p = gpxpy.gpx.GPXTrackPoint(
            lat[k], lon[k], elevation=round(float(ele[k]), 3), time=t0 + dt.timedelta(seconds=k)
        )
        p.type_of_gpx_fix, p.horizontal_dilution, p.vertical_dilution = "dgps", 0.8, 0.1
        seg.points.append(p)
    path.write_text(doc.to_xml())


def make_survey(folder: Path, seed: int = 44) -> dict[str, Any]:
    """The walk's files in ``folder``; returns their paths and the truth (EGM96 heights)."""
    import pandas as pd
    import rasterio
    import real_dems
    from pyproj import Transformer
    from rasterio.transform import from_origin

    from terrain import Grid
    from terrain.vertical_datum import geoid_height

    dem = real_dems.load("olinda")
    w, s, e, n = Grid.from_dataarray(dem).bounds
    west, south = (w + e) / 2 - 1500, (s + n) / 2 - 1500
    truth = dem.interp(
        x=west + 5 + 10 * np.arange(300), y=south + 2995 - 10 * np.arange(300), method="linear"
    )
    rng = np.random.default_rng(seed)
    to_ll = Transformer.from_crs(MAP_CRS, "EPSG:4326", always_xy=True)

    def above_egm96(px, py):
        return truth.interp(x=("p", px), y=("p", py), method="linear").values

    y = np.arange(south + 20, south + 2980, 5.0)
    lines = [
        np.column_stack([np.full(y.size, x), y]) for x in np.arange(west + 150, west + 3000, 300)
    ]
    lines = [ln if k % 2 == 0 else ln[::-1] for k, ln in enumerate(lines)]
    xy = np.vstack(lines)
    half = len(xy) // 2
    t0 = dt.datetime(2026, 7, 1, 9, 0, tzinfo=dt.UTC)
    lon, lat = to_ll.transform(xy[:, 0], xy[:, 1])
    h = above_egm96(*xy.T) + geoid_height(lon, lat) + 1.8  # the antenna's ellipsoidal height
    _pos(folder / "day1.pos", lon[:half], lat[:half], h[:half] + rng.normal(0, 0.02, half), t0)
    sea = above_egm96(*xy[half:].T) + 1.8 + rng.normal(0, 0.05, len(xy) - half)
    _gpx(folder / "day2.gpx", lon[half:], lat[half:], sea, t0 + dt.timedelta(days=1))
    cx = west - 500 + 45 + 90 * np.arange(45)
    cy = south + 3500 - 45 - 90 * np.arange(45)
    prior = dem.interp(x=cx, y=cy, method="linear").values + rng.normal(0, 1.5, (45, 45))
    corner = from_origin(west - 500, south + 3500, 90, 90)
    with rasterio.open(
        folder / "srtm.tif", "w", driver="GTiff", height=45, width=45, count=1,
        dtype="float32", crs=f"{MAP_CRS}+5773", transform=corner,
    ) as dst:  # fmt: skip
        dst.write(prior.astype("float32"), 1)
    cp = np.column_stack(
        [rng.uniform(west + 50, west + 2950, 60), rng.uniform(south + 50, south + 2950, 60)]
    )
    clon, clat = to_ll.transform(cp[:, 0], cp[:, 1])
    ch = above_egm96(*cp.T) + geoid_height(clon, clat) + rng.normal(0, 0.02, 60)
    pd.DataFrame({"lon": clon, "lat": clat, "h": ch, "z_std": 0.02, "crs": "EPSG:4979"}).to_csv(
        folder / "checkpoints.csv", index=False
    )
    return {"truth": truth, "prior": folder / "srtm.tif", "n_fixes": len(xy)}


def evaluate(out: Path, truth: Any) -> dict[str, Any]:
    """The map in ``out`` against the truth carried to the ellipsoid, and Delaunay's."""
    import xarray as xr

    from terrain import Grid, delaunay_linear
    from terrain.vertical_datum import lattice_geoid_height
    from toolkit.samples_io import read_samples

    ds = xr.open_dataset(out / "product.nc")
    g = Grid.from_dataarray(ds["elevation"].assign_attrs(ds.attrs))
    t = truth.interp(x=g.x, y=g.y).values + lattice_geoid_height(g.x, g.y, g.crs, "egm96")
    e = ds["elevation"].values - t
    s = ds["elevation_std"].values
    d = delaunay_linear(read_samples(out / "samples.csv").samples, g).elevation.values - t
    ok, hull = np.isfinite(t), np.isfinite(t) & np.isfinite(d)
    cert = json.loads((out / "certificate.json").read_text())
    held = cert["heldout_calibration"]  # the certificate's block: pooled values at its top
    rmse = float(np.sqrt(np.mean(e[hull] ** 2)))
    return {
        "rmse_m": float(np.sqrt(np.mean(e[ok] ** 2))),
        "x_delaunay": rmse / float(np.sqrt(np.mean(d[hull] ** 2))),
        "truth_68": float(np.mean(np.abs(e[ok]) < s[ok])),
        "truth_95": float(np.mean(np.abs(e[ok]) < 1.96 * s[ok])),
        "heldout_68": held.get("map_coverage_68"),
        "heldout_95": held.get("map_coverage_95"),
        "checkpoints_rmse_m": cert["accuracy"]["rmse_m"],
        "checkpoints_bias_m": cert["accuracy"]["bias_m"],
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    ap.add_argument("--out", type=Path, default=HERE / "results" / "gnss_heights.json")
    args = ap.parse_args(argv)
    from typer.testing import CliRunner

    from toolkit.cli import app

    if not real_dems_or_skip(args.out, "gnss_heights"):
        return 0
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        made = make_survey(folder)
        for name in args.cases:
            extra = [a.format(prior=made["prior"]) for a in CASES[name]]
            out = folder / name
            cmd = ["reconstruct", str(folder / "day1.pos"), str(folder / "day2.gpx"),
                   "--antenna-height", "1.8", "--checkpoints", str(folder / "checkpoints.csv"),
                   "--resolution", "20", "--crs", MAP_CRS, "--out", str(out), *extra]  # fmt: skip
            t0 = time.perf_counter()
            res = CliRunner().invoke(app, cmd)
            seconds = time.perf_counter() - t0
            if res.exit_code != 0:
                raise SystemExit(f"{name}: exit {res.exit_code}\n{res.output}")
            rows.append({"case": name, "seconds": seconds, **evaluate(out, made["truth"])})
            with xr.open_dataset(out / "product.nc") as ds:  # --prior-as auto: its choice
                chosen = ds.attrs.get("prior_reading")
            rows[-1]["reading"] = json.loads(chosen)["choice"] if chosen else ""
    print(
        table(
            rows,
            [
                ("case", "case", ""),
                ("rmse_m", "RMSE m", ".3f"),
                ("x_delaunay", "x Delaunay", ".3f"),
                ("truth_68", "truth 68", ".3f"),
                ("truth_95", "truth 95", ".3f"),
                ("heldout_68", "held-out 68", ".3f"),
                ("heldout_95", "held-out 95", ".3f"),
                ("checkpoints_rmse_m", "cp RMSE m", ".3f"),
                ("checkpoints_bias_m", "cp bias m", "+.3f"),
                ("seconds", "s", ".1f"),
                ("reading", "auto read", ""),
            ],
        )
    )
    write_json(args.out, {"benchmark": "gnss_heights", "n_fixes": made["n_fixes"], "results": rows})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
