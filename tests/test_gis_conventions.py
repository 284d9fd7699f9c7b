"""GIS conventions of every product (issue 17), checked with GDAL's own command-line readers on
the written files: the NetCDF CRS as a CF grid_mapping, the vertical datum stated in each
product, and index contours flagged."""

from __future__ import annotations

import json
import re
import shutil
import subprocess

import numpy as np
import pytest
import xarray as xr

from terrain import ElevationSamples, Grid, random_terrain
from terrain.product import VERTICAL_DATUM, terrain_dataset
from toolkit.certify import certify
from toolkit.export import INDEX_EVERY, write_cog, write_contours, write_mesh

BOUNDS = (526000.0, 6475000.0, 526600.0, 6475600.0)  # 600 m x 600 m, UTM 8N
CRS = "EPSG:32608"
gdal = pytest.mark.skipif(shutil.which("gdalinfo") is None, reason="GDAL command-line tools")


def _run(*args: str) -> str:
    return subprocess.run(args, capture_output=True, text=True, check=True, timeout=60).stdout


@pytest.fixture(scope="module")
def product():
    grid = Grid.from_bounds(BOUNDS, 10.0, crs=CRS)
    z = random_terrain(grid, relief=25.0, seed=1).values
    return terrain_dataset(grid, z, np.full(grid.shape, 0.3), {"seed": 1})


@gdal
def test_product_nc_crs_reads_in_gdal_and_back_in_xarray(product, tmp_path):
    nc = tmp_path / "product.nc"
    product.to_netcdf(nc, engine="scipy")  # as glacimap run writes it (NetCDF3)
    info = _run("gdalinfo", f'NETCDF:"{nc}":elevation')
    assert 'PROJCRS["WGS 84 / UTM zone 8N"' in info, info[:600]
    assert _run("gdalsrsinfo", "-o", "epsg", f'NETCDF:"{nc}":elevation').split() == [CRS]
    # the affine transform GDAL reads is the grid's: 10 m cells from the NW corner
    assert "Origin = (526000.000000000000000,6475600.000000000000000)" in info
    assert "Pixel Size = (10.000000000000000,-10.000000000000000)" in info
    back = xr.open_dataset(nc)
    assert back["elevation"].attrs["grid_mapping"] == "spatial_ref"
    assert back["spatial_ref"].attrs["grid_mapping_name"] == "transverse_mercator"
    assert Grid.from_dataarray(back) == Grid.from_dataarray(product)


@gdal
def test_gp_product_carries_the_grid_mapping(tmp_path):
    """The product TerrainGP.predict_grid makes (the one glacimap run exports)."""
    from terrain.gp import TerrainGP

    grid = Grid.from_bounds(BOUNDS, 20.0, crs=CRS)
    truth = random_terrain(grid, relief=25.0, seed=2)
    rng = np.random.default_rng(0)
    xy = rng.uniform([BOUNDS[0] + 20, BOUNDS[1] + 20], [BOUNDS[2] - 20, BOUNDS[3] - 20], (150, 2))
    z = truth.interp(x=("p", xy[:, 0]), y=("p", xy[:, 1])).values
    ds = TerrainGP(seed=0).fit(ElevationSamples(xy, z, 0.05**2, crs=CRS)).predict_grid(grid)
    ds.to_netcdf(tmp_path / "gp.nc", engine="scipy")
    assert _run(
        "gdalsrsinfo", "-o", "epsg", f'NETCDF:"{tmp_path / "gp.nc"}":elevation'
    ).split() == [CRS]
    assert ds.attrs["vertical_datum"] == VERTICAL_DATUM


@gdal
def test_every_product_states_its_vertical_datum(product, tmp_path):
    assert "ellipsoid" in VERTICAL_DATUM and "no geoid" in VERTICAL_DATUM
    product.to_netcdf(tmp_path / "p.nc", engine="scipy")
    assert xr.open_dataset(tmp_path / "p.nc").attrs["vertical_datum"] == VERTICAL_DATUM
    write_cog(product, tmp_path / "e.tif")
    assert f"vertical_datum={VERTICAL_DATUM}" in _run("gdalinfo", str(tmp_path / "e.tif"))
    out = write_contours(product, tmp_path / "c.gpkg", 1.0, tmp_path / "c.geojson")
    assert out["vertical_datum"] == VERTICAL_DATUM
    meta = _run("ogrinfo", "-so", "-al", str(tmp_path / "c.gpkg"))
    assert f"vertical_datum={VERTICAL_DATUM}" in meta
    assert VERTICAL_DATUM in json.loads((tmp_path / "c.geojson").read_text())["description"]
    mesh = write_mesh(product, tmp_path / "m.ply", tmp_path / "m.vtp")
    assert mesh["vertical_datum"] == VERTICAL_DATUM
    header = (tmp_path / "m.ply").read_bytes().split(b"end_header")[0].decode("ascii")
    assert f"comment vertical_datum of z {VERTICAL_DATUM}" in header
    cert = certify(tmp_path / "e.tif", {"x": [526300.0], "y": [6475300.0], "z": [100.0]}, crs=CRS)
    assert cert["dem"]["vertical_datum"] == VERTICAL_DATUM
    # a product that names another datum keeps it everywhere
    other = product.assign_attrs(vertical_datum="EGM2008 geoid (orthometric)")
    write_cog(other, tmp_path / "o.tif")
    assert "vertical_datum=EGM2008 geoid" in _run("gdalinfo", str(tmp_path / "o.tif"))


@gdal
def test_index_contours_round_trip_through_ogrinfo(product, tmp_path):
    out = write_contours(product, tmp_path / "c.gpkg", 1.0)
    text = _run("ogrinfo", "-al", "-q", str(tmp_path / "c.gpkg"))
    feats = re.findall(r"elev \(Real\) = ([-\d.]+)\s+index \(Integer\(Boolean\)\) = (\d)", text)
    assert len(feats) == out["lines"] > 10
    elev = np.array([float(e) for e, _ in feats])
    index = np.array([i == "1" for _, i in feats])
    # every 5th interval counted from 0 m: 100, 105, 110 m ... at a 1 m interval
    assert np.array_equal(index, np.round(elev) % INDEX_EVERY == 0)
    assert index.sum() == out["index_lines"] > 0 and (~index).any()
    out = write_contours(product, tmp_path / "c2.gpkg", 2.5)  # 12.5 m index contours
    text = _run("ogrinfo", "-al", "-q", str(tmp_path / "c2.gpkg"))
    feats = re.findall(r"elev \(Real\) = ([-\d.]+)\s+index \(Integer\(Boolean\)\) = (\d)", text)
    elev = np.array([float(e) for e, _ in feats])
    index = np.array([i == "1" for _, i in feats])
    assert np.array_equal(index, np.isclose(np.mod(elev, 12.5), 0.0))
