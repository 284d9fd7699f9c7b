"""GPS files as other tools write them (tried as a new user would, issue 17): RTKLIB in every
solution format, NMEA from loggers and receivers without RMC, GPX tracks in any order.

Each reader must give back the fixes the file was written from (to the file's rounding), or
count what it cannot use, or refuse with one InputError naming the field and the fix.
"""

from __future__ import annotations

import datetime as dt
import math
from pathlib import Path

import numpy as np
import pytest
from pyproj import Transformer

from factorgraph.field.gpx import read_gpx
from factorgraph.field.nmea import read_nmea
from factorgraph.field.rtklib import gps_utc_leap_s, read_rtklib
from terrain.errors import InputError

#: 20 fixes on a 2 s clock near the default site (58.42 N, 134.55 W), from 2026-07-01 20:00 UTC.
N = 20
T0 = dt.datetime(2026, 7, 1, 20, 0, tzinfo=dt.UTC).timestamp()
UTC = T0 + 2.0 * np.arange(N)
LAT = 58.4170 + 1e-5 * np.arange(N)
LON = -134.5486 + 2e-5 * np.arange(N)
H = 100.0 + 0.1 * np.arange(N)
TO_ECEF = Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)


def _sd_row() -> str:
    return " ".join(f"{v:8.4f}" for v in (0.01, 0.01, 0.02, 0, 0, 0)) + "   0.00  999.9"


def _gpst(t: float) -> str:
    return (dt.datetime.fromtimestamp(t + 18, dt.UTC)).strftime("%Y/%m/%d %H:%M:%S.000")


def _columns(layout: str) -> str:
    sd = {
        "llh": "sdn(m) sde(m) sdu(m)",
        "xyz": "sdx(m) sdy(m) sdz(m)",
        "enu": "sde(m) sdn(m) sdu(m)",
    }[layout]
    pos = {
        "llh": "latitude(deg) longitude(deg) height(m)",
        "xyz": "x-ecef(m) y-ecef(m) z-ecef(m)",
        "enu": "e-baseline(m) n-baseline(m) u-baseline(m)",
    }[layout]
    return f"{pos}   Q  ns {sd}"


def _write(path: Path, layout: str, pos: np.ndarray, header: str = "", times=None) -> Path:
    times = [_gpst(t) for t in UTC] if times is None else times
    rows = [f"{times[i]} {p[0]:15.4f} {p[1]:15.4f} {p[2]:12.4f}   1  12 {_sd_row()}" for i, p in
            enumerate(pos)]  # fmt: skip
    text = "% program   : RTKPOST ver.2.4.3 b34\n" + header
    text += f"%  GPST                  {_columns(layout)}  sdxy(m) sdyz(m) sdzx(m) age(s) ratio\n"
    path.write_text(text + "\n".join(rows) + "\n")
    return path


def test_rtklib_ecef_solution_is_read_as_wgs84_llh(tmp_path):
    x, y, z = TO_ECEF.transform(LON, LAT, H)
    f = read_rtklib(_write(tmp_path / "xyz.pos", "xyz", np.column_stack([x, y, z])))
    assert f.utc_s.size == N and not f.skipped
    np.testing.assert_allclose(f.utc_s, UTC)  # GPST - 18 s
    # the 1e-4 m ECEF rounding: below 2e-9 deg (0.2 mm) and 1e-4 m in height
    np.testing.assert_allclose(f.lat_deg, LAT, atol=2e-9)
    np.testing.assert_allclose(f.lon_deg, LON, atol=4e-9)
    np.testing.assert_allclose(f.h_m, H, atol=2e-4)
    # sdx = sdy = 0.01, sdz = 0.02 m, no cross terms, rotated to E, N, U: E only sees x, y
    # (0.01 m); N and U mix z in by the latitude (invariant: the trace is kept)
    assert f.sigma[0, 0] == pytest.approx(0.01, abs=1e-6)
    assert np.sum(f.sigma[0] ** 2) == pytest.approx(0.01**2 + 0.01**2 + 0.02**2, rel=1e-9)
    assert f.sigma[0, 2] > f.sigma[0, 1] > 0.01  # U is nearer the z axis at 58 N


