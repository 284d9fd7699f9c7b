"""Control, checkpoint and sample tables as spreadsheets and survey software write them (tried
as a new user would, issue 17): one reader (factorgraph.field.table) behind all three, so a
file that one accepts the others accept too.

Reference: the same 12 points written as a plain comma-separated UTF-8 file.
"""

from __future__ import annotations

import numpy as np
import pytest

from factorgraph.control_io import read_control
from factorgraph.field.table import header_key, read_text_table
from terrain import Grid, InputError, random_terrain
from terrain.product import terrain_dataset
from toolkit.certify import certify
from toolkit.certify_io import read_checkpoints
from toolkit.samples_io import read_samples

CRS = "EPSG:32608"
RNG = np.random.default_rng(3)
XY = np.column_stack([526000 + RNG.uniform(20, 580, 12), 6475000 + RNG.uniform(20, 580, 12)])
Z = 100 + RNG.normal(0, 5, 12)
IDS = [str(i + 1) for i in range(12)]  # numeric ids, as many total stations number points


def _write(path, header, rows, sep=",", decimal=".", encoding="utf-8", newline="\n"):
    def num(v):
        return f"{v:.4f}".replace(".", decimal)

    lines = [sep.join(header)]
    lines += [sep.join([i, num(x), num(y), num(z), *rest]) for i, (x, y), z, rest in rows]
    path.write_bytes((newline.join(lines) + newline).encode(encoding))
    return path


def _rows(extra=()):
    return [(IDS[i], XY[i], Z[i], list(extra)) for i in range(12)]


VARIANTS = {
    "semicolon_decimal_comma": dict(sep=";", decimal=","),  # a European spreadsheet export
    "tab": dict(sep="\t"),
    "pipe": dict(sep="|"),
    "windows_1252_crlf": dict(encoding="cp1252", newline="\r\n"),  # Excel "CSV" on Windows
    "bom": dict(encoding="utf-8-sig"),
}


@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_control_and_checkpoints_read_every_export(tmp_path, variant):
    header = ["Point", "Easting (m)", "Northing (m)", "Elevation (m)", "sigma", "crs", "note"]
    rows = _rows(["0.02", CRS, "près du névé"])  # a note that is not ASCII
    path = _write(tmp_path / f"{variant}.csv", header, rows, **VARIANTS[variant])
    cps = read_checkpoints(path)
    ctl = read_control(path)  # before: "Easting (m)" refused, any non-comma file refused
    np.testing.assert_allclose(cps.xy, XY, atol=5e-5)  # the %.4f rounding
    np.testing.assert_allclose(cps.z, Z, atol=5e-5)
    np.testing.assert_allclose(ctl.xyz[:, :2], XY, atol=5e-5)
    assert list(ctl.ids) == IDS and ctl.crs == CRS
    assert ctl.notes["note"][0] == "près du névé"


def test_table_reports_what_it_read_differently(tmp_path):
    path = _write(tmp_path / "t.csv", ["id", "x", "y", "z"], _rows(), sep=";", decimal=",")
    t = read_text_table(path, "t")
    assert t.delimiter == ";" and "decimal comma in 36 cells" in t.notes  # 12 rows x 3
    path.write_text("id;x;y;z\n1;2;3\n")
    with pytest.raises(InputError, match=r"t.csv line 2.*4 cells.*delimiter ';'"):
        read_text_table(path, "t")
    assert header_key("Easting (m)", {"easting"}) == "easting"
    assert header_key("height_m", {"height"}) == "height"
    assert header_key("track_z_std_m", {"z_std"}) == "track_z_std_m"  # not an alias: kept


def test_control_crs_from_a_sidecar(tmp_path):
    path = _write(tmp_path / "gcp.csv", ["id", "x", "y", "z", "sigma"], _rows(["0.02"]))
    with pytest.raises(InputError, match=r"gcp.crs sidecar"):
        read_control(path)
    (tmp_path / "gcp.crs").write_text(CRS + "\n")  # as checkpoints and samples allow
    assert read_control(path).crs == CRS


