"""Survey points from GIS layers (GeoPackage, Shapefile, GeoJSON) and point clouds (LAS /
LAZ) for ``glacimap reconstruct`` and ``certify``: written here with GDAL (pyogrio) and
laspy, read back through the CLI's own readers."""

import laspy
import numpy as np
import pandas as pd
import pyogrio.raw
import pytest
import shapely
import xarray as xr
from pyproj import CRS, Transformer
from typer.testing import CliRunner

from terrain.errors import CRSMismatchError, InputError
from toolkit.certify_io import read_checkpoints
from toolkit.cli import app
from toolkit.sample_blocks import reduce_table
from toolkit.samples_io import read_sample_files

runner = CliRunner()
UTM = "EPSG:32633"
X0, Y0 = 500_000.0, 7_000_000.0


def _surface(x, y):
    return 300 + 0.1 * (x - X0) + 2.0 * np.sin((y - Y0) / 35.0)


def _points(n, seed=0, size=300.0):
    rng = np.random.default_rng(seed)
    return rng.uniform([X0, Y0], [X0 + size, Y0 + size], (n, 2))


def _layer(path, geoms, crs=UTM, fields=None, driver="GPKG", geometry_type="Point"):
    fields = fields or {}
    pyogrio.raw.write(
        path,
        shapely.to_wkb(geoms),
        geometry_type=geometry_type,
        crs=crs,
        driver=driver,
        fields=list(fields),
        field_data=list(fields.values()),
    )
    return path


def _las(path, xy, z, classes=None, crs=UTM, withheld=None):
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.offsets, header.scales = [X0, Y0, 0.0], [0.001, 0.001, 0.001]
    if crs is not None:
        header.add_crs(CRS.from_user_input(crs))
    las = laspy.LasData(header)
    las.x, las.y, las.z = xy[:, 0], xy[:, 1], z
    las.classification = np.full(len(z), 1, np.uint8) if classes is None else classes
    if withheld is not None:
        las.withheld = withheld
    las.write(path)
    return path


def test_a_geopackage_of_3d_points_with_a_sigma_attribute(tmp_path):
    xy = _points(500)
    z = _surface(*xy.T)
    path = _layer(
        tmp_path / "spots.gpkg",
        shapely.points(xy[:, 0], xy[:, 1], z),
        fields={"sigma": np.full(500, 0.05), "id": np.arange(500)},
        geometry_type="Point Z",
    )
    table = read_sample_files([path])
    assert table.samples.crs.equals(CRS(UTM)) and table.derived
    np.testing.assert_allclose(table.samples.xy, xy, atol=1e-9)
    np.testing.assert_allclose(table.samples.z, z, atol=1e-9)
    np.testing.assert_allclose(table.samples.z_var, 0.0025)  # the sigma attribute squared
    assert "column 'sigma' read as each sample's 1-sigma" in table.note
    assert "columns not read: id" in table.note


def test_a_shapefile_with_a_height_attribute_and_geojson_in_degrees(tmp_path):
    xy = _points(200, seed=1)
    z = _surface(*xy.T)
    shp = _layer(
        tmp_path / "survey.shp",
        shapely.points(xy[:, 0], xy[:, 1]),
        fields={"ELEV": z},
        driver="ESRI Shapefile",
    )
    table = read_sample_files([shp])
    np.testing.assert_allclose(table.samples.z, z, atol=1e-9)
    lon, lat = Transformer.from_crs(UTM, "EPSG:4326", always_xy=True).transform(*xy.T)
    gj = _layer(
        tmp_path / "survey.geojson",
        shapely.points(lon, lat),
        crs="EPSG:4326",
        fields={"height": z},
        driver="GeoJSON",
    )
    table = read_sample_files([gj])  # degrees projected to their UTM zone, said
    assert table.samples.crs.equals(CRS(UTM))
    np.testing.assert_allclose(table.samples.xy, xy, atol=1e-3)
    assert "projected to EPSG:32633" in table.note


