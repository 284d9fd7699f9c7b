"""Checkpoint heights in the certified DEM's vertical datum (``toolkit.certify_heights``).

A DEM in EGM96 heights (its compound CRS says so) over a flat 100 m site and GNSS
checkpoints on the ellipsoid (100 m + N, N by pyproj's own CRS transform WGS 84 3-D ->
WGS 84 + EGM96): carried to the DEM's datum the RMSE is 0; compared as stored it is |N|.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from _rasters import write_array
from pyproj import Transformer
from rasterio.transform import from_origin
from typer.testing import CliRunner

from terrain import InputError
from toolkit.certify import certify
from toolkit.cli import app

XY = np.array([[500100.0, 6600100.0], [500200.0, 6600200.0], [500300.0, 6600300.0],
               [500150.0, 6600400.0], [500250.0, 6600050.0], [500420.0, 6600440.0]])  # fmt: skip


def _n(lon, lat):
    import pyproj.datadir

    pyproj.datadir.append_data_dir("/usr/share/proj")
    to_msl = Transformer.from_crs("EPSG:4979", "EPSG:4326+5773", always_xy=True)
    return -np.asarray(to_msl.transform(lon, lat, np.zeros(len(lon)))[2])


@pytest.fixture()
def site(tmp_path):
    dem = write_array(tmp_path / "dem_egm96.tif", np.full((50, 50), 100.0),
                      from_origin(500000, 6600500, 10, 10), "EPSG:32608+5773")  # fmt: skip
    lon, lat = Transformer.from_crs("EPSG:32608", "EPSG:4326", always_xy=True).transform(*XY.T)
    h = 100.0 + _n(lon, lat)  # ellipsoidal heights of the DEM's surface
    geo = tmp_path / "cps_4979.csv"  # lon, lat, h: a 3-D geographic CRS states ellipsoidal
    pd.DataFrame({"lon": lon, "lat": lat, "h": h, "crs": "EPSG:4979"}).to_csv(geo, index=False)
    utm = tmp_path / "cps_utm.csv"  # the same in UTM: no datum stated
    table = {"x": XY[:, 0], "y": XY[:, 1], "z": h, "crs": "EPSG:32608"}
    pd.DataFrame(table).to_csv(utm, index=False)
    return dem, geo, utm, h - 100.0


def test_checkpoints_on_the_ellipsoid_are_carried_to_the_dems_geoid(site):
    dem, geo, utm, n = site
    assert np.all(n > 5.0)
    c = certify(dem, geo, n_boot=50)
    assert c["accuracy"]["rmse_m"] == pytest.approx(0.0, abs=1e-6)
    h = c["checkpoints"]["heights"]
    assert (h["dem"], h["checkpoints"]) == ("egm96", "ellipsoidal")
    assert h["shift_m"] == pytest.approx(-n.mean(), abs=1e-6)
    assert c["dem"]["vertical_datum"] == "heights above egm96"
    c = certify(dem, utm, n_boot=50)  # the checkpoints say nothing: compared as stored
    assert c["accuracy"]["rmse_m"] == pytest.approx(np.sqrt(np.mean(n**2)), rel=1e-6)
    assert (
        "the checkpoints state no vertical datum; taken as above EGM96"
        in (c["checkpoints"]["heights"]["note"])
    )
    c = certify(dem, utm, n_boot=50, checkpoint_heights="ellipsoidal")
    assert c["accuracy"]["rmse_m"] == pytest.approx(0.0, abs=1e-6)
    with pytest.raises(InputError, match="--checkpoint-heights.*checkpoints state.*ellipsoidal"):
        certify(dem, geo, checkpoint_heights="egm96")
    with pytest.raises(InputError, match="--dem-heights.*DEM state.*egm96"):
        certify(dem, utm, dem_heights="ellipsoidal")


def test_cli_certify_says_the_heights(site, tmp_path):
    dem, _, utm, _ = site
    r = CliRunner().invoke(
        app, ["certify", str(dem), str(utm), "--checkpoint-heights", "ellipsoidal", "--n-boot",
              "50", "--out", str(tmp_path / "c.json")],
    )  # fmt: skip
    assert r.exit_code == 0, r.output
    assert "checkpoint heights above the WGS 84 ellipsoid carried to the DEM's (EGM96)" in (
        " ".join(r.output.split())
    )
    r = CliRunner().invoke(app, ["certify", str(dem), str(utm), "--checkpoint-heights", "msl",
                                 "--out", str(tmp_path / "never.json")])  # fmt: skip
    assert isinstance(r.exception, InputError) and not (tmp_path / "never.json").exists()