def test_rtklib_enu_baseline_needs_and_uses_the_ref_pos(tmp_path):
    lat0, lon0, h0 = 58.40, -134.50, 80.0
    base = np.array(TO_ECEF.transform(lon0, lat0, h0))
    la, lo = math.radians(lat0), math.radians(lon0)
    rot = np.array(
        [
            [-math.sin(lo), math.cos(lo), 0],
            [-math.sin(la) * math.cos(lo), -math.sin(la) * math.sin(lo), math.cos(la)],
            [math.cos(la) * math.cos(lo), math.cos(la) * math.sin(lo), math.sin(la)],
        ]
    )
    enu = (np.column_stack(TO_ECEF.transform(LON, LAT, H)) - base) @ rot.T
    ref = f"% ref pos   :  {lat0:.9f} {lon0:.9f}    {h0:.4f}\n"
    f = read_rtklib(_write(tmp_path / "enu.pos", "enu", enu, header=ref))
    np.testing.assert_allclose(f.lat_deg, LAT, atol=2e-9)
    np.testing.assert_allclose(f.lon_deg, LON, atol=4e-9)
    np.testing.assert_allclose(f.h_m, H, atol=2e-4)
    np.testing.assert_allclose(f.sigma[0], [0.01, 0.01, 0.02])  # sde sdn sdu as written
    with pytest.raises(InputError, match=r"enu2.pos ref pos.*out-outhead"):
        read_rtklib(_write(tmp_path / "enu2.pos", "enu", enu))


def test_rtklib_gps_week_seconds_and_dms(tmp_path):
    weeks = [divmod(t + 18 - 315964800.0, 604800.0) for t in UTC]  # GPS epoch 1980-01-06
    times = [f"{int(w)} {s:11.3f}" for w, s in weeks]
    llh = np.column_stack([LAT, LON, H])
    f = read_rtklib(_write(tmp_path / "week.pos", "llh", llh, times=times))
    np.testing.assert_allclose(f.utc_s, UTC)
    np.testing.assert_allclose(f.lat_deg, LAT, atol=1e-4)  # the writer's %15.4f

    def dms(v):
        a = abs(v)
        d, m = int(a), int((a - int(a)) * 60)
        return f"{'-' if v < 0 else ''}{d} {m:02d} {((a - d) * 60 - m) * 60:09.6f}"

    rows = [
        f"{_gpst(UTC[i])} {dms(LAT[i])} {dms(LON[i])} {H[i]:10.4f}   5  12 {_sd_row()}"
        for i in range(N)
    ]
    path = tmp_path / "dms.pos"
    path.write_text(
        "%  GPST                  latitude(d'\")  longitude(d'\")  height(m)   Q  ns   sdn(m)"
        "   sde(m)   sdu(m)  sdne(m)  sdeu(m)  sdun(m) age(s)  ratio\n" + "\n".join(rows) + "\n"
    )
    f = read_rtklib(path)
    np.testing.assert_allclose(f.lat_deg, LAT, atol=1e-9)  # 1e-6 arc-seconds
    np.testing.assert_allclose(f.lon_deg, LON, atol=1e-9)
    assert set(f.quality) == {"single"}


def test_rtklib_leap_seconds_by_date_and_unknown_header(tmp_path):
    # IERS Bulletin C: GPS - UTC = 17 s during 2016, 18 s from 2017-01-01, 13 s in 2005
    gpst = dt.datetime(2016, 12, 31, 23, 59, 59, tzinfo=dt.UTC).timestamp()
    assert gps_utc_leap_s(gpst) == 17
    assert gps_utc_leap_s(gpst + 20) == 18
    assert gps_utc_leap_s(dt.datetime(2005, 6, 1, tzinfo=dt.UTC).timestamp()) == 13
    path = tmp_path / "odd.pos"
    path.write_text("%  GPST  foo(m) bar(m) baz(m) Q ns\n2026/07/01 20:00:00.000 1 2 3 1 5\n")
    with pytest.raises(InputError, match=r"odd.pos header.*foo\(m\).*out-outhead"):
        read_rtklib(path)


def _cs(body: str) -> str:
    c = 0
    for ch in body:
        c ^= ord(ch)
    return f"${body}*{c:02X}"