def test_contour_lines_give_their_vertices_with_the_lines_elevation(tmp_path):
    levels = np.arange(0, 300, 50.0)
    lines = [
        shapely.LineString([(X0, Y0 + d), (X0 + 100, Y0 + d), (X0 + 200, Y0 + d)]) for d in levels
    ]
    path = _layer(
        tmp_path / "contours.gpkg",
        np.array(lines),
        fields={"elevation": 1000 + levels},
        geometry_type="LineString",
    )
    table = read_sample_files([path], crs=UTM)
    assert table.samples.n == 18
    np.testing.assert_allclose(np.sort(table.samples.z), np.repeat(1000 + levels, 3))
    assert "6 features' 18 vertices read as samples" in table.note


def test_bad_layers_are_refused_by_name(tmp_path):
    xy = _points(20, seed=2)
    square = shapely.box(X0, Y0, X0 + 10, Y0 + 10)
    poly = _layer(tmp_path / "poly.gpkg", np.array([square]), geometry_type="Polygon")
    with pytest.raises(InputError, match="SAMPLES.*points.*contours.*poly.gpkg .polygon"):
        read_sample_files([poly])
    flat = _layer(
        tmp_path / "flat.gpkg", shapely.points(xy[:, 0], xy[:, 1]), fields={"n": np.arange(20)}
    )
    with pytest.raises(InputError, match="missing z"):
        read_sample_files([flat])
    z = _surface(*xy.T)
    both = _layer(
        tmp_path / "both.gpkg",
        shapely.points(xy[:, 0], xy[:, 1], z),
        fields={"elev": z + 0.5},
        geometry_type="Point Z",
    )
    with pytest.raises(InputError, match="geometry Z and attribute 'elev' differ by up to 0.5 m"):
        read_sample_files([both])
    feet = _layer(tmp_path / "feet.gpkg", shapely.points(xy[:, 0], xy[:, 1], z), crs="EPSG:2232",
                  geometry_type="Point Z")  # fmt: skip
    with pytest.raises(InputError, match="US survey foot.*metres.*ogr2ogr -t_srs"):
        read_sample_files([feet])


def test_checkpoints_from_a_geopackage_as_from_a_csv(tmp_path):
    xy = _points(40, seed=3)
    z = _surface(*xy.T)
    gpkg = _layer(
        tmp_path / "cps.gpkg", shapely.points(xy[:, 0], xy[:, 1], z), geometry_type="Point Z"
    )
    csv = tmp_path / "cps.csv"
    pd.DataFrame({"x": xy[:, 0], "y": xy[:, 1], "z": z, "crs": UTM}).to_csv(csv, index=False)
    a, b = read_checkpoints(gpkg), read_checkpoints(csv)
    np.testing.assert_allclose(a.xy, b.xy, atol=1e-9)
    np.testing.assert_allclose(a.z, b.z, atol=1e-9)
    assert a.crs.equals(b.crs)
    with pytest.raises(InputError, match="not a cloud"):
        read_checkpoints(_las(tmp_path / "c.las", xy, z))


def test_a_classified_cloud_keeps_its_ground_and_counts_the_rest(tmp_path):
    rng = np.random.default_rng(4)
    xy = _points(5_000, seed=4)
    z = _surface(*xy.T)
    classes = rng.choice(np.array([2, 5, 7], np.uint8), 5_000, p=[0.8, 0.15, 0.05])
    withheld = rng.random(5_000) < 0.01
    path = _las(tmp_path / "cloud.laz", xy, z + 3.0 * (classes == 5), classes, withheld=withheld)
    table = read_sample_files([path])
    keep = (classes == 2) & ~withheld
    assert table.samples.n == keep.sum() and table.derived
    np.testing.assert_allclose(np.sort(table.samples.z), np.sort(np.round(z[keep], 3)), atol=1e-6)
    note = " ".join(table.note.split())
    n5, n7 = ((classes == 5) & ~withheld).sum(), ((classes == 7) & ~withheld).sum()
    assert f"left out {n5:,} class 5 (high vegetation), {n7:,} class 7 (low noise)" in note
    assert f"left out {withheld.sum():,} withheld points" in note
    both = read_sample_files([path], point_classes=(2, 5))
    assert both.samples.n == ((classes != 7) & ~withheld).sum()


