"""Survey points exported by Emlid Flow / ReachView 3 (``factorgraph.field.controller_csv``).

The header is Emlid Flow's survey export as published (Name, Code, ..., CS name); the rows are
made here: positions on a UTM 33N site (Svalbard's latitude band), the geographic pair from
pyproj's own transform, heights in metres or, on a US state plane in ftUS, in US survey feet
as the app writes them there (a real Emlid row on such a plane: ellipsoidal height 461.923
ft at 40.72 N, -89.67 E). Reference values: the rows' own numbers, converted by the exact
US survey foot (1200 / 3937 m).
"""

from __future__ import annotations

import numpy as np
import pytest
import rasterio
from _rasters import write_array
from pyproj import CRS, Transformer
from rasterio.transform import from_origin
from typer.testing import CliRunner

from terrain import InputError
from toolkit.certify import certify
from toolkit.certify_io import read_checkpoints
from toolkit.cli import app
from toolkit.samples_io import read_sample_files, samples_height_attrs

HEADER = (
    "Name,Code,Code description,Easting,Northing,Elevation,Description,Longitude,Latitude,"
    "Ellipsoidal height,Origin,Tilt angle,Easting RMS,Northing RMS,Elevation RMS,Lateral RMS,"
    "Antenna height,Antenna height units,Solution status,Correction type,Averaging start,"
    "Averaging end,Samples,PDOP,GDOP,Base easting,Base northing,Base elevation,Base longitude,"
    "Base latitude,Base ellipsoidal height,Baseline,Mount point,CS name"
)
US_FT = 1200.0 / 3937.0


def emlid_csv(path, e, n, h, rms, status, cs="WGS 84 / UTM zone 33N", epsg="EPSG:32633", unit=1.0):
    """An Emlid Flow export of points ``e, n`` (in ``cs``'s unit) with ellipsoidal heights
    ``h`` and RMS ``rms`` (m, written in ``cs``'s unit)."""
    lon, lat = Transformer.from_crs(epsg, "EPSG:4326", always_xy=True).transform(e, n)
    lines = [HEADER]
    for i in range(len(e)):
        cells = [
            f"P{i}", "", "", f"{e[i]:.3f}", f"{n[i]:.3f}", f"{h[i] / unit:.3f}", "",
            f"{lon[i]:.9f}", f"{lat[i]:.9f}", f"{h[i] / unit:.3f}", "Global", "",
            f"{0.01 / unit:.3f}", f"{0.01 / unit:.3f}", f"{rms[i] / unit:.3f}", "0.014",
            "1.800", "m", status[i], "RTK", "2026-07-01 10:00:00.0 UTC+00:00",
            "2026-07-01 10:00:05.0 UTC+00:00", "5", "1.2", "1.9", "510000.000", "8700000.000",
            "40.000", "15.3", "78.3", "40.000", "1.5", "NEAR", cs,
        ]  # fmt: skip
        lines.append(",".join(cells))
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture()
def svalbard(tmp_path):
    rng = np.random.default_rng(3)
    e = rng.uniform(500000, 501000, 40)
    n = rng.uniform(8700000, 8701000, 40)
    h = 200.0 + 0.02 * (e - 500000) + rng.normal(0, 0.05, 40)
    rms = np.where(np.arange(40) < 36, 0.012, 0.150)
    status = np.where(np.arange(40) < 36, "FIX", "FLOAT")
    return emlid_csv(tmp_path / "points.csv", e, n, h, rms, status), e, n, h, rms


def test_an_emlid_export_reads_its_projected_pair_and_ellipsoidal_heights(svalbard):
    path, e, n, h, rms = svalbard
    cps = read_checkpoints(path)
    np.testing.assert_allclose(cps.xy, np.column_stack([e, n]), atol=5e-4)  # 3 decimals
    np.testing.assert_allclose(cps.z, h, atol=5e-4)
    np.testing.assert_allclose(cps.z_std, rms, atol=5e-4)
    assert cps.crs.to_epsg() == 32633 and cps.height_datum == "ellipsoidal"
    assert cps.columns["z"] == "Ellipsoidal height" and cps.columns["z_std"] == "Elevation RMS"
    assert "solution status 36 FIX, 4 FLOAT (all kept" in cps.note
    assert "Elevation" not in cps.ignored_columns and "Name" in cps.ignored_columns
    table = read_sample_files([path])  # the map's route: no --crs needed, RMS as noise
    np.testing.assert_allclose(table.samples.z_var, np.round(rms, 3) ** 2, rtol=1e-9)
    assert "Emlid Flow export" in table.note
    assert samples_height_attrs([path], None)["height_datum"] == "ellipsoidal"
    with pytest.raises(InputError, match="--samples-heights.*Ellipsoidal height column"):
        samples_height_attrs([path], "egm96")


