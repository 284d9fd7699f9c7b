"""``glacimap reconstruct --breaklines``: a scarp the surveyor digitised, read from GeoJSON
or WKT, fitted as a step of the prior mean and recorded in the products; bad files refused
by name before anything is written.

References: the step put into the samples (3 m) and the library's ``BreaklineMean`` on the
same samples (``tests/test_breakline.py`` checks it by hand).
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
import xarray as xr
from scipy.special import expit
from typer.testing import CliRunner

from terrain import InputError, default_site
from terrain.sampling import sample_dem
from toolkit.breaklines_io import read_breaklines
from toolkit.cli import app

runner = CliRunner()
CRS = "EPSG:32608"
X0, Y0 = 526000.0, 6475000.0


def _line() -> np.ndarray:
    """A sinuous east-west line through the default site, run 100 m beyond it."""
    u = np.linspace(-100.0, 700.0, 161)
    return np.column_stack([X0 + u, Y0 + 300.0 + 25.0 * np.sin(u / 70.0)])


@pytest.fixture(scope="module")
def scarp_csv(tmp_path_factory):
    """600 spot heights (20 cm 1-sigma) of the default site with a 3 m step, 1 m wide, up
    to the north of :func:`_line`."""
    rng = np.random.default_rng(1)
    xy = rng.uniform([X0 + 2, Y0 + 2], [X0 + 598, Y0 + 598], size=(600, 2))
    across = xy[:, 1] - (Y0 + 300.0 + 25.0 * np.sin((xy[:, 0] - X0) / 70.0))
    z = sample_dem(default_site(resolution=4.0), xy) + 3.0 * expit(across) + rng.normal(0, 0.2, 600)
    path = tmp_path_factory.mktemp("in") / "spots.csv"
    pd.DataFrame({"x": xy[:, 0], "y": xy[:, 1], "z": z, "z_var": 0.04}).to_csv(path, index=False)
    return path


def test_geojson_and_wkt_give_the_same_lines(tmp_path):
    line = _line()
    feature = {"type": "Feature", "properties": {"name": "ice cliff"},
               "geometry": {"type": "LineString", "coordinates": line.tolist()}}  # fmt: skip
    gj = tmp_path / "lines.geojson"
    gj.write_text(json.dumps({"type": "FeatureCollection", "features": [feature]}))
    wkt = tmp_path / "lines.wkt"
    wkt.write_text("LINESTRING (" + ", ".join(f"{x!r} {y!r}" for x, y in line.tolist()) + ")\n")
    a, b = read_breaklines(gj), read_breaklines(wkt)
    assert len(a) == len(b) == 1
    np.testing.assert_array_equal(a[0], line)
    np.testing.assert_array_equal(b[0], line)


def test_a_geopackage_in_lon_lat_is_reprojected_and_bare_lon_lat_refused(tmp_path):
    # Reference: pyproj's own transform of the same vertices (the file stores lon/lat).
    import pyogrio
    import shapely
    from pyproj import Transformer

    line = _line()
    to_ll = Transformer.from_crs(CRS, "EPSG:4326", always_xy=True)
    lon, lat = to_ll.transform(line[:, 0], line[:, 1])
    gpkg = tmp_path / "cliff.gpkg"
    wkb = np.array([shapely.to_wkb(shapely.LineString(np.column_stack([lon, lat])))], object)
    pyogrio.raw.write(gpkg, wkb, [], [], geometry_type="LineString", crs="EPSG:4326")
    (got,) = read_breaklines(gpkg, CRS)
    np.testing.assert_allclose(got, line, atol=1e-6)  # m: the round trip through lon/lat
    # a feature without a geometry is left out, counted, never silently
    pyogrio.raw.write(gpkg, np.array([wkb[0], None], object), [], [],
                      geometry_type="LineString", crs="EPSG:4326")  # fmt: skip
    with pytest.warns(UserWarning, match="1 empty geometries left out"):
        assert len(read_breaklines(gpkg, CRS)) == 1
    # the same lon/lat as WKT declares no CRS: refused for a projected map, by name
    wkt = tmp_path / "cliff.wkt"
    wkt.write_text(shapely.to_wkt(shapely.LineString(np.column_stack([lon, lat]))))
    with pytest.raises(InputError, match="--breaklines.*longitude / latitude"):
        read_breaklines(wkt, CRS)
    # a GeoJSON without a crs member holding map coordinates (GDAL calls it WGS 84): as is
    gj = tmp_path / "cliff.geojson"
    gj.write_text(json.dumps({"type": "LineString", "coordinates": line.tolist()}))
    np.testing.assert_array_equal(read_breaklines(gj, CRS)[0], line)


def test_cli_fits_the_step_and_records_it(scarp_csv, tmp_path):
    gj = tmp_path / "cliff.geojson"
    gj.write_text(json.dumps({"type": "LineString", "coordinates": _line().tolist()}))
    out = tmp_path / "map"
    res = runner.invoke(app, ["reconstruct", str(scarp_csv), "--crs", CRS, "--resolution", "10",
                              "--breaklines", str(gj), "--out", str(out)])  # fmt: skip
    assert res.exit_code == 0, res.output
    attrs = xr.open_dataset(out / "product.nc").attrs
    assert "BreaklineMean" in attrs["mean_function"]
    height = float(attrs["mean_function"].split("step1_m=")[1].split()[0])
    assert height == pytest.approx(3.0, abs=0.45)  # measured 3.14 +- 0.15 (3 sigma)
    inputs = {r["role"]: r["name"] for r in json.loads(attrs["inputs"])}
    assert inputs["breaklines"] == "cliff.geojson"
    # without checkpoints the certificate still states the line it was fitted with (the
    # step, its width and their 1-sigma), as one with checkpoints does
    cert = json.loads((out / "certificate.json").read_text())
    (row,) = cert["breaklines"]
    assert row["step_m"] == pytest.approx(height, abs=1e-4)
    assert row["width_m"] > 0 and row["width_sd_m"] > 0 and row["step_sd_m"] > 0


def test_cli_reads_a_lon_lat_geopackage_as_the_same_lines(scarp_csv, tmp_path):
    # Reference: the same lines given in the map's CRS (GeoJSON, the test above): the map
    # made from a GeoPackage in EPSG:4326 has the same step height to 1e-4 m.
    import pyogrio
    import shapely
    from pyproj import Transformer

    line = _line()
    lon, lat = Transformer.from_crs(CRS, "EPSG:4326", always_xy=True).transform(*line.T)
    gpkg = tmp_path / "cliff.gpkg"
    wkb = np.array([shapely.to_wkb(shapely.LineString(np.column_stack([lon, lat])))], object)
    pyogrio.raw.write(gpkg, wkb, [], [], geometry_type="LineString", crs="EPSG:4326")
    gj = tmp_path / "cliff.geojson"
    gj.write_text(json.dumps({"type": "LineString", "coordinates": line.tolist()}))
    heights = []
    for path in (gj, gpkg):
        out = tmp_path / path.suffix[1:]
        res = runner.invoke(app, ["reconstruct", str(scarp_csv), "--crs", CRS, "--resolution",
                                  "20", "--breaklines", str(path), "--out", str(out)])  # fmt: skip
        assert res.exit_code == 0, res.output
        said = "reprojected from EPSG:4326" if path is gpkg else "no CRS declared"
        assert f"breaklines: 1 line(s) from {path.name}; {said}" in " ".join(res.output.split())
        mean = xr.open_dataset(out / "product.nc").attrs["mean_function"]
        heights.append(float(mean.split("step1_m=")[1].split()[0]))
    assert heights[1] == pytest.approx(heights[0], abs=1e-4)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        (None, "an existing vector file"),
        ("POLYGON ((0 0, 1 0, 1 1, 0 0))", "LineStrings"),
        ("not a geometry", "does not parse"),
        ('{"type": "FeatureCollection", "features": []}', "at least one line"),
    ],
)
def test_cli_bad_breaklines_are_refused_before_anything_is_written(
    scarp_csv, tmp_path, text, match
):
    path = tmp_path / "lines.wkt"
    if text is not None:
        path.write_text(text)
    out = tmp_path / "never"
    res = runner.invoke(app, ["reconstruct", str(scarp_csv), "--crs", CRS,
                              "--breaklines", str(path), "--out", str(out)])  # fmt: skip
    assert res.exit_code != 0
    assert isinstance(res.exception, InputError) and "--breaklines" in str(res.exception)
    assert match in str(res.exception)
    assert not out.exists()


def test_the_width_and_taper_options_read_auto_or_metres():
    from toolkit.breaklines_io import breakline_taper, breakline_width

    for option, read in (
        ("--breakline-width", breakline_width),
        ("--breakline-taper", breakline_taper),
    ):
        assert read("auto") == read(" AUTO ") == "auto"
        assert read("1.5") == 1.5
        for bad in ("wide", "0", "-1", "nan", "inf"):
            with pytest.raises(InputError, match=option):
                read(bad)


def test_cli_maps_a_cliff_that_dies_out_inside_the_survey(tmp_path):
    # The default site with a 3 m step, 1 m wide, whose height falls by half a cosine of
    # the easting over the 150 m before it stops 450 m into the site; the line drawn to
    # there. Until 0.37.0 such a line was refused ("both ends outside").
    rng = np.random.default_rng(2)
    xy = rng.uniform([X0 + 2, Y0 + 2], [X0 + 598, Y0 + 598], size=(800, 2))
    across = xy[:, 1] - (Y0 + 300.0 + 25.0 * np.sin((xy[:, 0] - X0) / 70.0))
    fade = np.clip((X0 + 450.0 - xy[:, 0]) / 150.0, 0.0, 1.0)
    step = 3.0 * expit(across) * (0.5 - 0.5 * np.cos(np.pi * fade))
    z = sample_dem(default_site(resolution=4.0), xy) + step + rng.normal(0, 0.2, len(xy))
    csv = tmp_path / "spots.csv"
    pd.DataFrame({"x": xy[:, 0], "y": xy[:, 1], "z": z, "z_var": 0.04}).to_csv(csv, index=False)
    line = _line()
    gj = tmp_path / "cliff.geojson"
    gj.write_text(
        json.dumps({"type": "LineString", "coordinates": line[line[:, 0] <= X0 + 450].tolist()})
    )
    out = tmp_path / "map"
    res = runner.invoke(app, ["reconstruct", str(csv), "--crs", CRS, "--resolution", "10",
                              "--breaklines", str(gj), "--out", str(out)])  # fmt: skip
    assert res.exit_code == 0, res.output
    said = " ".join(res.output.split())  # the console wraps at 80 columns
    assert "last vertex inside the survey: the step dies out over the" in said
    attrs = xr.open_dataset(out / "product.nc").attrs
    height = float(attrs["mean_function"].split("step1_m=")[1].split()[0])
    assert height == pytest.approx(3.0, abs=0.5)  # measured 2.72 +- 0.17 (800 spot heights)
    record = json.loads(attrs["breaklines"])["properties"]
    assert record["open_ends"] == [[False, True]] and record["tapers_m"][0] > 0
    # a taper given is used as given; a bad one stops the command before any work
    res = runner.invoke(app, ["reconstruct", str(csv), "--crs", CRS, "--resolution", "10",
                              "--breaklines", str(gj), "--breakline-taper", "60",
                              "--out", str(tmp_path / "given")])  # fmt: skip
    assert res.exit_code == 0 and "dies out over the 60 m before it" in " ".join(res.output.split())
    never = tmp_path / "never"
    res = runner.invoke(app, ["reconstruct", str(csv), "--crs", CRS, "--breaklines", str(gj),
                              "--breakline-taper", "long", "--out", str(never)])  # fmt: skip
    assert isinstance(res.exception, InputError) and "--breakline-taper" in str(res.exception)
    assert not never.exists()


def test_process_takes_breaklines_and_finds_no_step_where_there_is_none(tmp_path):
    # The example field folder (the default site, EPSG:32608) has no scarp: a line across
    # its middle gets a height within 4 sigma of 0 (measured -0.0001 +- 0.028 m), recorded
    # with the file; a bad file stops the command before any work, with nothing written.
    from pathlib import Path

    example = Path(__file__).resolve().parents[1] / "docs" / "examples" / "field"
    wkt = tmp_path / "across.wkt"
    wkt.write_text("LINESTRING (525900 6475300, 526700 6475310)\n")
    out = tmp_path / "out"
    res = runner.invoke(app, ["process", str(example), "--breaklines", str(wkt),
                              "--out", str(out)])  # fmt: skip
    assert res.exit_code == 0, res.output
    assert "breaklines: line 1: step" in res.output  # said with its 1-sigma and width
    attrs = xr.open_dataset(out / "product.nc").attrs
    text = attrs["mean_function"].split("step1_m=")[1].split()
    height, sd = float(text[0]), float(text[2].rstrip(")"))
    assert abs(height) < 4 * sd
    assert {r["role"]: r["name"] for r in json.loads(attrs["inputs"])}["breaklines"] == wkt.name
    bad = tmp_path / "bad.wkt"
    bad.write_text("POINT (1 2)\n")
    never = tmp_path / "never"
    res = runner.invoke(app, ["process", str(example), "--breaklines", str(bad),
                              "--out", str(never)])  # fmt: skip
    assert isinstance(res.exception, InputError) and "--breaklines" in str(res.exception)
    assert not never.exists()
    # lon/lat without a CRS for the field folder's UTM map: refused by name, nothing written
    bad.write_text("LINESTRING (-135.4 58.4, -135.3 58.41)\n")
    res = runner.invoke(app, ["process", str(example), "--breaklines", str(bad),
                              "--out", str(never)])  # fmt: skip
    assert isinstance(res.exception, InputError) and "longitude / latitude" in str(res.exception)
    assert not never.exists()
