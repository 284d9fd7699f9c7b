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
    with pytest.raises(InputError, match="gps crs.*EGM96 \\(EPSG:5773\\)"):
        project_fixes(fixes, "EPSG:4326+5703", "EPSG:32608")  # NAVD88: not a geoid we carry