def test_a_state_plane_in_us_feet_is_read_in_metres_from_longitude_latitude(tmp_path):
    # NAD83(2011) / Illinois West (ftUS), EPSG:6457: the app writes feet; the map's CRS
    # cannot be in feet, so the geographic pair is read (then projected to UTM by the map).
    e = np.array([2434191.346, 2434291.346, 2434391.346])
    n = np.array([1475350.261, 1475450.261, 1475380.261])
    h = np.array([461.923, 462.5, 463.1]) * US_FT
    path = emlid_csv(
        tmp_path / "il.csv", e, n, h, np.full(3, 0.038 * US_FT), ["FIX"] * 3,
        cs="NAD83(2011) / Illinois West (ftUS)", epsg="EPSG:6457", unit=US_FT,
    )  # fmt: skip
    cps = read_checkpoints(path)
    assert cps.crs.to_epsg() == 4326 and cps.columns["x"] == "Longitude"
    np.testing.assert_allclose(cps.z, h, atol=1e-3)  # 3 decimals of a foot
    np.testing.assert_allclose(cps.z_std, 0.038 * US_FT, atol=1e-3)
    assert "converted to metres" in cps.note


def test_a_coordinate_system_pyproj_does_not_know_or_two_of_them_are_refused(tmp_path):
    e, n = np.array([500000.0, 500100.0]), np.array([8700000.0, 8700100.0])
    path = emlid_csv(tmp_path / "a.csv", e, n, np.full(2, 100.0), np.full(2, 0.01), ["FIX"] * 2,
                     cs="My site grid")  # fmt: skip
    with pytest.raises(InputError, match="'CS name'.*a coordinate system pyproj knows"):
        read_checkpoints(path)
    text = path.read_text().replace("My site grid\n", "WGS 84 / UTM zone 33N\n", 1)
    (tmp_path / "b.csv").write_text(text.replace("My site grid", "WGS 84 / UTM zone 32N"))
    with pytest.raises(InputError, match="one coordinate system for every point"):
        read_checkpoints(tmp_path / "b.csv")


def test_a_dem_in_egm96_is_certified_against_an_emlid_export(svalbard, tmp_path):
    # The DEM states EGM96 (compound CRS), the export ellipsoidal heights: certify carries
    # the checkpoints to the DEM's datum without being told.
    import pyproj.datadir

    pyproj.datadir.append_data_dir("/usr/share/proj")
    path, e, n, h, _ = svalbard
    lon, lat = Transformer.from_crs("EPSG:32633", "EPSG:4326", always_xy=True).transform(e, n)
    to_msl = Transformer.from_crs("EPSG:4979", "EPSG:4326+5773", always_xy=True)
    big_n = h - np.asarray(to_msl.transform(lon, lat, h)[2])  # N at each point
    dem = tmp_path / "dem.tif"
    xs = 499990 + 20 * np.arange(52) + 10
    ys = 8701010 - 20 * np.arange(52) - 10
    xx, yy = np.meshgrid(xs, ys)
    write_array(dem, 200.0 + 0.02 * (xx - 500000) - big_n.mean(),
                from_origin(499990, 8701010, 20, 20), "EPSG:32633+5773")  # fmt: skip
    c = certify(dem, path, n_boot=50)
    assert (c["checkpoints"]["heights"]["dem"], c["checkpoints"]["heights"]["checkpoints"]) == (
        "egm96",
        "ellipsoidal",
    )
    assert c["checkpoints"]["heights"]["shift_m"] == pytest.approx(-big_n.mean(), abs=1e-3)
    assert abs(c["accuracy"]["bias_m"]) < 0.05  # the rows' own 5 cm scatter


def test_cli_reconstruct_maps_an_emlid_export(svalbard, tmp_path):
    path = svalbard[0]
    out = tmp_path / "out"
    r = CliRunner().invoke(app, ["reconstruct", str(path), "--resolution", "50", "--out", str(out)])
    assert r.exit_code == 0, r.output
    words = " ".join(r.output.split())
    assert "Emlid Flow export: Easting, Northing in WGS 84 / UTM zone 33N" in words
    with rasterio.open(out / "elevation.tif") as src:
        assert src.crs.to_epsg() == 32633
        assert src.tags()["vertical_datum"].startswith("ellipsoidal height above the WGS 84")


def test_ground_control_from_an_emlid_export_equals_the_plain_table(svalbard, tmp_path):
    # The same points as glacimap's own control table (id, x, y, z, sigma_x/y/z, crs): the
    # same ControlPoints; the export's CS and a contradicting crs= refused.
    from factorgraph.control_io import read_control

    path, e, n, h, rms = svalbard
    ctrl = read_control(path)
    plain = tmp_path / "gcp.csv"
    lines = ["id,x,y,z,sigma_x,sigma_y,sigma_z,crs"] + [
        f"P{i},{e[i]:.3f},{n[i]:.3f},{h[i]:.3f},0.010,0.010,{rms[i]:.3f},EPSG:32633"
        for i in range(len(e))
    ]
    plain.write_text("\n".join(lines) + "\n")
    ref = read_control(plain)
    np.testing.assert_array_equal(ctrl.ids, ref.ids)
    np.testing.assert_allclose(ctrl.xyz, ref.xyz, atol=1e-9)
    np.testing.assert_allclose(ctrl.sigma, ref.sigma, atol=1e-9)
    assert CRS(ctrl.crs).equals(CRS(ref.crs))
    with pytest.raises(InputError, match="control crs.*the export's own"):
        read_control(path, crs="EPSG:32632")