def _gga(t: float, i: int, talker: str = "GN") -> str:
    tod = dt.datetime.fromtimestamp(t, dt.UTC).strftime("%H%M%S.00")
    lat, lon = abs(LAT[i]), abs(LON[i])
    la = f"{int(lat):02d}{(lat - int(lat)) * 60:010.7f}"
    lo = f"{int(lon):03d}{(lon - int(lon)) * 60:010.7f}"
    return _cs(f"{talker}GGA,{tod},{la},N,{lo},W,1,12,1.00,{H[i]:.4f},M,0.0,M,,")


def _zda(t: float) -> str:
    d = dt.datetime.fromtimestamp(t, dt.UTC)
    return _cs(f"GPZDA,{d:%H%M%S}.00,{d:%d},{d:%m},{d:%Y},00,00")


def _rmc(t: float) -> str:
    d = dt.datetime.fromtimestamp(t, dt.UTC)
    return _cs(f"GNRMC,{d:%H%M%S}.00,A,5825.0,N,13433.0,W,,,{d:%d%m%y},,,A")


def test_nmea_date_from_zda_and_logger_prefixes(tmp_path):
    lines = []
    for i in range(N):  # a Trimble-style log: GGA + ZDA, no RMC, GP and GN talkers mixed
        lines += [_gga(UTC[i], i, "GP" if i % 2 else "GN"), _zda(UTC[i])]
    path = tmp_path / "zda.nmea"
    path.write_text("\r\n".join(lines) + "\r\n\r\n")  # CRLF and a trailing empty line
    f = read_nmea(path)
    np.testing.assert_allclose(f.utc_s, UTC)
    np.testing.assert_allclose(f.lat_deg, LAT, atol=2e-10)
    stamped = [f"2026-07-01T20:00:{i:02d}Z  {ln}" for i, ln in enumerate(lines)]
    path.write_text("\n".join(stamped) + "\n")  # a data logger's time stamp before each line
    g = read_nmea(path)
    np.testing.assert_allclose(g.utc_s, UTC)
    path.write_text("time,lat,lon\n1,2,3\n")
    with pytest.raises(InputError, match=r"NMEA sentences.*Fix: export the receiver"):
        read_nmea(path)


def test_nmea_log_started_before_midnight_without_a_date_yet(tmp_path):
    # 20 fixes from 23:59:50 UTC; the first RMC comes only after midnight (the first 6 GGA
    # have no date yet): they belong to the day before the RMC's date.
    t0 = dt.datetime(2026, 7, 2, tzinfo=dt.UTC).timestamp() - 10.0
    t = t0 + 2.0 * np.arange(N)
    lines = [_gga(t[i], i) for i in range(6)]
    for i in range(6, N):
        lines += [_rmc(t[i]), _gga(t[i], i)]
    path = tmp_path / "midnight.nmea"
    path.write_text("\n".join(lines) + "\n")
    f = read_nmea(path)
    np.testing.assert_allclose(f.utc_s, t)
    assert not f.skipped


def _corrupt(line: str, field: int, text: str) -> str:
    """``line`` with comma field ``field`` (0 = the address) replaced, checksum recomputed: a
    receiver's own garbage, which a checksum does not catch."""
    parts = line[1 : line.index("*")].split(",")
    parts[field] = text
    return _cs(",".join(parts))


@pytest.mark.parametrize(
    ("field", "text", "reason"),
    [(1, "20a000.00", "bad_time"), (2, "58x5.0", "bad_position"), (3, "", "bad_position")],
    ids=["time", "latitude digits", "no hemisphere letter"],
)
def test_nmea_malformed_gga_fields_are_counted_not_fatal(tmp_path, field, text, reason):
    """A malformed time of day crashed the reader (pynmea2 returns the raw text when its
    conversion fails: "'str' object has no attribute 'hour'"), malformed latitude digits
    raised a bare ValueError, and a missing N/S letter put the fix on the equator (pynmea2's
    ``latitude`` reads it as 0 degrees)."""
    lines = [_rmc(UTC[0])] + [_gga(UTC[i], i) for i in range(N)]
    lines[5] = _corrupt(lines[5], field, text)
    lines.insert(0, _corrupt(_rmc(UTC[0]), 1, "20x000.00"))  # a dated RMC, malformed time
    path = tmp_path / "bad.nmea"
    path.write_text("\n".join(lines) + "\n")
    f = read_nmea(path)
    assert f.skipped == {reason: 1}
    keep = np.arange(N) != 4
    np.testing.assert_allclose(f.utc_s, UTC[keep])
    np.testing.assert_allclose(f.lat_deg, LAT[keep], atol=2e-10)
    np.testing.assert_allclose(f.lon_deg, LON[keep], atol=2e-10)


