"""Ground control points: reading (aliases, sigma columns, any CRS), area and independence
checks (ASPRS 2023), each bad input naming the point."""

from __future__ import annotations

import numpy as np
import pytest
from pyproj import Transformer

from factorgraph.control import ControlPoints, check_in_area, check_independent
from factorgraph.control_io import read_control
from terrain.errors import InputError

UTM = "EPSG:32608"


def _write(tmp_path, text: str, name: str = "gcp.csv"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_read_canonical_columns_and_round_trip(tmp_path):
    path = _write(
        tmp_path,
        "id,x,y,z,sigma_x,sigma_y,sigma_z,target_id,crs\n"
        "A,526100.5,6475100.25,1210.125,0.02,0.03,0.04,17,EPSG:32608\n"
        "B,526500,6475500,1230,0.02,0.02,0.05,,EPSG:32608\n",
    )
    c = read_control(path)
    assert c.ids.tolist() == ["A", "B"] and c.crs == UTM
    np.testing.assert_array_equal(c.xyz[0], [526100.5, 6475100.25, 1210.125])
    np.testing.assert_array_equal(c.sigma, [[0.02, 0.03, 0.04], [0.02, 0.02, 0.05]])
    assert c.target_id.tolist() == [17, -1]
    again = read_control(c.write_csv(tmp_path / "out.csv"))  # the writer's file reads back
    np.testing.assert_array_equal(again.xyz, c.xyz)
    np.testing.assert_array_equal(again.sigma, c.sigma)
    assert again.ids.tolist() == c.ids.tolist() and again.target_id.tolist() == [17, -1]


def test_aliases_sigma_h_and_notes(tmp_path):
    path = _write(
        tmp_path,
        "Name,Easting,Northing,Elevation,sigma_h,sigma_z,Description\n"
        "GCP1,526100,6475100,1210,0.015,0.025,rock cairn\n",
    )
    c = read_control(path, crs=32608)
    assert c.ids.tolist() == ["GCP1"] and c.crs == UTM
    np.testing.assert_array_equal(c.sigma, [[0.015, 0.015, 0.025]])
    assert c.notes == {"description": ["rock cairn"]}


def test_one_sigma_column_and_default_sigma(tmp_path):
    c = read_control(_write(tmp_path, "id,x,y,z,sigma\nP,1,2,3,0.05\n"), crs=UTM)
    np.testing.assert_array_equal(c.sigma, [[0.05, 0.05, 0.05]])
    path = _write(tmp_path, "id,x,y,z\nP,1,2,3\n", "nosigma.csv")
    with pytest.raises(InputError, match="sigma.*sigma_m="):
        read_control(path, crs=UTM)
    c = read_control(path, crs=UTM, sigma_m=(0.01, 0.01, 0.03))
    np.testing.assert_array_equal(c.sigma, [[0.01, 0.01, 0.03]])


def test_geographic_file_reprojects_to_the_map_crs(tmp_path):
    """Reference: pyproj's own EPSG:4326 -> EPSG:32608 transform (independent of the reader's
    column handling: lat/lon given in the file in that order)."""
    e, n = 526100.0, 6475100.0
    lon, lat = Transformer.from_crs(UTM, "EPSG:4326", always_xy=True).transform(e, n)
    path = _write(tmp_path, f"point,lat,lon,h,sigma\nG,{lat!r},{lon!r},1210.0,0.02\n")
    c = read_control(path, crs="EPSG:4326")
    utm = c.to_crs(UTM)
    np.testing.assert_allclose(utm.xyz[0], [e, n, 1210.0], atol=1e-6)
    assert utm.crs == UTM and c.to_crs(c.crs) is c
    # ~ 58.4 deg N, 135 deg W: the Juneau Icefield (UTM 8N)
    assert 58 < lat < 59 and -136 < lon < -134


def test_unknown_column_says_did_you_mean(tmp_path):
    path = _write(tmp_path, "id,x,y,z,sigma_zz\nP,1,2,3,0.1\n")
    with pytest.raises(InputError, match="sigma_zz.*did you mean 'sigma_z'"):
        read_control(path, crs=UTM)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("id,x,y\nP,1,2\n", r"columns \['z'\]"),
        ("id,x,y,z,sigma\nP,1,2,3,0\n", "'P' sigma"),
        ("id,x,y,z,sigma\nP,1,2,3,0.1\nP,4,5,6,0.1\n", "unique"),
        ("id,x,y,z,sigma\nP,1,2,abc,0.1\n", "line 2 z"),
        ("id,x,y,z,sigma\n", "at least|header"),
    ],
)
def test_bad_files_name_the_problem(tmp_path, text, match):
    with pytest.raises(InputError, match=match):
        read_control(_write(tmp_path, text), crs=UTM)


def test_missing_crs_and_bad_crs(tmp_path):
    path = _write(tmp_path, "id,x,y,z,sigma\nP,1,2,3,0.1\n")
    with pytest.raises(InputError, match="crs"):
        read_control(path)
    with pytest.raises(InputError, match="control.crs"):
        read_control(path, crs="EPSG:999999")


def test_outside_the_map_names_the_point():
    c = ControlPoints(["in", "far"], [[10, 10, 0], [900, 10, 0]], 0.02, UTM)
    check_in_area(ControlPoints(["in"], [[10, 10, 0]], 0.02, UTM), (0, 0, 100, 100))
    with pytest.raises(InputError, match="'far'.*1 of 2 outside"):
        check_in_area(c, (0, 0, 100, 100))


def test_checkpoints_must_be_independent_of_control():
    c = ControlPoints(["A", "B"], [[0, 0, 0], [100, 0, 0]], 0.02, UTM)
    check_independent(c, {"x": [50.0, 0.0], "y": [0.0, 0.6], "id": ["C1", "C2"]})  # 0.6 m away
    with pytest.raises(InputError, match="'B'.*ASPRS 2023"):
        check_independent(c, {"x": [50.0], "y": [0.0], "id": ["B"]})
    with pytest.raises(InputError, match="0.300 m from control point 'A'"):
        check_independent(c, {"x": [50.0, 0.3], "y": [0.0, 0.0]})
    # another CRS: the same ground point in lon/lat is still the same point
    lon, lat = Transformer.from_crs(UTM, "EPSG:4326", always_xy=True).transform(526000, 6475000)
    c2 = ControlPoints(["A"], [[526000, 6475000, 0]], 0.02, UTM)
    with pytest.raises(InputError, match="'A'"):
        check_independent(c2, {"x": [lon], "y": [lat], "crs": "EPSG:4326"}, tol_m=0.01)


def test_control_point_validation():
    with pytest.raises(InputError, match="'Q' x/y/z"):
        ControlPoints(["Q"], [[np.nan, 0, 0]], 0.02, UTM)
    with pytest.raises(InputError, match="centring"):
        ControlPoints(["Q"], [[0, 0, 0]], 0.02, UTM, centring_sigma_m=-1)
