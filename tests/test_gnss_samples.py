"""A GNSS survey's own file as the map's samples (``toolkit.gnss_samples``, ``glacimap
reconstruct profile.gpx``).

The logs are written here with independent writers: GPX by ``gpxpy``, NMEA sentences by
``pynmea2`` (its own checksums), an RTKLIB ``.pos`` by hand after RTKLIB 2.4.3's output
format. References: positions projected by ``pyproj`` directly, heights by hand (ellipsoidal
height minus the antenna height), the kinds' UERE from ``factorgraph.field.fixes``; EGM96's
undulation by pyproj's own CRS transform (WGS 84 3-D to WGS 84 + EGM96 height).
"""

from __future__ import annotations

import datetime as dt

import gpxpy
import gpxpy.gpx
import numpy as np
import pandas as pd
import pynmea2
import pytest
import xarray as xr
from pyproj import Transformer
from typer.testing import CliRunner

from factorgraph.field.fixes import UERE_M, VERTICAL_FACTOR
from terrain import InputError
from toolkit.cli import app
from toolkit.gnss_samples import gnss_format, read_gnss_samples
from toolkit.samples_io import read_samples

UTM = "EPSG:32608"
T0 = dt.datetime(2026, 7, 1, 9, 0, 0, tzinfo=dt.UTC)
TO_LL = Transformer.from_crs(UTM, "EPSG:4326", always_xy=True)
runner = CliRunner()


def _surface(x, y):
    """A tilted plane with a bump (m, UTM 8N)."""
    return (
        1200.0
        + 0.05 * (x - 500_000)
        + 8.0 * np.exp(-((x - 500_150) ** 2 + (y - 6_600_150) ** 2) / 80.0**2)
    )


def _profile(n_lines=4, step=3.0, spacing=100.0, length=300.0):
    """A boustrophedon of north-south lines (UTM 8N, m) at 1 fix per ``step`` m."""
    pts = []
    for i in range(n_lines):
        y = 6_600_000 + np.arange(0.0, length, step)
        pts.append(
            np.column_stack([np.full(y.size, 500_000 + i * spacing), y if i % 2 == 0 else y[::-1]])
        )
    return np.vstack(pts)


def _undulation(lon, lat):
    """EGM96's N (m) by pyproj's own CRS transform (WGS 84 3-D -> WGS 84 + EGM96 height),
    the grid found in the system's PROJ folder: independent of terrain.vertical_datum."""
    import pyproj.datadir

    pyproj.datadir.append_data_dir("/usr/share/proj")
    to_msl = Transformer.from_crs("EPSG:4979", "EPSG:4326+5773", always_xy=True)
    return -np.asarray(to_msl.transform(lon, lat, np.zeros(np.size(lon)))[2])


def _gpx(path, xy, h, hdop=None, vdop=None, sea_level=True):
    """A GPX of ellipsoidal heights ``h`` written as a consumer receiver does: ``ele`` above
    sea level (EGM96), unless ``sea_level`` is False."""
    lon, lat = TO_LL.transform(xy[:, 0], xy[:, 1])
    if sea_level and h[0] is not None:
        h = np.asarray(h, float) - _undulation(lon, lat)
    g = gpxpy.gpx.GPX()
    trk = gpxpy.gpx.GPXTrack()
    seg = gpxpy.gpx.GPXTrackSegment()
    g.tracks.append(trk)
    trk.segments.append(seg)
    for k in range(len(h)):
        p = gpxpy.gpx.GPXTrackPoint(
            lat[k], lon[k], elevation=h[k], time=T0 + dt.timedelta(seconds=k)
        )
        p.type_of_gpx_fix = "3d"
        p.horizontal_dilution, p.vertical_dilution = hdop, vdop
        seg.points.append(p)
    path.write_text(g.to_xml())
    return path