class _Trap(str):
    """Field text whose reading raises KeyboardInterrupt: a Ctrl-C landing in the conversion."""

    def __getitem__(self, key):
        raise KeyboardInterrupt


def test_nmea_ctrl_c_during_field_conversion_is_not_swallowed(tmp_path, monkeypatch):
    """pynmea2 converts fields lazily inside a bare ``except:`` that returns the raw text on
    any error: a Ctrl-C there was lost, and `glacimap run` went on to write its products
    (tests/test_cli_signals.py failed about one run in five). The reader must let it out."""
    import pynmea2

    real_parse = pynmea2.parse

    def parse(line, check=False):
        s = real_parse(line, check=check)
        if s.sentence_type == "GGA":
            s.data[0] = _Trap(s.data[0])  # the time of day
        return s

    monkeypatch.setattr(pynmea2, "parse", parse)
    path = tmp_path / "gps.nmea"
    path.write_text("\n".join([_rmc(UTC[0])] + [_gga(UTC[i], i) for i in range(N)]) + "\n")
    with pytest.raises(KeyboardInterrupt):
        read_nmea(path)


def test_gpx_tracks_in_any_order_and_a_track_without_heights(tmp_path):
    def seg(idx, ele=True):
        pts = []
        for i in idx:
            when = dt.datetime.fromtimestamp(UTC[i], dt.timezone(dt.timedelta(hours=1)))
            e = f"<ele>{H[i]:.3f}</ele>" if ele else ""
            pts.append(
                f'<trkpt lat="{LAT[i]:.9f}" lon="{LON[i]:.9f}">{e}'
                f"<time>{when.isoformat()}</time></trkpt>"  # +01:00, not Z
            )
        return "<trkseg>" + "".join(pts) + "</trkseg>"

    def gpx(body):
        return (
            '<?xml version="1.0"?><gpx version="1.0" creator="qa" '
            f'xmlns="http://www.topografix.com/GPX/1/0">{body}</gpx>'
        )

    path = tmp_path / "newest_first.gpx"  # the newest track first, as many devices write
    path.write_text(
        gpx(f"<trk>{seg(range(12, N))}</trk><trk>{seg(range(6))}{seg(range(6, 12))}</trk>")
    )
    f = read_gpx(path)
    assert not f.skipped  # before: 8 of 20 fixes counted as backwards_time
    np.testing.assert_allclose(f.utc_s, UTC)
    np.testing.assert_allclose(f.h_m, H)
    path.write_text(gpx(f"<trk>{seg(range(N), ele=False)}</trk>"))
    with pytest.raises(InputError, match=r"no_elevation.*Fix: export the track with heights"):
        read_gpx(path)


def test_rover_tables_from_a_european_spreadsheet(tmp_path):
    """odometry, tilt and tracks saved with ';', a decimal comma and CRLF read back the same
    log as the example folder's plain CSV (17 significant digits survive the comma)."""
    import shutil

    from factorgraph import read_field_log

    example = Path(__file__).resolve().parents[1] / "docs" / "examples" / "field"
    folder = tmp_path / "field"
    shutil.copytree(example, folder)
    for name in ("odometry.csv", "tilt.csv", "tracks.csv"):
        lines = (folder / name).read_text().splitlines()
        lines = [ln.replace(",", ";").replace(".", ",") for ln in lines]
        (folder / name).write_bytes(("\r\n".join(lines) + "\r\n").encode("cp1252"))
    ref, _ = read_field_log(example)
    log, rep = read_field_log(folder)  # before: "columns [...] too" on the first table
    np.testing.assert_array_equal(log.t, ref.t)
    np.testing.assert_array_equal(log.odometry, ref.odometry)
    np.testing.assert_array_equal(log.tilt_up, ref.tilt_up)
    np.testing.assert_array_equal(log.obs_uv, ref.obs_uv)
    assert rep.tilt == "used"


