"""``glacimap change``: two epochs in, dh COG + volume tables + HTML report out.

Inputs are made here: the default site (before) and its seeded second epoch (after, known
change), shifted 2 m east and +0.4 m to exercise the co-registration, with independent
noise; the true volume change is the sum of the known change over the outline's cells.
Outputs are read back with rasterio, json and csv.
"""

from __future__ import annotations

import csv
import json

import numpy as np
import pyogrio
import pytest
import rasterio
import shapely
from shapely.geometry import box
from typer.testing import CliRunner

from terrain import Grid, InputError, default_outline, default_site, surface_change
from terrain.product import terrain_dataset
from terrain.synthetic import DEFAULT_SITE_BOUNDS
from terrain.volume import outline_weights
from toolkit.cli import app
from toolkit.export import write_cog

runner = CliRunner()


def _write_polygon(path, geom, crs="EPSG:32608"):
    pyogrio.raw.write(
        path, np.array([shapely.to_wkb(geom)], dtype=object), [], [], geometry_type="Polygon",
        crs=crs,
    )  # fmt: skip
    return path


@pytest.fixture(scope="module")
def epochs(tmp_path_factory):
    d = tmp_path_factory.mktemp("epochs")
    truth = default_site(resolution=2.0)
    outline = default_outline(DEFAULT_SITE_BOUNDS)
    change = surface_change(truth, outline, seed=7)
    g = Grid.from_dataarray(truth)
    rng = np.random.default_rng(0)
    z0 = truth.values + rng.normal(0, 0.05, g.shape)
    after = truth.values + change.values
    # the later DEM is displaced 2 m east (one cell) and +0.4 m
    shifted = np.full(g.shape, np.nan)
    shifted[:, 1:] = after[:, :-1] + 0.4
    shifted += rng.normal(0, 0.05, g.shape)
    std = np.full(g.shape, 0.05)
    b = terrain_dataset(g, z0, std, {"seed": 1, "epoch": "before"})
    a = terrain_dataset(g, shifted, std, {"seed": 2, "epoch": "after"})
    b.to_netcdf(d / "before.nc", engine="scipy")
    write_cog(a, d / "after.tif")  # the NaN column is nodata
    true_v = float(np.sum(outline_weights(g, outline) * change.values))
    return d, outline, true_v