def test_a_cloud_without_a_crs_needs_one_and_a_contradiction_is_refused(tmp_path):
    xy = _points(300, seed=5)
    bare = _las(tmp_path / "bare.las", xy, _surface(*xy.T), crs=None)
    with pytest.raises(InputError, match="--crs.*bare.las.*header names none"):
        read_sample_files([bare])
    assert read_sample_files([bare], crs=UTM).samples.crs.equals(CRS(UTM))
    with pytest.raises(CRSMismatchError):
        read_sample_files([_las(tmp_path / "c.las", xy, _surface(*xy.T))], crs="EPSG:32632")
    with pytest.raises(InputError, match="--point-classes"):
        read_sample_files([tmp_path / "c.las"], point_classes=(99,))
    whole = _las(tmp_path / "whole.laz", _points(50_000, seed=5), np.zeros(50_000)).read_bytes()
    (tmp_path / "cut.laz").write_bytes(whole[: len(whole) // 2])  # a download cut short
    with pytest.raises(InputError, match="laspy reads.*cut.laz"):
        read_sample_files([tmp_path / "cut.laz"])


def test_auto_reduces_a_dense_cloud_but_never_a_rovers_samples(tmp_path):
    xy = _points(150_000, seed=6, size=600.0)
    rng = np.random.default_rng(6)
    z = _surface(*xy.T) + rng.normal(0, 0.05, len(xy))
    table = read_sample_files([_las(tmp_path / "dense.laz", xy, z)], block_size="auto")
    assert 20_000 < table.samples.n <= 50_000
    assert "150,000 points reduced to" in table.note and "(auto:" in table.note
    err = table.samples.z - _surface(*table.samples.xy.T)
    assert np.std(err / np.sqrt(table.samples.z_var)) == pytest.approx(1.0, abs=0.1)
    kept = read_sample_files([tmp_path / "dense.laz"], block_size=None)
    assert kept.samples.n == 150_000
    kept.track_z_std = np.full(kept.samples.n, 0.1)  # a rover's along-track errors
    same, red = reduce_table(kept, "auto")
    assert red is None and same.samples.n == 150_000 and "not reduced to blocks" in same.note
    with pytest.raises(InputError, match="--block-size.*along-track"):
        reduce_table(kept, 2.0)


def test_cli_maps_a_laz_cloud_and_writes_its_block_samples(tmp_path):
    xy = _points(40_000, seed=7)
    rng = np.random.default_rng(7)
    z = _surface(*xy.T) + rng.normal(0, 0.05, len(xy))
    laz = _las(tmp_path / "cloud.laz", xy, z, np.full(len(z), 2, np.uint8))
    out = tmp_path / "map"
    r = runner.invoke(
        app, ["reconstruct", str(laz), "--block-size", "6", "--resolution", "6", "--out", str(out)]
    )
    assert r.exit_code == 0, r.output
    words = " ".join(r.output.split())
    # hand count: the 6 m blocks of a lattice floored to a multiple of 6 m that hold points
    blocks = len({tuple(b) for b in np.floor((xy - np.floor(xy.min(0) / 6) * 6) / 6).astype(int)})
    assert 2_500 <= blocks <= 2_601  # a 300 m square over 6 m blocks, edges cut
    assert f"40,000 points reduced to {blocks:,} samples, one per 6 m block" in words
    back = pd.read_csv(out / "samples.csv")
    assert len(back) == blocks and set(back["crs"]) == {UTM}
    ds = xr.open_dataset(out / "product.nc")
    xx, yy = np.meshgrid(ds["x"].values, ds["y"].values)
    err = ds["elevation"].values - _surface(xx, yy)
    assert float(np.sqrt(np.mean(err**2))) < 0.05  # 0.05 m lidar, 16 points per sample
    bad = runner.invoke(
        app, ["reconstruct", str(laz), "--block-size", "-1", "--out", str(tmp_path / "b")]
    )
    assert isinstance(bad.exception, InputError) and "--block-size" in str(bad.exception)
    assert not (tmp_path / "b").exists()  # refused before anything is read or written


def test_tiles_of_one_survey_are_reduced_together(tmp_path):
    # Two tiles (split at x = X0 + 150 m, inside blocks) reduce as the one cloud they are;
    # a tile in another CRS is refused; a cloud in degrees is projected to its UTM zone.
    xy = _points(120_000, seed=8)
    rng = np.random.default_rng(8)
    z = _surface(*xy.T) + rng.normal(0, 0.05, len(xy))
    west = xy[:, 0] < X0 + 150.0
    one = read_sample_files([_las(tmp_path / "all.laz", xy, z)], block_size=6.0)
    a = _las(tmp_path / "west.laz", xy[west], z[west])
    b = _las(tmp_path / "east.laz", xy[~west], z[~west])
    two = read_sample_files([a, b], block_size=6.0)
    assert two.samples.n == one.samples.n
    np.testing.assert_allclose(two.samples.z, one.samples.z, atol=1e-9)
    assert "west.laz, east.laz: 120,000 points" in two.note
    other = _las(tmp_path / "other.laz", xy[:10], z[:10], crs="EPSG:32632")
    with pytest.raises(InputError, match="one CRS"):
        read_sample_files([a, other], block_size=6.0)
    lon, lat = Transformer.from_crs(UTM, "EPSG:4326", always_xy=True).transform(*xy[:2000].T)
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.offsets, header.scales = [15.0, 63.0, 0.0], [1e-8, 1e-8, 0.001]
    header.add_crs(CRS.from_epsg(4326))
    las = laspy.LasData(header)
    las.x, las.y, las.z = lon, lat, z[:2000]
    las.write(tmp_path / "degrees.laz")
    deg = read_sample_files([tmp_path / "degrees.laz"], block_size=None)
    assert deg.samples.crs.equals(CRS(UTM)) and "projected to EPSG:32633" in deg.note
    np.testing.assert_allclose(np.sort(deg.samples.xy[:, 0]), np.sort(xy[:2000, 0]), atol=1e-3)


def test_a_clouds_compound_crs_states_its_heights(tmp_path):
    # EGM96 heights (EPSG:5773) become the map's stated datum, and so do NAVD88's (5703: a
    # national datum, carried by PROJ's grid where change / certify need it); heights in
    # feet (NAVD88 ftUS, 6360) are refused; an option contradicting
    # the file is refused.
    from toolkit.samples_io import samples_height_attrs

    xy = _points(300, seed=9)
    z = _surface(*xy.T)
    egm = _las(tmp_path / "egm.laz", xy, z, crs=f"{UTM}+5773")
    assert samples_height_attrs([egm], None)["height_datum"] == "egm96"
    assert samples_height_attrs([egm], "egm96")["height_datum"] == "egm96"
    with pytest.raises(InputError, match="--samples-heights"):
        samples_height_attrs([egm], "ellipsoidal")
    table = read_sample_files([egm])
    assert table.samples.crs.equals(CRS(UTM))  # the map's CRS is the horizontal part
    navd = _las(tmp_path / "navd.laz", xy, z, crs="EPSG:32618+5703")
    attrs = samples_height_attrs([navd], None)
    assert attrs["height_datum"] == "EPSG:5703"
    assert attrs["vertical_datum"].startswith("orthometric height above NAVD88 height (EPSG:5703)")
    feet = _las(tmp_path / "feet.laz", xy, z, crs="EPSG:32618+6360")
    with pytest.raises(InputError, match="US survey foot"):
        read_sample_files([feet])


def test_a_parquet_table_of_samples_reads_as_its_csv(tmp_path):
    xy = _points(100, seed=10)
    frame = pd.DataFrame({"x": xy[:, 0], "y": xy[:, 1], "z": _surface(*xy.T), "sigma": 0.1})
    frame.to_parquet(tmp_path / "s.parquet")
    frame.to_csv(tmp_path / "s.csv", index=False)
    a = read_sample_files([tmp_path / "s.parquet"], crs=UTM)
    b = read_sample_files([tmp_path / "s.csv"], crs=UTM)
    np.testing.assert_array_equal(a.samples.xy, b.samples.xy)
    np.testing.assert_array_equal(a.samples.z_var, b.samples.z_var)
    np.testing.assert_allclose(a.samples.z_var, 0.01)


def test_ground_control_from_a_geopackage_as_from_a_csv(tmp_path):
    # A surveyor's GCP layer: the geometry's x, y, Z, a name, a sigma, a note and a field the
    # control reader does not know (dropped); the same ControlPoints as its CSV.
    from factorgraph.control_io import read_control
    from toolkit.point_files import read_control_layer

    xy = _points(6, seed=11)
    z = _surface(*xy.T)
    names = np.array([f"GCP{k}" for k in range(6)])
    gpkg = _layer(
        tmp_path / "gcp.gpkg",
        shapely.points(xy[:, 0], xy[:, 1], z),
        fields={
            "name": names,
            "sigma": np.full(6, 0.02),
            "description": np.array(["rock"] * 6),
            "OBJECTID": np.arange(6),
        },
        geometry_type="Point Z",
    )
    csv = tmp_path / "gcp.csv"
    pd.DataFrame(
        {"id": names, "x": xy[:, 0], "y": xy[:, 1], "z": z, "sigma": 0.02, "crs": UTM}
    ).to_csv(csv, index=False)
    a, b = read_control_layer(gpkg), read_control(csv)
    assert list(a.ids) == list(b.ids)
    np.testing.assert_allclose(a.xyz, b.xyz, atol=1e-9)
    np.testing.assert_allclose(a.sigma, b.sigma)
    assert CRS.from_user_input(a.crs).equals(CRS(UTM)) and a.notes["description"][0] == "rock"


def test_a_dsm_with_voids_is_read_as_its_cells_and_its_voids_are_mapped(tmp_path):
    # A drone DSM (0.05 m noise) with a void: its valid cells are the samples, the void is
    # counted and the map fills it with a 1-sigma larger than over the cells, which holds.
    import rasterio
    from rasterio.transform import from_origin

    xs = X0 + 2.0 * np.arange(60) + 1.0
    ys = Y0 + 120.0 - 2.0 * np.arange(60) - 1.0
    xx, yy = np.meshgrid(xs, ys)
    z = _surface(xx, yy) + np.random.default_rng(12).normal(0, 0.05, xx.shape)
    hole = np.hypot(xx - X0 - 60, yy - Y0 - 60) < 14
    band = np.where(hole, -9999.0, z).astype("float32")
    dsm = tmp_path / "dsm.tif"
    profile = dict(driver="GTiff", width=60, height=60, count=1, dtype="float32", crs=UTM,
                   transform=from_origin(X0, Y0 + 120.0, 2.0, 2.0), nodata=-9999.0)  # fmt: skip
    with rasterio.open(dsm, "w", **profile) as ds:
        ds.write(band, 1)
    table = read_sample_files([dsm])
    assert table.samples.n == (~hole).sum() and table.derived
    assert f"{(~hole).sum():,} cells of 2 x 2 read as samples" in table.note
    assert f"({hole.sum():,} voids, nodata, left to the map)" in table.note
    out = tmp_path / "map"
    r = runner.invoke(app, ["reconstruct", str(dsm), "--resolution", "2", "--out", str(out)])
    assert r.exit_code == 0, r.output
    ds = xr.open_dataset(out / "product.nc")
    std = ds["elevation_std"].values
    err = ds["elevation"].values - _surface(*np.meshgrid(ds["x"].values, ds["y"].values))
    # measured: 1-sigma 0.011 m in the void against 0.006 m over the cells, the void's RMSE
    # 0.0065 m, all of it within 1.96 sigma (a smooth surface: the GP fills it well)
    assert np.median(std[hole]) > 1.5 * np.median(std[~hole])  # the void is less certain
    assert float(np.sqrt(np.mean(err[hole] ** 2))) < 0.05
    assert np.mean(np.abs(err[hole]) <= 1.96 * std[hole]) >= 0.9
    with pytest.raises(InputError, match="not a cloud, a granule or a raster"):
        read_checkpoints(dsm)