def test_gps_file_recognised_by_its_content(tmp_path):
    """A logger's NMEA saved as ``.txt`` (no gps entry in survey.json), and an RTKLIB solution
    named in gps.file without gps.format: found and read by content (before: "exactly one of
    *.nmea, ..." and "gps.format ... got None")."""
    import json
    import shutil

    from factorgraph import read_field_log

    example = Path(__file__).resolve().parents[1] / "docs" / "examples" / "field"
    folder = tmp_path / "field"
    shutil.copytree(example, folder)
    (folder / "gps.nmea").rename(folder / "rover_log.txt")
    man = json.loads((folder / "survey.json").read_text())
    man.pop("gps")
    (folder / "survey.json").write_text(json.dumps(man))
    log, rep = read_field_log(folder)
    assert rep.gps_file == "rover_log.txt" and rep.gps_format == "nmea" and rep.gps_used == 156
    x, y, z = TO_ECEF.transform(LON, LAT, H)
    _write(tmp_path / "solution.txt", "xyz", np.column_stack([x, y, z]))
    from factorgraph.field.reader import sniff_gps_format

    assert sniff_gps_format(tmp_path / "solution.txt") == "rtklib"
    assert sniff_gps_format(folder / "odometry.csv") is None


def test_map_crs_far_from_the_survey_is_a_warning():
    """UTM 33N (12-18 E) for a site at 134.5 W projects, with a 3.7 % scale error (pyproj
    get_factors): said in words with the site's zone; the site's own zone and a polar
    stereographic CRS within its area, or the next zone (0.09 %) say nothing."""
    from factorgraph.field.fixes import crs_area_warning

    msg = crs_area_warning(LON, LAT, "EPSG:32633")
    assert "EPSG:32633's area of use (12 to 18 E" in msg and "off by 3.7 %" in msg
    assert msg.endswith("the site's UTM zone is EPSG:32608")
    assert crs_area_warning(LON, LAT, "EPSG:32608") is None
    assert crs_area_warning(LON, LAT, "EPSG:32609") is None  # 2.5 deg past its edge: 0.09 %
    assert crs_area_warning(LON, LAT, "EPSG:3338") is None  # Alaska Albers (crosses 180)
    assert crs_area_warning(LON, LAT + 15.0, "EPSG:3413") is None  # 73 N, polar stereo


def test_survey_without_a_crs_names_the_sites_utm_zone(tmp_path):
    import json
    import shutil

    from factorgraph import read_field_log

    example = Path(__file__).resolve().parents[1] / "docs" / "examples" / "field"
    folder = tmp_path / "field"
    shutil.copytree(example, folder)
    man = json.loads((folder / "survey.json").read_text())
    man.pop("crs")
    (folder / "survey.json").write_text(json.dumps(man))
    # before: "Fix: pass crs= or set crs in survey.json" (glacimap process has no --crs)
    with pytest.raises(InputError, match=r'survey.json crs.*add "crs": "EPSG:32608"'):
        read_field_log(folder)
    assert read_field_log(folder, crs="EPSG:32608")[0].crs == "EPSG:32608"


def test_ambiguous_clock_says_what_to_write(tmp_path):
    """The example folder without clock_offset_s: the course fit is ambiguous (two turns of
    consumer GPS, docs/field-format.md), and the error gives the survey.json fix a CLI user
    can apply (before: "in survey.json or as an argument", process has no such argument)."""
    import json
    import shutil

    from factorgraph import read_field_log

    example = Path(__file__).resolve().parents[1] / "docs" / "examples" / "field"
    folder = tmp_path / "field"
    shutil.copytree(example, folder)
    man = json.loads((folder / "survey.json").read_text())
    truth = man.pop("clock_offset_s")
    (folder / "survey.json").write_text(json.dumps(man))
    with pytest.raises(InputError, match=rf'"clock_offset_s".*0 when.*about {truth:.0f} \('):
        read_field_log(folder)


ROS_CAMERA = """image_width: 640
image_height: 480
camera_name: narrow_stereo
camera_matrix:
  rows: 3
  cols: 3
  data: [321.5, 0.0, 318.25, 0.0, 322.0, 241.5, 0.0, 0.0, 1.0]
distortion_model: {model}
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.1, 0.01, 0.001, -0.002, 0.0]
"""