def _pos(path, xy, h, q, sdu, geodetic=False):
    """RTKLIB 2.4.3 llh output, GPST (UTC + 18 s); ``geodetic``: its height line says so."""
    lon, lat = TO_LL.transform(xy[:, 0], xy[:, 1])
    kind = "geodetic" if geodetic else "ellipsoidal"
    lines = [
        "% program   : RTKLIB ver.2.4.3",
        f"% (lat/lon/height=WGS84/{kind},Q=1:fix,2:float,3:sbas,4:dgps,5:single,6:ppp,ns=# of "
        "satellites)",
        "%  GPST                  latitude(deg) longitude(deg)  height(m)   Q  ns   sdn(m)   "
        "sde(m)   sdu(m)  sdne(m)  sdeu(m)  sdun(m) age(s)  ratio",
    ]
    for k in range(len(h)):
        t = T0 + dt.timedelta(seconds=k + 18)
        lines.append(
            f"{t:%Y/%m/%d %H:%M:%S}.000 {lat[k]:14.9f} {lon[k]:14.9f} {h[k]:10.4f} {q[k]:3d}  12"
            f"   0.0100   0.0100 {sdu[k]:8.4f}   0.0000   0.0000   0.0000   1.00   50.0"
        )
    path.write_text("\n".join(lines) + "\n")
    return path


def test_rtklib_fixes_become_samples_in_the_map_crs(tmp_path):
    xy = _profile(n_lines=2, step=10.0)
    h = _surface(*xy.T) + 2.0
    q = np.where(np.arange(len(h)) % 5 == 0, 2, 1)  # every 5th an RTK float
    sdu = np.where(q == 1, 0.02, 0.25)
    s, track, note = read_gnss_samples(_pos(tmp_path / "p.pos", xy, h, q, sdu), UTM, 2.0)
    assert str(s.crs.to_epsg()) == "32608" and s.n == len(h)
    np.testing.assert_allclose(s.xy, xy, atol=2e-3)  # 1e-9 deg in the file: ~0.1 mm
    np.testing.assert_allclose(s.z, h - 2.0, atol=1e-4)
    np.testing.assert_allclose(s.z_var, sdu**2, rtol=1e-6)
    np.testing.assert_allclose(track, np.where(q == 1, 0.0, sdu), rtol=1e-6)  # fixed: independent
    np.testing.assert_allclose(s.extra["t_s"] - T0.timestamp(), np.arange(len(h)), atol=1e-6)
    assert "rtk_fixed 48" in note and "rtk_float 12" in note and "antenna height 2 m" in note


def test_an_emlid_reach_llh_log_is_the_same_solution_without_its_header(tmp_path):
    # Emlid Reach writes its position log (.LLH) as RTKLIB's llh rows in GPS time without
    # the '%' header: the same rows read as the .pos with the header give the same samples.
    xy = _profile(n_lines=2, step=10.0)
    h = _surface(*xy.T) + 2.0
    q = np.where(np.arange(len(h)) % 5 == 0, 2, 1)
    sdu = np.where(q == 1, 0.02, 0.25)
    pos = _pos(tmp_path / "p.pos", xy, h, q, sdu)
    llh = tmp_path / "solution_202607010900.LLH"
    llh.write_text("".join(ln + "\n" for ln in pos.read_text().splitlines() if ln[:1] != "%"))
    assert gnss_format(llh) == "rtklib"
    a, track_a, _ = read_gnss_samples(pos, UTM, 2.0)
    b, track_b, note = read_gnss_samples(llh, UTM, 2.0)
    np.testing.assert_array_equal(b.xy, a.xy)
    np.testing.assert_array_equal(b.z, a.z)
    np.testing.assert_array_equal(b.extra["t_s"], a.extra["t_s"])  # GPST - 18 s, as the header
    np.testing.assert_array_equal(track_b, track_a)
    assert "Emlid Reach .LLH log" in note
    (tmp_path / "odd.LLH").write_text("% GPST x y z\n2026/07/01 09:00:00.000 1 2 3 1 12\n")
    with pytest.raises(InputError, match="odd.LLH header"):
        read_gnss_samples(tmp_path / "odd.LLH", UTM, 2.0)


def test_gpx_without_dop_takes_the_kinds_uere_and_its_utm_zone(tmp_path):
    xy = _profile(n_lines=1, step=10.0)
    h = _surface(*xy.T)
    s, track, note = read_gnss_samples(_gpx(tmp_path / "t.gpx", xy, h))
    sigma = VERTICAL_FACTOR * UERE_M["single"]
    np.testing.assert_allclose(s.z_var, sigma**2)
    np.testing.assert_allclose(track, sigma)  # autonomous: its error wanders in time
    assert s.crs.to_epsg() == 32608  # 135 W: UTM zone 8 north, chosen and said
    assert "the fixes' UTM zone" in note and f"{len(h)} fixes state no vertical 1-sigma" in note
    assert "none given: --antenna-height" in note
    # with DOPs: UERE x VDOP
    s2, _, _ = read_gnss_samples(_gpx(tmp_path / "d.gpx", xy, h, 0.8, 1.4), UTM)
    np.testing.assert_allclose(s2.z_var, (UERE_M["single"] * 1.4) ** 2)


