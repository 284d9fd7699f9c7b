"""ICESat-2 ATL06 granules as samples: a file written here in ATL06's layout (groups
``gtXx/land_ice_segments`` with ``latitude``, ``longitude``, ``h_li``, ``h_li_sigma``,
``sigma_geo_h``, ``atl06_quality_summary``; the fill value 3.4028235e38, as NSIDC's
product files carry them), read back through the CLI's reader."""

import h5py
import numpy as np
import pandas as pd
import pytest
from pyproj import CRS, Transformer
from typer.testing import CliRunner

from terrain.errors import InputError
from toolkit.cli import app
from toolkit.samples_io import read_sample_files, samples_height_attrs

runner = CliRunner()
FILL = np.float32(3.4028235e38)
UTM = "EPSG:32632"  # 61 N, 7.2 E: a Norwegian ice cap


def _surface(x, y):
    return 1500 + 0.02 * (x - 400_000) - 0.01 * (y - 6_760_000) + 4 * np.sin(y / 300.0)


def _granule(path, lat0=61.0, lon0=7.2, beams=("gt1l", "gt1r", "gt2l", "gt3r"), seed=0):
    """Segments every 20 m along north-bound tracks 90 m (pairs) and 3.3 km apart."""
    rng = np.random.default_rng(seed)
    to_utm = Transformer.from_crs("EPSG:4326", UTM, always_xy=True)
    x0, y0 = to_utm.transform(lon0, lat0)
    rows = {}
    with h5py.File(path, "w") as f:
        for k, beam in enumerate(beams):
            pair, side = int(beam[2]) - 1, beam[3]
            x = x0 + pair * 3300.0 + (90.0 if side == "r" else 0.0)
            y = y0 + np.arange(0, 4000.0, 20.0)
            lon, lat = Transformer.from_crs(UTM, "EPSG:4326", always_xy=True).transform(
                np.full(y.size, x), y
            )
            sigma = np.full(y.size, 0.03)
            h = _surface(x, y) + rng.normal(0, 0.03, y.size)
            quality = np.zeros(y.size, np.int8)
            quality[k::17] = 1  # flagged segments
            h = h.astype(np.float32)
            h[5 + k :: 23] = FILL  # no height
            seg = f.create_group(f"{beam}/land_ice_segments")
            seg["latitude"], seg["longitude"] = lat, lon
            seg["h_li"] = h
            seg["h_li"].attrs["_FillValue"] = FILL
            seg["h_li_sigma"] = sigma.astype(np.float32)
            seg["sigma_geo_h"] = np.full(y.size, 0.04, np.float32)
            seg["atl06_quality_summary"] = quality
            rows[beam] = (quality, h)
    return path, rows


def test_good_segments_become_samples_in_their_utm_zone(tmp_path):
    path, rows = _granule(tmp_path / "ATL06_20200101_01230605_006_01.h5")
    table = read_sample_files([path])
    total = sum(q.size for q, _ in rows.values())
    flagged = sum(int((q != 0).sum()) for q, _ in rows.values())
    missing = sum(int(((q == 0) & (h >= 1e38)).sum()) for q, h in rows.values())
    assert table.samples.n == total - flagged - missing and table.derived
    assert table.samples.crs.equals(CRS(UTM))
    note = " ".join(table.note.split())
    assert f"{total:,} segments, {total - flagged - missing:,} kept" in note
    assert f"left out {flagged} flagged by atl06_quality_summary" in note
    assert f"left out {missing} without a height" in note
    # hand value: 0.03^2 + 0.04^2 = 0.0025 m^2 (0.05 m)
    np.testing.assert_allclose(table.samples.z_var, 0.0025, rtol=1e-6)
    err = table.samples.z - _surface(*table.samples.xy.T)
    assert abs(err.mean()) < 0.01 and err.std() < 0.05  # float32 heights, 0.03 m noise
    assert samples_height_attrs([path], None) == {}  # on the ellipsoid, as GNSS logs


def test_polar_granules_need_a_crs_and_bad_files_are_named(tmp_path):
    polar, _ = _granule(tmp_path / "polar.h5", lat0=-82.0, lon0=170.0, beams=("gt2l",))
    with pytest.raises(InputError, match="--crs.*EPSG:3031"):
        read_sample_files([polar])
    table = read_sample_files([polar], crs="EPSG:3031")
    assert table.samples.crs.equals(CRS("EPSG:3031"))
    with pytest.raises(InputError, match="projected CRS"):
        read_sample_files([polar], crs="EPSG:4326")
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f["data"] = np.arange(3)
    with pytest.raises(InputError, match="ATL06 granule"):
        read_sample_files([other])
    bad = tmp_path / "broken.h5"
    bad.write_bytes(b"not hdf5")
    with pytest.raises(InputError, match="HDF5 file h5py reads"):
        read_sample_files([bad])


def test_cli_maps_a_granule_and_writes_its_samples(tmp_path):
    path, _ = _granule(tmp_path / "ATL06.h5")
    out = tmp_path / "map"
    r = runner.invoke(app, ["reconstruct", str(path), "--resolution", "100", "--out", str(out)])
    assert r.exit_code == 0, r.output
    assert "ICESat-2 ATL06, beams gt1l, gt1r, gt2l, gt3r" in " ".join(r.output.split())
    back = pd.read_csv(out / "samples.csv")
    assert set(back["crs"]) == {UTM} and (back["z_var"] > 0).all()
