"""Heights on a geoid and on the ellipsoid (``terrain.vertical_datum``).

Reference values: NGA's EGM96 test points for the 15' geoid grid (latitude, east longitude,
N in metres, as GeographicLib's geoid documentation lists them). NGA interpolates the grid
its own way, PROJ bilinearly: they agree within 6 cm (measured: 0.3-5.6 cm).
"""

from __future__ import annotations

import numpy as np
import pytest

from terrain import InputError
from terrain import vertical_datum as vd

NGA_EGM96 = [  # lat, lon east, N (m)
    (38.6281550, 269.7791550, -31.628),
    (-14.6212170, 305.0211140, -2.969),
    (46.8743190, 102.4487290, -43.575),
    (-23.6174460, 133.8747120, 15.871),
    (38.6254730, 359.9995000, 50.066),
    (-0.4667440, 0.0023000, 17.329),
]


def test_egm96_undulation_matches_ngas_test_points():
    lat, lon, ref = np.array(NGA_EGM96).T
    lon = np.where(lon > 180.0, lon - 360.0, lon)
    np.testing.assert_allclose(vd.geoid_height(lon, lat, "egm96"), ref, atol=0.06)


def test_ellipsoidal_height_adds_the_undulation_and_nothing_for_the_ellipsoid():
    lon, lat, height = np.array([-135.3, 7.5]), np.array([58.4, 46.0]), np.array([1200.0, 3000.0])
    n = vd.geoid_height(lon, lat)
    np.testing.assert_allclose(vd.ellipsoidal_height(height, lon, lat, "EGM96"), height + n)
    np.testing.assert_array_equal(vd.ellipsoidal_height(height, lon, lat, "ellipsoidal"), height)


def test_bad_names_and_a_missing_grid_are_errors_that_say_the_fix(monkeypatch, tmp_path):
    with pytest.raises(InputError, match="--heights.*ellipsoidal / egm96 / egm2008.*'msl'"):
        vd.height_datum_option("msl", "--heights")
    assert vd.height_datum_option("Auto", "--heights", allow_auto=True) == "auto"
    with pytest.raises(InputError, match="a geoid"):
        vd.geoid_grid("ellipsoidal")
    monkeypatch.setattr(vd, "_search_dirs", lambda: [tmp_path])  # a machine without grids
    with pytest.raises(InputError, match=r"--gnss-heights.*egm96_15\.gtx.*proj-data"):
        vd.geoid_height([0.0], [0.0], "egm96", "--gnss-heights")
    with pytest.raises(InputError, match=r"us_nga_egm08_25\.tif.*cdn\.proj\.org"):
        vd.geoid_grid("egm2008")


def test_field_gps_heights_above_a_geoid_are_carried_to_the_ellipsoid():
    from factorgraph.field.fixes import GPSFixes, project_fixes

    lon, lat = np.array([-135.30, -135.29]), np.array([58.40, 58.41])
    fixes = GPSFixes(
        np.array([0.0, 1.0]), lat, lon, np.array([1200.0, 1201.0]), np.zeros((2, 3)),
        np.array(["single", "single"]),
    )  # fmt: skip
    ell = project_fixes(fixes, "EPSG:4979", "EPSG:32608")
    msl = project_fixes(fixes, "EPSG:4326+5773", "EPSG:32608")  # ele above EGM96
    np.testing.assert_allclose(msl[:, :2], ell[:, :2])
    np.testing.assert_allclose(msl[:, 2] - ell[:, 2], vd.geoid_height(lon, lat))
    with pytest.raises(InputError, match="gps crs.*NAVD88 height.*us_noaa_g2012ba0.tif.*projsync"):
        project_fixes(fixes, "EPSG:4326+5703", "EPSG:32608")  # NAVD88: its grid not here