def test_heights_are_carried_to_the_ellipsoid(tmp_path):
    # GPX ele (sea level, as receivers write it) and an RTKLIB solution in geodetic heights
    # get EGM96's N back; an NMEA GGA without its separation is read as stated and counted;
    # --gnss-heights says otherwise. N here (59.5 N, 135 W) is ~ +6.5 m: no small offset.
    xy = _profile(n_lines=1, step=10.0)
    h = _surface(*xy.T)
    lon, lat = TO_LL.transform(xy[:, 0], xy[:, 1])
    n = _undulation(lon, lat)
    assert np.all(np.abs(n) > 3.0)
    s, _, note = read_gnss_samples(_gpx(tmp_path / "msl.gpx", xy, h), UTM)
    np.testing.assert_allclose(s.z, h, atol=2e-4)  # 4-decimal ele
    assert "GPX ele states no datum: read as above EGM96" in note
    assert "--gnss-heights ellipsoidal if they are not" in note
    ell = _gpx(tmp_path / "ell.gpx", xy, h, sea_level=False)
    s, _, note = read_gnss_samples(ell, UTM, heights="ellipsoidal")
    np.testing.assert_allclose(s.z, h, atol=2e-4)
    assert "read as ellipsoidal heights" in note and "pass --gnss-heights" not in note
    sep = _gpx(tmp_path / "sep.gpx", xy, h)  # sea level, and its geoidheight as written
    doc = gpxpy.parse(sep.read_text())
    for p, nk in zip(doc.tracks[0].segments[0].points, n, strict=True):
        p.geoid_height = round(float(nk) + 0.25, 3)  # the receiver's own geoid, 25 cm off
    sep.write_text(doc.to_xml())
    s, _, note = read_gnss_samples(sep, UTM)
    np.testing.assert_allclose(s.z, h + 0.25, atol=2e-3)  # ele + geoidheight, as stated
    assert "states no datum" not in note
    q = np.ones(len(h), int)
    pos = _pos(tmp_path / "geo.pos", xy, h - n, q, np.full(len(h), 0.02), geodetic=True)
    s, _, note = read_gnss_samples(pos, UTM)
    np.testing.assert_allclose(s.z, h, atol=2e-4)
    assert "geodetic heights (its header) taken as above EGM96" in note
    nmea = _nmea(tmp_path / "nosep.nmea", xy, h - n, separation="")
    s, _, note = read_gnss_samples(nmea, UTM)
    np.testing.assert_allclose(s.z, h - n, atol=2e-3)  # as read, and said
    assert f"{len(h)} GGA without a geoid separation states no datum" in note
    s, _, _ = read_gnss_samples(nmea, UTM, heights="egm96")
    np.testing.assert_allclose(s.z, h, atol=2e-3)
    with pytest.raises(InputError, match="--gnss-heights"):
        read_gnss_samples(nmea, UTM, heights="msl")
    csv = tmp_path / "s.csv"
    pd.DataFrame({"x": xy[:, 0], "y": xy[:, 1], "z": h, "crs": UTM}).to_csv(csv, index=False)
    with pytest.raises(InputError, match="--gnss-heights.*a CSV's z is read as given"):
        read_samples(csv, gnss_heights="egm96")


def _nmea(path, xy, h, separation="10.000"):
    """GGA only (no date), RTK fixed, the altitude ``h - separation`` (``""``: none stated)."""
    lon, lat = TO_LL.transform(xy[:, 0], xy[:, 1])
    rows = []
    for k in range(len(h)):
        t = T0 + dt.timedelta(seconds=k)
        la, lo = abs(lat[k]), abs(lon[k])
        alt = h[k] - (float(separation) if separation else 0.0)
        msg = pynmea2.GGA(
            "GP", "GGA",
            (f"{t:%H%M%S}.00", f"{int(la):02d}{(la % 1) * 60:010.7f}", "N" if lat[k] > 0 else "S",
             f"{int(lo):03d}{(lo % 1) * 60:010.7f}", "E" if lon[k] > 0 else "W", "4", "12", "0.7",
             f"{alt:.3f}", "M", separation, "M", "1.0", "0000"),
        )  # fmt: skip
        rows.append(str(msg))
    path.write_text("\n".join(rows) + "\n")
    return path


