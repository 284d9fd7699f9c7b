"""``glacimap reconstruct`` twice and ``glacimap change`` on a real DEM take the GP route.

A real survey's map is a tiled fit with more samples than its fit subset, and on most real
ground its kernel has Microscale parts; until session 31 either one made the rebuild of its
GP fail, and the change fell back to the variogram route (docs/change.md "maps of real
surveys rebuilt too"; here the subset's GLS: the maps were 2.0 and 7.0 mm off).
Ground: jacksboro (matplotlib ships it, so no download), a 600 m glacier-sized site; the
second epoch is the first lowered by a Gaussian bowl of 2 m depth and 150 m scale. The
reference volume is the bowl summed over the truth's own cells inside the outline.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import shapely
from _real_sites import real_site
from test_cli_change import _write_polygon
from typer.testing import CliRunner

from toolkit.cli import app

runner = CliRunner()
DEPTH_M, SCALE_M, HALF_SIDE_M = 2.0, 150.0, 200.0


def _write_samples(path, samples) -> None:
    zv = np.broadcast_to(np.asarray(samples.z_var, float), (samples.n,))
    with open(path, "w") as fh:
        fh.write("x,y,z,z_var,crs\n")
        for (x, y), z, v in zip(samples.xy, samples.z, zv, strict=True):
            fh.write(f"{x:.4f},{y:.4f},{z:.5f},{v:.6f},{samples.crs.to_string()}\n")


@pytest.mark.slow
def test_real_terrain_change_takes_the_gp_route_and_finds_the_volume(tmp_path):
    real_dems, truth = real_site("jacksboro")
    xs, ys = np.meshgrid(truth.x.values, truth.y.values)
    cx, cy = float(xs.mean()), float(ys.mean())
    bowl = DEPTH_M * np.exp(-((xs - cx) ** 2 + (ys - cy) ** 2) / SCALE_M**2)
    after = truth - bowl
    d = tmp_path
    _write_samples(d / "before.csv", real_dems.track_samples(truth, 3000, seed=0))
    _write_samples(d / "after.csv", real_dems.track_samples(after, 3000, seed=1))
    like = ["--like", str(d / "before" / "elevation.tif")]
    for epoch, grid in (("before", ["--resolution", "4"]), ("after", like)):
        r = runner.invoke(
            app, ["reconstruct", str(d / f"{epoch}.csv"), *grid, "--out", str(d / epoch)]
        )
        assert r.exit_code == 0, r.output
    box = shapely.box(cx - HALF_SIDE_M, cy - HALF_SIDE_M, cx + HALF_SIDE_M, cy + HALF_SIDE_M)
    outline = _write_polygon(d / "outline.gpkg", box)
    r = runner.invoke(
        app,
        ["change", str(d / "before"), str(d / "after"), "--outline", str(outline),
         "--samples-before", str(d / "before.csv"), "--samples-after", str(d / "after.csv"),
         "--out", str(d / "change")],
    )  # fmt: skip
    assert r.exit_code == 0, r.output
    vol = json.loads((d / "change" / "volume.json").read_text())
    assert vol["route"] == "gp_structure", vol["route_reason"]
    # Reference: the bowl summed over the truth's cells inside the outline (m^3).
    inside = (np.abs(xs - cx) <= HALF_SIDE_M) & (np.abs(ys - cy) <= HALF_SIDE_M)
    cell_m2 = abs(float(np.diff(truth.x.values[:2])[0]) * float(np.diff(truth.y.values[:2])[0]))
    true_dv = -float(bowl[inside].sum()) * cell_m2
    dv, sd = vol["volume_m3"], vol["volume_std_m3"]
    assert 0 < sd < 0.25 * abs(true_dv)
    assert abs(dv - true_dv) < 3 * sd, (dv, sd, true_dv)