def test_export_writes_the_map_above_egm96(tmp_path):
    # The default site as a glacimap map (ellipsoidal) exported above EGM96: the COG's
    # elevation is the map's less N at each cell (N by pyproj's CRS transform), its
    # 1-sigma band unchanged, its metadata saying so; a product back at its own datum is
    # itself; a bad name or a product without a datum: InputError, nothing written.
    import rasterio
    from pyproj import Transformer
    from typer.testing import CliRunner

    from terrain import Grid, default_site
    from terrain.product import terrain_dataset
    from toolkit.cli import app

    truth = default_site(resolution=20.0)
    g = Grid.from_dataarray(truth)
    ds = terrain_dataset(g, truth.values, np.full(g.shape, 0.3), {"seed": 3})
    nc = tmp_path / "product.nc"
    ds.to_netcdf(nc, engine="scipy")
    out = tmp_path / "out"
    r = CliRunner().invoke(app, ["export", str(nc), "--heights", "EGM96", "--no-mesh",
                                 "--interval", "5", "--out", str(out)])  # fmt: skip
    assert r.exit_code == 0, r.output
    assert "heights carried from the WGS 84 ellipsoid to EGM96" in " ".join(r.output.split())
    xx, yy = np.meshgrid(g.x, g.y)
    lon, lat = Transformer.from_crs(g.crs, "EPSG:4326", always_xy=True).transform(xx, yy)
    import pyproj.datadir

    pyproj.datadir.append_data_dir("/usr/share/proj")
    to_msl = Transformer.from_crs("EPSG:4979", "EPSG:4326+5773", always_xy=True)
    msl = np.asarray(to_msl.transform(lon, lat, truth.values)[2])  # H = h - N
    with rasterio.open(out / "elevation.tif") as src:
        np.testing.assert_allclose(src.read(1), msl, atol=1e-3)  # float32 band
        np.testing.assert_allclose(src.read(2), 0.3, atol=1e-6)
        assert "orthometric height above EGM96" in src.tags()["vertical_datum"]
    same, note = vd.product_in_datum(ds, "ellipsoidal")
    assert same is ds and "already" in note
    back, _ = vd.product_in_datum(vd.product_in_datum(ds, "egm96")[0], "ellipsoidal")
    np.testing.assert_allclose(back["elevation"].values, ds["elevation"].values, atol=1e-9)
    never = tmp_path / "never"
    r = CliRunner().invoke(app, ["export", str(nc), "--heights", "msl", "--out", str(never)])
    assert isinstance(r.exception, InputError) and not never.exists()
    bare = ds.copy()
    bare.attrs = {k: v for k, v in ds.attrs.items() if k != "vertical_datum"}
    with pytest.raises(InputError, match="--heights.*states its heights' datum"):
        vd.product_in_datum(bare, "egm96")


def test_a_map_from_a_csv_is_in_the_csvs_datum_and_says_so(tmp_path):
    # A CSV's z are taken as given: the map is in their datum. Without --samples-heights
    # the product says the datum is not stated (not the GPS ellipsoid: change and certify
    # would carry it as such); with it, the datum is named; a geoid with GNSS logs is refused.
    import pandas as pd
    from typer.testing import CliRunner

    from terrain.vertical_datum import dem_height_datum
    from toolkit.cli import app
    from toolkit.samples_io import samples_height_attrs

    rng = np.random.default_rng(0)
    xy = rng.uniform([500_000, 6_600_000], [500_300, 6_600_300], (300, 2))
    z = 1000 + 0.02 * (xy[:, 0] - 500_000) + rng.normal(0, 0.05, 300)
    csv = tmp_path / "s.csv"
    pd.DataFrame({"x": xy[:, 0], "y": xy[:, 1], "z": z, "crs": "EPSG:32608"}).to_csv(
        csv, index=False
    )
    import xarray as xr

    for extra, want in (([], None), (["--samples-heights", "egm96"], "egm96")):
        out = tmp_path / f"m{len(extra)}"
        r = CliRunner().invoke(app, ["reconstruct", str(csv), "--resolution", "20", "--out",
                                     str(out), *extra])  # fmt: skip
        assert r.exit_code == 0, r.output
        attrs = xr.open_dataset(out / "product.nc").attrs
        assert dem_height_datum(attrs) == want
    assert "not stated" in xr.open_dataset(tmp_path / "m0" / "product.nc").attrs["vertical_datum"]
    gpx = tmp_path / "t.gpx"
    gpx.write_text('<gpx version="1.1" creator="t"></gpx>')
    with pytest.raises(InputError, match="--samples-heights.*GNSS logs"):
        samples_height_attrs([gpx], "egm96")
    assert samples_height_attrs([gpx], None) == {}  # logs: the product's default, ellipsoidal
