"""Field ingest: what is skipped is counted by reason; bad input is one clear InputError."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from factorgraph import localize, read_field_log, write_field_log
from factorgraph.field import MAX_BAD_CHECKSUM_FRACTION, gross_outliers
from factorgraph.simulate import simulate_traverse
from terrain.errors import InputError
from terrain.synthetic import default_site

W, N = 526000.0, 6475600.0
LEGS = np.array([[W + 20, N - 75], [W + 80, N - 75], [W + 80, N - 60], [W + 20, N - 60]])


@pytest.fixture(scope="module")
def log():
    return simulate_traverse(default_site(2.0), LEGS, seed=5)


def _folder(log, tmp_path, fmt="nmea"):
    write_field_log(log, tmp_path, gps_format=fmt)
    return tmp_path


def _nmea_lines(folder):
    return (folder / "gps.nmea").read_text().splitlines()


def _write_lines(folder, lines):
    (folder / "gps.nmea").write_text("\n".join(lines) + "\n")


def _manifest(folder, **changes):
    path = folder / "survey.json"
    man = json.loads(path.read_text())
    man.update(changes)
    path.write_text(json.dumps(man))


def _corrupt(line: str) -> str:
    """Flip one digit of the payload: the checksum no longer matches."""
    i = line.index(",") + 3
    return line[:i] + ("1" if line[i] != "1" else "2") + line[i + 1 :]


def test_bad_checksums_counted_then_fatal(log, tmp_path):
    folder = _folder(log, tmp_path)
    lines = _nmea_lines(folder)
    n_bad = int(0.03 * len(lines))
    gga = [i for i, ln in enumerate(lines) if "GGA" in ln][:n_bad]
    _write_lines(folder, [_corrupt(ln) if i in gga else ln for i, ln in enumerate(lines)])
    back, rep = read_field_log(folder)
    assert rep.gps_skipped["bad_checksum"] == n_bad
    assert rep.gps_used == log.gps_k.size - n_bad
    assert set(back.gps_k) == set(log.gps_k) - set(log.gps_k[:n_bad])
    n_bad = int((MAX_BAD_CHECKSUM_FRACTION + 0.02) * len(lines)) + 1
    _write_lines(folder, [_corrupt(ln) if i < n_bad else ln for i, ln in enumerate(lines)])
    with pytest.raises(InputError, match=r"checksums.*at most 5 %"):
        read_field_log(folder)


def test_time_order_no_solution_gaps_and_outliers_counted(log, tmp_path):
    folder = _folder(log, tmp_path)
    lines = _nmea_lines(folder)
    epochs = [lines[i : i + 3] for i in range(0, len(lines), 3)]  # RMC, GGA, GST per fix
    gga = [e[1].split(",") for e in epochs]
    fields = gga[10][:]
    fields[6] = "0"  # quality 0: no solution
    epochs[10][1] = _rebuild(fields)
    far = gga[40][:]
    far[2] = f"{float(far[2]) + 2.7:.7f}"  # +2.7 arc-minutes north: 5 km off
    epochs[40][1] = _rebuild(far)
    out = []
    for i, e in enumerate(epochs):
        if 60 <= i < 80:  # a 20 s outage
            continue
        out += e
        if i == 20:
            out.append(e[1])  # the same fix twice
        if i == 30:
            out.append(epochs[25][1])  # a stale fix from the past
    _write_lines(folder, out)
    back, rep = read_field_log(folder)
    sk = rep.gps_skipped
    assert sk == {
        "no_solution": 1,
        "gross_outlier": 1,
        "duplicate_time": 1,
        "backwards_time": 1,
    }, sk
    assert rep.gps_records == len(epochs) - 20 + 2
    assert rep.gps_used == len(epochs) - 20 - 2
    assert rep.gps_gaps["count"] == 1 and rep.gps_gaps["longest_s"] == pytest.approx(21.0)
    assert 40 not in back.gps_k and 10 not in back.gps_k
    assert back.ingest["gps_skipped"] == sk  # the log carries the counts
    assert any("gross_outlier" in ln for ln in rep.lines())


def _rebuild(fields: list[str]) -> str:
    import pynmea2

    body = ",".join(fields).split("*")[0]
    talker, kind = body[1:3], body[3:6]
    return str(pynmea2.GGA(talker, kind, body.split(",")[1:]))


def test_gross_outlier_gated_in_localize(log):
    """Strict glacimap-log/1 path: a fix 5 km off is gated, counted, and the result equals
    localizing the log without it (was 'Singular matrix')."""
    xyz = log.gps_xyz.copy()
    xyz[30, 0] += 5000.0
    res = localize(dataclasses.replace(log, gps_xyz=xyz))
    assert res.log.ingest["gps_gross_outliers_gated"] == 1
    keep = np.arange(log.gps_k.size) != 30
    truth = dict(log.truth, gps_bias=log.truth["gps_bias"][keep])
    clean = dataclasses.replace(log, gps_k=log.gps_k[keep], gps_xyz=log.gps_xyz[keep], truth=truth)
    ref = localize(clean)
    np.testing.assert_allclose(res.keyframe_xyz, ref.keyframe_xyz, atol=1e-9, rtol=0)
    assert res.log.gps_k.size == log.gps_k.size - 1


def test_gross_outliers_median_gate():
    """Hand case: a rover at 1 m/s, fixes 1 m sigma; a burst of two blunders is caught, a
    10 m honest drift of the bias over a minute is not, a lone fix cannot be judged."""
    t = np.arange(60.0)
    xyz = np.column_stack([t, np.zeros(60), np.zeros(60)])
    xyz[:, 1] += np.linspace(0, 10, 60)  # slow bias walk
    xyz[[20, 21], 0] += [300.0, -250.0]
    bad = gross_outliers(t, xyz, np.ones((60, 3)), t)
    assert np.flatnonzero(bad).tolist() == [20, 21]
    assert not gross_outliers(
        t[:2], xyz[:2] + [[0, 0, 0], [9e3, 0, 0]], np.ones((2, 3)), t[:2]
    ).any()


def test_gpx_without_track(log, tmp_path):
    folder = _folder(log, tmp_path, "gpx")
    (folder / "gps.gpx").write_text(
        '<?xml version="1.0"?><gpx version="1.1" creator="x" '
        'xmlns="http://www.topografix.com/GPX/1/1"><wpt lat="58.4" lon="-134.5"/></gpx>'
    )
    with pytest.raises(InputError, match=r"gps.gpx tracks.*no track points.*1 waypoints"):
        read_field_log(folder)


def test_gpx_points_without_time_or_elevation_counted(log, tmp_path):
    import gpxpy

    folder = _folder(log, tmp_path, "gpx")
    doc = gpxpy.parse((folder / "gps.gpx").read_text())
    pts = doc.tracks[0].segments[0].points
    pts[5].time = None
    pts[6].elevation = None
    pts[7].type_of_gpx_fix = "none"
    pts[8].type_of_gpx_fix = "2d"
    (folder / "gps.gpx").write_text(doc.to_xml())
    _, rep = read_field_log(folder)
    assert rep.gps_skipped == {
        "no_time": 1,
        "no_elevation": 1,
        "no_solution": 1,
        "2d_fix_no_height": 1,
    }


def test_rtklib_unknown_header(log, tmp_path):
    folder = _folder(log, tmp_path, "rtklib")
    text = (folder / "gps.pos").read_text()
    text = text.replace("latitude(deg) longitude(deg)  height(m)", "x(ft) y(ft) z(ft)")
    (folder / "gps.pos").write_text(text)  # ECEF, ENU, d/m/s: tests/test_field_formats.py
    with pytest.raises(InputError, match=r"gps.pos header.*x\(ft\)"):
        read_field_log(folder)


def test_rtklib_gpst_is_utc_plus_leap_seconds(log, tmp_path):
    folder = _folder(log, tmp_path, "rtklib")
    first = [ln for ln in (folder / "gps.pos").read_text().splitlines() if ln[0] != "%"][0]
    assert first.startswith("2026/07/01 20:00:18.000")  # 20:00:00 UTC + 18 s (IERS)
    _, rep = read_field_log(folder)
    assert rep.gps_used == log.gps_k.size


@pytest.mark.parametrize(
    ("crs", "match"),
    [("EPSG:4326", "projected map CRS"), ("EPSG:999999", "CRSs pyproj knows")],
)
def test_crs_that_cannot_be_projected(log, tmp_path, crs, match):
    folder = _folder(log, tmp_path)
    with pytest.raises(InputError, match=match):
        read_field_log(folder, crs=crs)


def test_clocks_that_do_not_overlap(log, tmp_path):
    folder = _folder(log, tmp_path)
    with pytest.raises(InputError, match="clocks that overlap"):
        read_field_log(folder, clock_offset_s=0.0)  # UTC of 1970: the GPS is 56 years later


@pytest.mark.parametrize(
    ("fmt", "text"),
    [
        ("nmea", ""),
        (
            "rtklib",
            "%  GPST          latitude(deg) longitude(deg)  height(m)   Q  "
            "ns   sdn(m)   sde(m)   sdu(m)  sdne(m)\n",
        ),
        ("gpx", ""),
    ],
)
def test_empty_or_header_only_gps(log, tmp_path, fmt, text):
    folder = _folder(log, tmp_path, fmt)
    name = {"nmea": "gps.nmea", "gpx": "gps.gpx", "rtklib": "gps.pos"}[fmt]
    (folder / name).write_text(text)
    with pytest.raises(InputError, match="empty file|header only"):
        read_field_log(folder)


def test_gga_without_date(log, tmp_path):
    folder = _folder(log, tmp_path)
    _write_lines(folder, [ln for ln in _nmea_lines(folder) if "RMC" not in ln])
    with pytest.raises(InputError, match="RMC or ZDA sentences in the log or gps.date"):
        read_field_log(folder)
    man = json.loads((folder / "survey.json").read_text())
    _manifest(folder, gps=dict(man["gps"], date="2026-07-01"))
    _, rep = read_field_log(folder)
    assert rep.gps_used == log.gps_k.size


def test_manifest_typo_and_lever_arm(log, tmp_path):
    folder = _folder(log, tmp_path)
    _manifest(folder, clock_ofset_s=3.0)
    with pytest.raises(InputError, match="did you mean 'clock_offset_s'"):
        read_field_log(folder)
    man = json.loads((folder / "survey.json").read_text())
    del man["clock_ofset_s"]
    man["lever_arm_m"] = [0.0, 0.0, 1.5]
    (folder / "survey.json").write_text(json.dumps(man))
    back, _ = read_field_log(folder)
    np.testing.assert_allclose(back.gps_xyz[:, 2], log.gps_xyz[:, 2] - 1.5, atol=6e-5)
    _manifest(folder, lever_arm_m=[0.3, 0.0, 1.5])
    with pytest.raises(InputError, match="lever_arm_m"):
        read_field_log(folder)


def test_tracks_nan_and_camera_distortion(log, tmp_path):
    """Tracks recorded through a lens with distortion come back to the pinhole model
    (reference: cv2.projectPoints distorts, read_field_log undistorts)."""
    import cv2
    import pandas as pd

    folder = _folder(log, tmp_path)
    cam = log.sensors.camera
    K = np.array([[cam.fx_px, 0, cam.cx_px], [0, cam.fy_px, cam.cy_px], [0, 0, 1.0]])
    dist = np.array([-0.12, 0.03, 0.001, -0.0005, 0.0])
    rays = np.column_stack(
        [(log.obs_uv - [cam.cx_px, cam.cy_px]) / [cam.fx_px, cam.fy_px], np.ones(log.obs_k.size)]
    )
    distorted, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), K, dist)
    tracks = pd.read_csv(folder / "tracks.csv", float_precision="round_trip")
    tracks[["u_px", "v_px"]] = distorted.reshape(-1, 2)
    tracks.loc[3, "u_px"] = np.nan
    tracks.to_csv(folder / "tracks.csv", index=False, float_format="%.17g")
    fs = cv2.FileStorage(str(folder / "camera.yaml"), cv2.FILE_STORAGE_READ)
    K_file = fs.getNode("camera_matrix").mat()
    fs.release()
    np.testing.assert_array_equal(K_file, K)
    text = (folder / "camera.yaml").read_text()
    start = text.index("distortion_coefficients")
    end = text.index("mount_pitch_deg")
    coeffs = ", ".join(f"{v:.6f}" for v in dist)
    block = (
        "distortion_coefficients: !!opencv-matrix\n   rows: 1\n   cols: 5\n   dt: d\n"
        f"   data: [ {coeffs} ]\n"
    )
    (folder / "camera.yaml").write_text(text[:start] + block + text[end:])
    back, rep = read_field_log(folder)
    assert rep.tracks_skipped == {"nan_observation": 1}
    assert "undistorted" in rep.camera
    keep = np.arange(log.obs_k.size) != 3
    np.testing.assert_allclose(back.obs_uv, log.obs_uv[keep], atol=2e-3)


def test_localize_cli_summary_counts_gated_fix(log, tmp_path):
    """``glacimap localize`` on a glacimap-log/1 folder whose gps.csv has one fix 5 km off:
    no traceback, and localize_summary.json counts it."""
    import pandas as pd
    from typer.testing import CliRunner

    from factorgraph import write_log
    from toolkit.cli import app

    write_log(log, tmp_path / "log")
    gps = pd.read_csv(tmp_path / "log" / "gps.csv")
    gps.loc[30, "x"] += 5000.0
    gps.to_csv(tmp_path / "log" / "gps.csv", index=False)
    res = CliRunner().invoke(
        app, ["localize", str(tmp_path / "log"), "--out", str(tmp_path / "loc")]
    )
    assert res.exit_code == 0, (res.output, res.exception)
    summary = json.loads((tmp_path / "loc" / "localize_summary.json").read_text())
    assert summary["gps_skipped"] == {"gross_outlier": 1}
    assert summary["gps_used"] == log.gps_k.size - 1
    assert "gross_outlier 1" in res.output


def test_tilt_not_covering_every_keyframe_is_not_used(log, tmp_path):
    import pandas as pd

    folder = _folder(log, tmp_path)
    tilt = pd.read_csv(folder / "tilt.csv")
    tilt.iloc[:-5].to_csv(folder / "tilt.csv", index=False)  # the last 5 keyframes lack it
    back, rep = read_field_log(folder)
    assert back.tilt_up is None and rep.tilt.startswith("not used: 5 keyframes")
    tilt.iloc[:1].to_csv(folder / "tilt.csv", index=False)  # one reading only
    back, rep = read_field_log(folder)
    assert back.tilt_up is None and "keyframes without a reading" in rep.tilt


def test_per_fix_sigma_reaches_localize():
    """A receiver's own sigma (2 cm RTK fixes) outweighs the stated model (2.5 m): the same
    fixes with per-fix sigmas hold the track to centimetres, without them to decimetres
    (measured: keyframe horizontal RMSE 0.015 m with, 0.083 m without)."""
    from factorgraph.sensors import GPSModel, SensorSuite

    rtk = SensorSuite(gps=GPSModel(sigma_white_m=(0.02,) * 3, bias_sigma_m=(0.01,) * 3))
    sim = simulate_traverse(default_site(2.0), LEGS, sensors=rtk, seed=5)
    model = SensorSuite(gps=GPSModel(bias_sigma_m=(0.01,) * 3))  # white 2.5 m stated
    plain = dataclasses.replace(sim, sensors=model)
    per_fix = dataclasses.replace(plain, gps_sigma=np.full(sim.gps_xyz.shape, 0.02))

    def rmse(res):
        e = res.keyframe_xyz[:, :2] - sim.truth["xyz"][:, :2]
        return float(np.sqrt((e**2).sum(1).mean()))

    with_sigma, without = rmse(localize(per_fix)), rmse(localize(plain))
    assert with_sigma < 0.05 < without, (with_sigma, without)