def test_samples_with_semicolons_keep_their_error_columns(tmp_path):
    path = _write(
        tmp_path / "s.csv", ["id", "x", "y", "z", "z_var", "crs"], _rows(["0,04", CRS]), sep=";",
        decimal=",",
    )  # fmt: skip
    table = read_samples(path)
    np.testing.assert_allclose(table.samples.z_var, 0.04)  # before: pandas read one column


@pytest.fixture(scope="module")
def dem():
    grid = Grid.from_bounds((526000.0, 6475000.0, 526600.0, 6475600.0), 10.0, crs=CRS)
    z = random_terrain(grid, relief=25.0, seed=1).values
    return terrain_dataset(grid, z, np.full(grid.shape, 0.3), {"seed": 3})


def test_checkpoints_not_scored_are_a_warning_and_lonlat_without_crs_is_named(dem, tmp_path):
    xy = XY.copy()
    xy[0, 0] += 5000.0  # one point 5 km east of the map
    cert = certify(dem, {"x": xy[:, 0], "y": xy[:, 1], "z": Z, "crs": [CRS] * 12})
    assert cert["checkpoints"]["n_used"] == 11
    assert any("1 of 12 checkpoints were not scored (1 outside the DEM)" in w for w in
               cert["warnings"])  # fmt: skip
    from pyproj import Transformer

    lon, lat = Transformer.from_crs(CRS, "EPSG:4326", always_xy=True).transform(*XY.T)
    path = _write(tmp_path / "ll.csv", ["id", "lon", "lat", "height"],
                  [(IDS[i], (lon[i], lat[i]), Z[i], []) for i in range(12)])  # fmt: skip
    with pytest.raises(InputError, match=r"look like longitude / latitude degrees.*EPSG:4326"):
        certify(dem, path)


def test_report_draws_samples_of_any_dialect_and_skips_what_it_cannot(tmp_path):
    from toolkit.cli.report import _sample_points

    path = _write(tmp_path / "samples.csv", ["id", "x", "y", "z", "crs"], _rows([CRS]), sep=";")
    np.testing.assert_allclose(_sample_points(path)["samples"], XY, atol=5e-5)
    path.write_text("Longitude,Latitude,Height,crs\n-134.5,58.4,100,EPSG:4326\n")
    assert _sample_points(path) == {}  # lon/lat: not drawn on the map (said, not a crash)
    path.write_text("a;b\n1;2\n")
    assert _sample_points(path) == {}  # before: numpy's "Some errors were detected" traceback


def test_certify_names_the_crs_it_reprojected_from_and_to(dem, tmp_path):
    import rasterio
    from pyproj import Transformer
    from typer.testing import CliRunner

    from terrain import Grid as _Grid
    from toolkit.cli import app

    grid = _Grid.from_dataarray(dem["elevation"])
    with rasterio.open(
        tmp_path / "dem.tif", "w", driver="GTiff", width=grid.nx, height=grid.ny, count=1,
        dtype="float64", crs=CRS, transform=rasterio.transform.from_origin(
            grid.bounds[0], grid.bounds[3], *grid.resolution),
    ) as dst:  # fmt: skip
        dst.write(np.asarray(dem["elevation"].values, float), 1)
    lon, lat = Transformer.from_crs(CRS, "EPSG:4326", always_xy=True).transform(*XY.T)
    path = _write(tmp_path / "ll.csv", ["id", "lon", "lat", "height", "crs"],
                  [(IDS[i], (lon[i], lat[i]), Z[i], ["EPSG:4326"]) for i in range(12)])  # fmt: skip
    res = CliRunner().invoke(app, ["certify", str(tmp_path / "dem.tif"), str(path)])
    assert res.exit_code == 0, res.output
    flat = " ".join(res.output.split())
    assert "reprojected from WGS 84 to WGS 84 / UTM zone 8N (pyproj)" in flat  # not WKT text