def test_nmea_without_a_date_reads_relative_times(tmp_path):
    xy = _profile(n_lines=1, step=30.0)
    h = _surface(*xy.T)
    path = _nmea(tmp_path / "log.nmea", xy, h)
    s, track, note = read_gnss_samples(path, UTM, 1.5)
    np.testing.assert_allclose(s.z, h - 1.5, atol=2e-3)  # altitude + geoid separation - antenna
    np.testing.assert_allclose(s.xy, xy, atol=0.01)
    np.testing.assert_allclose(np.diff(s.extra["t_s"]), 1.0)  # UTC of the placeholder day
    assert "no UTC date in the log" in note and np.all(track == 0.0)  # quality 4: RTK fixed
    np.testing.assert_allclose(s.z_var, (VERTICAL_FACTOR * UERE_M["rtk_fixed"] * 0.7) ** 2)


def test_bad_input_names_the_field(tmp_path):
    xy = _profile(n_lines=1, step=50.0)
    gpx = _gpx(tmp_path / "t.gpx", xy, _surface(*xy.T))
    with pytest.raises(InputError, match="--antenna-height"):
        read_gnss_samples(gpx, UTM, -1.0)
    with pytest.raises(InputError, match="--crs"):
        read_gnss_samples(gpx, "EPSG:4326")  # a map needs metres
    csv = tmp_path / "s.csv"
    pd.DataFrame({"x": xy[:, 0], "y": xy[:, 1], "z": 1.0, "crs": UTM}).to_csv(csv, index=False)
    with pytest.raises(InputError, match="--antenna-height.*a CSV's z is the surface's"):
        read_samples(csv, antenna_height_m=1.8)
    assert gnss_format(csv) is None and gnss_format(gpx) == "gpx"
    assert read_samples(gpx, UTM, 0.5).samples.n == len(xy)


def test_cli_maps_a_gpx_profile_and_writes_its_samples(tmp_path):
    xy = _profile()
    rng = np.random.default_rng(0)
    h = _surface(*xy.T) + 1.8 + rng.normal(0, 0.02, len(xy))
    gpx = _gpx(tmp_path / "profile.gpx", xy, h, 0.01, 0.01)  # 2.5 cm x 0.01: precise fixes
    out = tmp_path / "map"
    r = runner.invoke(
        app, ["reconstruct", str(gpx), "--antenna-height", "1.8", "--crs", UTM, "--resolution",
              "10", "--out", str(out)],
    )  # fmt: skip
    assert r.exit_code == 0, r.output
    assert "profile.gpx: gpx log, 400 fixes" in " ".join(r.output.split())
    back = pd.read_csv(out / "samples.csv")
    assert len(back) == len(xy) and set(back["crs"]) == {UTM}
    np.testing.assert_allclose(back["z"], h - 1.8, atol=1e-9)
    ds = xr.open_dataset(out / "product.nc")
    xx, yy = np.meshgrid(ds["x"].values, ds["y"].values)
    inside = (xx > 500_010) & (xx < 500_290) & (yy > 6_600_010) & (yy < 6_600_290)
    err = (ds["elevation"].values - _surface(xx, yy))[inside]
    assert abs(float(np.mean(err))) < 0.3  # the antenna taken off: no 1.8 m offset
    assert float(np.sqrt(np.mean(err**2))) < 1.0
    # the fixes' UTC date is the map's survey date (glacimap change reads it for the rate)
    assert ds.attrs["survey_date"] == "2026-07-01"
    assert ds.attrs["survey_period"] == "2026-07-01/2026-07-01"