def test_camera_from_ros_camera_calibration(tmp_path):
    """ROS camera_calibration's YAML ({rows, cols, data} maps, no OpenCV dt): read (before:
    an uncaught cv2.error, a traceback); a fisheye model is refused, not misapplied."""
    from factorgraph.field.intrinsics import read_camera
    from factorgraph.sensors import SensorSuite

    path = tmp_path / "camera.yaml"
    path.write_text(ROS_CAMERA.format(model="plumb_bob"))
    cam, dist = read_camera(path, SensorSuite().camera)
    assert (cam.fx_px, cam.fy_px, cam.cx_px, cam.cy_px) == (321.5, 322.0, 318.25, 241.5)
    np.testing.assert_allclose(dist, [-0.1, 0.01, 0.001, -0.002, 0.0])
    path.write_text(ROS_CAMERA.format(model="equidistant"))
    with pytest.raises(InputError, match=r"distortion_model.*equidistant.*fisheye"):
        read_camera(path, SensorSuite().camera)


def test_sigma_by_quality_with_a_misspelt_kind_is_refused(tmp_path):
    import json
    import shutil

    from factorgraph import read_field_log

    example = Path(__file__).resolve().parents[1] / "docs" / "examples" / "field"
    folder = tmp_path / "field"
    shutil.copytree(example, folder)
    man = json.loads((folder / "survey.json").read_text())
    man["gps"]["sigma_by_quality"] = {"rtk_fix": 0.01}  # before: ignored, 0.02 m kept
    (folder / "survey.json").write_text(json.dumps(man))
    with pytest.raises(
        InputError, match=r"sigma_by_quality key.*rtk_fix.*did you mean 'rtk_fixed'"
    ):
        read_field_log(folder)
    man["gps"]["sigma_by_quality"] = {"single": 1.5}
    (folder / "survey.json").write_text(json.dumps(man))
    assert read_field_log(folder)[1].gps_format == "nmea"


def test_sensor_key_typo_gets_a_did_you_mean():
    from factorgraph.sensors import SensorSuite

    with pytest.raises(InputError, match=r"Fix: 'sigma_whte_m': did you mean 'sigma_white_m'\?"):
        SensorSuite.from_dict({"gps": {"sigma_whte_m": [1, 1, 1]}})  # before: "Fix: " empty
    with pytest.raises(InputError, match=r"did you mean 'speed_mps'\?"):
        SensorSuite.from_dict({"speed_mp": 1.0})


def test_manifest_and_file_errors_carry_a_fix(tmp_path):
    """Each refusal says what to do (these ended in an empty "Fix: ")."""
    import json
    import shutil

    from factorgraph import read_field_log
    from toolkit.config import load_scenario

    example = Path(__file__).resolve().parents[1] / "docs" / "examples" / "field"
    folder = tmp_path / "field"
    shutil.copytree(example, folder)
    man = json.loads((folder / "survey.json").read_text())
    (folder / "survey.json").write_text(json.dumps({**man, "format": "v1"}))
    with pytest.raises(InputError, match=r'Fix: add "format": "glacimap-field/1"'):
        read_field_log(folder)
    (folder / "survey.json").write_text(json.dumps({**man, "stops": "stop.csv"}))
    with pytest.raises(InputError, match=r"stops.*Fix: check the name"):
        read_field_log(folder)
    with pytest.raises(InputError, match=r'Fix: pattern = "lawnmower" or "piecewise"'):
        load_scenario(overrides={"plan": {"pattern": "zigzag"}})


def test_nmea_malformed_times_in_rmc_and_gst_are_not_fatal(tmp_path):
    """An RMC or GST with a malformed time of day under a valid checksum: the RMC still dates
    the GGA before it, and the GST is not used (its fix keeps the quality x HDOP sigma)."""
    lines = [_gga(UTC[i], i) for i in range(3)]  # no date yet
    lines.append(_corrupt(_rmc(UTC[3]), 1, "2o0006.00"))
    tod = dt.datetime.fromtimestamp(UTC[3], dt.UTC).strftime("%H%M%S.00")
    lines.append(_cs(f"GPGST,{tod[:2]}x{tod[3:]},0.5,0.1,0.1,0.0,0.01,0.01,0.02"))
    lines += [_gga(UTC[i], i) for i in range(3, N)]
    path = tmp_path / "times.nmea"
    path.write_text("\n".join(lines) + "\n")
    f = read_nmea(path)
    np.testing.assert_allclose(f.utc_s, UTC)
    assert not f.skipped
    np.testing.assert_allclose(f.sigma[:, 0], f.sigma[0, 0])  # no fix took the GST's 0.01 m