def test_change_writes_products(epochs, tmp_path):
    d, outline, true_v = epochs
    gpkg = _write_polygon(tmp_path / "glacier.gpkg", outline)
    out = tmp_path / "out"
    res = runner.invoke(
        app, ["change", str(d / "before.nc"), str(d / "after.tif"), "--outline", str(gpkg),
              "--out", str(out)],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    vol = json.loads((out / "volume.json").read_text())
    assert vol["method"] == "variogram"
    assert vol["coregistration"]["shift_east_m"] == pytest.approx(2.0, abs=0.1)
    assert vol["coregistration"]["vertical_bias_m"] == pytest.approx(0.4, abs=0.03)
    # the known change, within 3 sigma and within 2 % (thinning of ~1.7 m over ~8 ha)
    assert abs(vol["volume_m3"] - true_v) < max(3 * vol["volume_std_m3"], 0.02 * abs(true_v))
    assert vol["mass_kg"] == pytest.approx(850.0 * vol["volume_m3"])
    with rasterio.open(out / "dh.tif") as src:
        assert src.count == 2 and src.descriptions == ("dh", "dh_std")
        assert src.crs.to_epsg() == 32608
        dh = src.read(1)
    assert np.nanmin(dh) < -2.0 and abs(np.nanmedian(dh[:20, :20])) < 0.05  # stable corner
    rows = list(csv.DictReader((out / "volume.csv").open()))
    assert rows[0]["quantity"] == "volume_change"
    assert float(rows[0]["value"]) == pytest.approx(vol["volume_m3"])
    html = (out / "change_report.html").read_text()
    for key in ('id="budget"', 'id="fig-dh"', 'id="fig-dh_std"', 'id="fig-hypsometry"'):
        assert key in html
    hyps = vol["hypsometry"]
    assert len(hyps) >= 4 and all(np.isfinite(r["mean_dh"]) for r in hyps)
    assert hyps[0]["mean_dh"] < hyps[-1]["mean_dh"]  # thinning is strongest low down
    assert not list(out.glob(".*"))  # no staging leftovers


@pytest.mark.parametrize(
    "case, match",
    [
        ("density", "density"),
        ("outline_outside", "outline"),
        ("stable_tiny", "MIN_STABLE_CELLS"),
        ("no_overlap", "overlap"),
    ],
)
def test_bad_input_writes_nothing(epochs, tmp_path, case, match):
    d, outline, _ = epochs
    gpkg = _write_polygon(tmp_path / "glacier.gpkg", outline)
    args = ["change", str(d / "before.nc"), str(d / "after.tif"), "--outline", str(gpkg)]
    if case == "density":
        args += ["--density", "0"]
    elif case == "outline_outside":
        far = box(0, 0, 100, 100)
        args[4] = str(_write_polygon(tmp_path / "far.gpkg", far))
        args += ["--no-coregister"]
    elif case == "stable_tiny":
        w, s = DEFAULT_SITE_BOUNDS[:2]
        args += ["--stable", str(_write_polygon(tmp_path / "s.gpkg", box(w, s, w + 20, s + 20)))]
    else:
        g = Grid.from_bounds((0, 0, 100, 100), 2.0)
        far = terrain_dataset(g, np.zeros(g.shape), np.ones(g.shape), {})
        far.to_netcdf(tmp_path / "far.nc", engine="scipy")
        args[2] = str(tmp_path / "far.nc")
    out = tmp_path / "out"
    res = runner.invoke(app, [*args, "--out", str(out)])
    assert res.exit_code != 0
    assert match in str(res.exception)
    assert not out.exists() or not any(out.iterdir())


def test_write_cog_named_bands_round_trip(tmp_path):
    """``write_cog(bands=...)`` (what the change COG uses): the named variables come back
    from GDAL as the bands, in order, NaN as nodata, attrs as tags, a y-ascending dataset
    written north-up; a missing variable is an InputError naming it."""
    import xarray as xr

    from terrain.errors import InputError

    g = Grid.from_bounds((0.0, 0.0, 64.0, 48.0), 2.0, "EPSG:32608")
    rng = np.random.default_rng(3)
    dh, sd = rng.normal(size=g.shape), rng.uniform(0.1, 0.2, g.shape)
    dh[0, 0] = np.nan
    ds = xr.Dataset(
        {"dh": (("y", "x"), dh), "dh_std": (("y", "x"), sd)},
        coords=g.coords(),
        attrs={**g.attrs(), "method": "test", "seed": 3},
    )
    path = write_cog(ds.sortby("y"), tmp_path / "c.tif", bands=[("dh_std", "s"), ("dh", "d")])
    with rasterio.open(path) as src:
        assert src.descriptions == ("dh_std", "dh")
        assert src.transform.e < 0 and src.crs.to_epsg() == 32608
        np.testing.assert_array_equal(src.read(1), sd.astype(np.float32))
        got = src.read(2)
        assert np.isnan(got[0, 0])
        np.testing.assert_array_equal(got[1:], dh[1:].astype(np.float32))
        assert src.tags()["method"] == "test" and src.tags()["seed"] == "3"
        assert src.overviews(1) == [2]  # 24 x 32 cells: 12 >= 8 pixels at 2, 6 < 8 at 4
    with pytest.raises(InputError, match="elevation"):
        write_cog(ds, tmp_path / "d.tif", bands=[("elevation", "x")])


def test_a_dem_in_geoid_heights_is_carried_to_the_maps_datum(tmp_path):
    # BEFORE: a glacimap map (ellipsoidal heights, said by its vertical_datum). AFTER: the
    # same ground, unchanged, as a GeoTIFF in EGM96 heights (H = h - N, N ~ +3.4 m here),
    # its compound CRS saying so. Without co-registration a change that ignored the datum
    # reads ~ -3.4 m of thinning; carried to the ellipsoid it reads ~0.
    from terrain.vertical_datum import lattice_geoid_height

    truth = default_site(resolution=10.0)
    g = Grid.from_dataarray(truth)
    n = lattice_geoid_height(g.x, g.y, g.crs, "egm96")
    assert 3.0 < n.mean() < 4.0
    std = np.full(g.shape, 0.05)
    terrain_dataset(g, truth.values, std, {"seed": 1}).to_netcdf(tmp_path / "b.nc", engine="scipy")
    profile = dict(driver="GTiff", height=g.ny, width=g.nx, count=1, dtype="float64",
                   transform=g.transform)  # fmt: skip
    for name, crs in (("a96.tif", "EPSG:32608+5773"), ("a.tif", "EPSG:32608")):
        with rasterio.open(tmp_path / name, "w", crs=crs, **profile) as dst:
            dst.write(truth.values - n, 1)
    gpkg = _write_polygon(tmp_path / "glacier.gpkg", default_outline(DEFAULT_SITE_BOUNDS))

    def change(after, *extra):
        out = tmp_path / f"out_{after}_{len(extra)}"
        res = runner.invoke(app, ["change", str(tmp_path / "b.nc"), str(tmp_path / after),
                                  "--outline", str(gpkg), "--no-coregister", "--out", str(out),
                                  *extra])  # fmt: skip
        return res, out

    res, out = change("a96.tif")
    assert res.exit_code == 0, res.output
    vol = json.loads((out / "volume.json").read_text())
    assert abs(vol["mean_dh_m"]) < 0.01  # h = H + N: the geoid's shift gone
    assert any("above EGM96 carried to BEFORE's (the WGS 84 ellipsoid)" in t for t in vol["notes"])
    res, out = change("a.tif")  # no datum stated: taken as BEFORE's, and said
    assert res.exit_code == 0, res.output
    vol = json.loads((out / "volume.json").read_text())
    assert vol["mean_dh_m"] == pytest.approx(-n.mean(), abs=0.05)
    assert any("AFTER states no vertical datum" in t for t in vol["notes"])
    res, out = change("a.tif", "--heights-after", "egm96")  # the user says it
    vol = json.loads((out / "volume.json").read_text())
    assert res.exit_code == 0 and abs(vol["mean_dh_m"]) < 0.01
    res, out = change("a96.tif", "--heights-after", "ellipsoidal")  # contradicts the file
    assert "--heights-after" in str(res.exception) and not out.exists()


def test_an_inventory_glacier_is_picked_and_an_outline_beyond_the_dems_refused(epochs, tmp_path):
    # An RGI-like inventory (GeoPackage, EPSG:4326, an RGIId per glacier): the site's glacier
    # and two others, one far away and one straddling the maps' east edge. Picked by its ID,
    # the volume is the same as from the glacier's own file; the whole inventory reaches far
    # beyond the DEMs: refused, nothing written; clipped on request, said with the area cut.
    import pyogrio
    from pyproj import Transformer

    d, outline, _ = epochs
    to_ll = Transformer.from_crs("EPSG:32608", "EPSG:4326", always_xy=True)
    w, s, e, n = DEFAULT_SITE_BOUNDS
    straddling = box(e - 100, s + 100, e + 200, s + 300)
    polys = [outline, box(w - 5000, s - 5000, w - 4000, s - 4000), straddling]
    ll = [shapely.transform(p, lambda xy: np.column_stack(to_ll.transform(*xy.T))) for p in polys]
    inventory = tmp_path / "rgi.gpkg"
    pyogrio.raw.write(
        inventory, np.array([shapely.to_wkb(p) for p in ll], dtype=object),
        [np.array(["RGI60-01.00001", "RGI60-01.00002", "RGI60-01.00003"], dtype=object)],
        ["RGIId"], geometry_type="Polygon", crs="EPSG:4326",
    )  # fmt: skip
    gpkg = _write_polygon(tmp_path / "glacier.gpkg", outline)
    base = ["change", str(d / "before.nc"), str(d / "after.tif"), "--no-coregister"]

    def change(name, *extra):
        out = tmp_path / name
        return runner.invoke(app, [*base, *extra, "--out", str(out)]), out

    res, out = change("own", "--outline", str(gpkg))
    assert res.exit_code == 0, res.output
    own = json.loads((out / "volume.json").read_text())
    res, out = change("picked", "--outline", str(inventory),
                      "--outline-where", "RGIId = 'RGI60-01.00001'")  # fmt: skip
    assert res.exit_code == 0, res.output
    picked = json.loads((out / "volume.json").read_text())
    assert picked["volume_m3"] == pytest.approx(own["volume_m3"], rel=1e-3)  # via degrees
    assert any("1 of 3 features: RGIId = 'RGI60-01.00001'" in t for t in picked["notes"])
    res, out = change("all", "--outline", str(inventory))
    assert isinstance(res.exception, InputError) and not out.exists()
    assert "beyond the change grid" in str(res.exception)
    assert "--clip-outline" in str(res.exception)
    res, out = change("none", "--outline", str(inventory), "--outline-where", "RGIId = 'x'")
    assert "selects features" in str(res.exception) and "RGIId" in str(res.exception)
    res, out = change("bad", "--outline", str(inventory), "--outline-where", "Name = 'x'")
    assert "OGR SQL WHERE" in str(res.exception) and not out.exists()
    res, out = change("clipped", "--outline", str(inventory), "--clip-outline",
                      "--outline-where", "RGIId != 'RGI60-01.00002'")  # fmt: skip
    assert res.exit_code == 0, res.output
    vol = json.loads((out / "volume.json").read_text())
    cut = 100 * 200 * 200 / (outline.area + straddling.area)  # the straddler's east 200 m
    note = next(t for t in vol["notes"] if "clipped" in t)
    assert f"({cut:.1f} %) cut" in note
    assert vol["area_m2"] > own["area_m2"]  # the straddler's covered part joins
    # one row per glacier of the whole inventory: the far one counted, the straddler's
    # covered part (2/3 of it), the volumes adding up to the clipped union's
    res, out = change("table", "--outline", str(inventory), "--clip-outline",
                      "--per-glacier", "RGIId")  # fmt: skip
    assert res.exit_code == 0, res.output
    vol = json.loads((out / "volume.json").read_text())
    rows = list(csv.DictReader((out / "glaciers.csv").open()))
    assert [r["id"] for r in rows] == ["RGI60-01.00001", "RGI60-01.00003"]
    assert vol["glaciers"]["note"] == "2 of 3 glaciers in the table; 1 beyond the DEMs"
    assert float(rows[0]["volume_m3"]) == pytest.approx(own["volume_m3"], rel=1e-6)
    assert float(rows[1]["covered_share"]) == pytest.approx(1 / 3, abs=1e-9)
    total = sum(float(r["volume_m3"]) for r in rows)
    assert total == pytest.approx(vol["volume_m3"], rel=1e-9)
    res, out = change("bad_id", "--outline", str(inventory), "--per-glacier", "rgi_id")
    assert "--outline attribute" in str(res.exception) and "RGIId" in str(res.exception)