def test_a_track_without_heights_and_a_receiver_standing_still(tmp_path):
    xy = _profile(n_lines=1, step=10.0)
    flat = _gpx(tmp_path / "flat.gpx", xy, [None] * len(xy))  # a 2-D track: no <ele>
    with pytest.raises(InputError, match="flat.gpx.*no usable position record.*<ele>"):
        read_gnss_samples(flat, UTM)
    still = np.vstack([xy[:1].repeat(20, axis=0), xy])  # 20 s on the first point first
    s, track, note = read_gnss_samples(_gpx(tmp_path / "s.gpx", still, _surface(*still.T)), UTM)
    assert s.n == len(xy) and track.shape == (s.n,)  # the 21 fixes at one point: one sample
    assert "20 fixes at a repeated position merged" in note


def test_several_days_of_logs_are_one_survey(tmp_path):
    xy = _profile(n_lines=2, step=10.0)
    h = _surface(*xy.T) + 1.8
    day1 = _gpx(tmp_path / "day1.gpx", xy[:30], h[:30], 0.01, 0.01)
    q = np.ones(len(xy) - 30, int)
    day2 = _pos(tmp_path / "day2.pos", xy[30:], h[30:], q, np.full(len(q), 0.02))
    from toolkit.samples_io import read_sample_files

    t = read_sample_files([day1, day2], None, 1.8)
    assert t.samples.n == len(xy) and t.samples.crs.to_epsg() == 32608  # the first's UTM zone
    np.testing.assert_allclose(t.samples.z, h - 1.8, atol=1e-4)
    np.testing.assert_allclose(t.samples.xy, xy, atol=2e-3)
    assert np.all(t.track_z_std[30:] == 0.0) and np.all(t.track_z_std[:30] > 0)  # RTK fixed
    assert "2 files, 60 samples, in EPSG:32608" in t.note
    assert "projected to EPSG:32608 (the CRS of day1.gpx)" in t.note  # not "given"
    csv = tmp_path / "spots.csv"
    pd.DataFrame({"x": xy[:5, 0] + 0.5, "y": xy[:5, 1], "z": h[:5], "crs": "EPSG:32609"}).to_csv(
        csv, index=False
    )
    with pytest.raises(Exception, match="EPSG:32609|32608"):  # a file in another CRS
        read_sample_files([day1, csv], None, None)
    r = runner.invoke(
        app, ["reconstruct", str(day1), str(day2), "--antenna-height", "1.8", "--resolution",
              "20", "--out", str(tmp_path / "m")],
    )  # fmt: skip
    assert r.exit_code == 0, r.output
    assert len(pd.read_csv(tmp_path / "m" / "samples.csv")) == len(xy)


def test_a_gpx_of_waypoints_gives_independent_spot_heights(tmp_path):
    # A handheld receiver's marked waypoints (stakes, spot heights), no track: each with
    # <ele> is a sample, its sea-level height carried to the ellipsoid (EGM96's N by pyproj's
    # own transform), no along-track term; one without <ele> is counted, not used.
    xy = _profile(n_lines=2, step=30.0)
    h = _surface(*xy.T)
    lon, lat = TO_LL.transform(xy[:, 0], xy[:, 1])
    ele = h - _undulation(lon, lat) + 1.0  # held 1 m above the snow
    g = gpxpy.gpx.GPX()
    for k in range(len(h)):
        w = gpxpy.gpx.GPXWaypoint(lat[k], lon[k], elevation=round(float(ele[k]), 3))
        w.horizontal_dilution = 1.2
        g.waypoints.append(w)
    g.waypoints.append(gpxpy.gpx.GPXWaypoint(float(lat[0]) + 0.001, float(lon[0])))  # no ele
    path = tmp_path / "stakes.gpx"
    path.write_text(g.to_xml())
    s, track, note = read_gnss_samples(path, UTM, antenna_height_m=1.0)
    assert s.n == len(h) and not track.any() and "t_s" not in s.extra
    np.testing.assert_allclose(s.z, h, atol=2e-3)
    words = " ".join(note.split())
    assert f"no track, {len(h)} waypoints read as spot heights" in words
    assert "1 waypoints not used {'no_elevation': 1}" in words
    assert "GPX ele states no datum: read as above EGM96" in words
    empty = gpxpy.gpx.GPX()
    empty.waypoints.append(gpxpy.gpx.GPXWaypoint(60.0, -135.0))
    (tmp_path / "bare.gpx").write_text(empty.to_xml())
    with pytest.raises(InputError, match="bare.gpx waypoints.*none with an elevation"):
        read_gnss_samples(tmp_path / "bare.gpx", UTM)
