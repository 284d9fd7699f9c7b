"""Write a :class:`MeasurementLog` as a rover's field folder (docs/field-format.md).

The inverse of :func:`factorgraph.read_field_log`: GPS as NMEA 0183 (GGA + RMC + GST, valid
checksums), GPX 1.1 or an RTKLIB ``.pos`` solution, in WGS 84 geographic coordinates and UTC;
odometry, tilt and tracks as rover-clock CSV; the camera as an OpenCV YAML calibration; and
``survey.json``. No truth is written: a field folder holds what a rover records.

Precision (what survives a round trip): NMEA latitude / longitude with 7 decimals of
arc-minute (1.9e-4 m north, less east), heights 4 decimals (5e-5 m), time 0.01 s; GPX
coordinates 9 decimals of a degree (1.1e-4 m); RTKLIB 9 decimals of a degree, heights
4 decimals, time 1 ms; sigmas 4 decimals; CSV tables 17 significant digits (exact).
"""

from __future__ import annotations

import calendar
import datetime as dt
import json
from pathlib import Path

import numpy as np

from terrain.atomic import atomic_path, ensure_writable_dir
from terrain.errors import bad_input

from ..log import MeasurementLog
from .fixes import UERE_M
from .intrinsics import write_camera
from .reader import FIELD_FORMAT, MANIFEST
from .rtklib import GPS_UTC_LEAP_S
from .stops import STOPS_FILE, write_stops

__all__ = ["DEFAULT_START_UTC", "GPS_FILES", "write_field_log"]

#: UTC time of the first keyframe when none is given.
DEFAULT_START_UTC = "2026-07-01T20:00:00+00:00"
#: File name of the GPS file per format.
GPS_FILES = {"nmea": "gps.nmea", "gpx": "gps.gpx", "rtklib": "gps.pos"}
_NMEA_KIND = {"single": 1, "dgps": 2, "rtk_fixed": 4, "rtk_float": 5}


def _kind(sigma_h: float) -> str:
    """Solution kind a receiver would report for this horizontal 1-sigma (m)."""
    return "rtk_fixed" if sigma_h <= 0.05 else "rtk_float" if sigma_h <= 0.5 else "single"


def _angle(value: float, deg_digits: int, hemis: str) -> tuple[str, str]:
    """NMEA ``(d)ddmm.mmmmmmm`` and hemisphere; integer arithmetic: never 60.0 minutes."""
    units = round(abs(value) * 60 * 10**7)
    deg, rest = divmod(units, 60 * 10**7)
    text = f"{deg:0{deg_digits}d}{rest // 10**7:02d}.{rest % 10**7:07d}"
    return text, hemis[0] if value >= 0 else hemis[1]


def _hms(utc: float) -> tuple[str, str, dt.datetime]:
    cs = round(utc * 100)
    when = dt.datetime.fromtimestamp(cs // 100, dt.UTC)
    return f"{when:%H%M%S}.{cs % 100:02d}", f"{when:%d%m%y}", when


def _nmea(utc, lat, lon, h, sig, kinds) -> str:
    import pynmea2

    out = []
    for i in range(utc.size):
        tod, dmy, _ = _hms(utc[i])
        la, ns = _angle(lat[i], 2, "NS")
        lo, ew = _angle(lon[i], 3, "EW")
        hdop = 0.5 * (sig[i, 0] + sig[i, 1]) / UERE_M[kinds[i]]
        q = str(_NMEA_KIND[kinds[i]])
        gga = (tod, la, ns, lo, ew, q, "12", f"{hdop:.2f}", f"{h[i]:.4f}", "M", "0.0", "M", "", "")
        gst = (tod, "", "", "", "", f"{sig[i, 1]:.4f}", f"{sig[i, 0]:.4f}", f"{sig[i, 2]:.4f}")
        rmc = (tod, "A", la, ns, lo, ew, "", "", dmy, "", "", "A")
        for kind, fields in (("RMC", rmc), ("GGA", gga), ("GST", gst)):
            out.append(str(getattr(pynmea2, kind)("GN", kind, fields)))
    return "\r\n".join(out) + "\r\n"


def _gpx(utc, lat, lon, h, sig, kinds) -> str:
    import gpxpy.gpx

    doc = gpxpy.gpx.GPX()
    doc.creator = "glacimap write_field_log"
    trk = gpxpy.gpx.GPXTrack(name="rover")
    seg = gpxpy.gpx.GPXTrackSegment()
    for i in range(utc.size):
        kind = "dgps" if kinds[i] != "single" else "single"
        uere = UERE_M[kind]
        p = gpxpy.gpx.GPXTrackPoint(
            latitude=round(float(lat[i]), 9),
            longitude=round(float(lon[i]), 9),
            elevation=round(float(h[i]), 4),
            time=dt.datetime.fromtimestamp(round(float(utc[i]), 3), dt.UTC),
            horizontal_dilution=round(0.5 * float(sig[i, 0] + sig[i, 1]) / uere, 6),
            vertical_dilution=round(float(sig[i, 2]) / uere, 6),
        )
        p.type_of_gpx_fix = "dgps" if kind == "dgps" else "3d"
        seg.points.append(p)
    trk.segments.append(seg)
    doc.tracks.append(trk)
    return doc.to_xml(version="1.1")


def _rtklib(utc, lat, lon, h, sig, kinds) -> str:
    q_of = {"rtk_fixed": 1, "rtk_float": 2, "dgps": 4, "single": 5}
    lines = [
        "% program   : glacimap write_field_log",
        "% (lat/lon/height=WGS84/ellipsoidal,Q=1:fix,2:float,3:sbas,4:dgps,5:single,6:ppp)",
        "%  GPST          latitude(deg) longitude(deg)  height(m)   Q  ns   sdn(m)   sde(m)"
        "   sdu(m)  sdne(m)  sdeu(m)  sdun(m) age(s)  ratio",
    ]
    for i in range(utc.size):
        ms = round((utc[i] + GPS_UTC_LEAP_S) * 1000)
        when = dt.datetime.fromtimestamp(ms // 1000, dt.UTC)
        lines.append(
            f"{when:%Y/%m/%d %H:%M:%S}.{ms % 1000:03d} {lat[i]:14.9f} {lon[i]:14.9f} "
            f"{h[i]:10.4f} {q_of[kinds[i]]:3d} {12:3d} {sig[i, 1]:8.4f} {sig[i, 0]:8.4f} "
            f"{sig[i, 2]:8.4f} {0:8.4f} {0:8.4f} {0:8.4f} {0:6.2f} {0:6.1f}"
        )
    return "\n".join(lines) + "\n"


def _csv(path: Path, cols: dict[str, np.ndarray], fmt: str = "%.17g") -> None:
    import pandas as pd

    with atomic_path(path) as tmp:
        pd.DataFrame(cols).to_csv(tmp, index=False, float_format=fmt)


def write_field_log(
    log: MeasurementLog,
    folder: str | Path,
    gps_format: str = "nmea",
    crs: str | None = None,
    start_utc: str = DEFAULT_START_UTC,
    write_clock_offset: bool = True,
) -> Path:
    """Write ``log`` into ``folder`` as the files a rover brings back from the field.

    Parameters
    ----------
    log : MeasurementLog
        A (simulated) log; its truth is not written.
    folder : path
        Created if needed; each file is written atomically.
    gps_format : {"nmea", "gpx", "rtklib"}
        GPS file format (:data:`GPS_FILES` names the file).
    crs : str, optional
        Projected CRS of the log's local frame (default ``log.crs``), recorded in the manifest.
    start_utc : str
        ISO 8601 UTC time of the first keyframe.
    write_clock_offset : bool
        Record ``clock_offset_s`` in ``survey.json``; False leaves it to be estimated.

    Returns
    -------
    Path
        The folder.
    """
    from pyproj import CRS, Transformer

    if gps_format not in GPS_FILES:
        raise bad_input("gps_format", gps_format, " or ".join(GPS_FILES), "pick one")
    if not isinstance(log, MeasurementLog):
        raise bad_input("log", type(log).__name__, "a MeasurementLog", "")
    map_crs = CRS.from_user_input(crs or log.crs)
    if not map_crs.is_projected:
        raise bad_input("crs", str(crs or log.crs), "a projected CRS", "e.g. EPSG:32608")
    try:
        t0 = dt.datetime.fromisoformat(start_utc)
    except ValueError as exc:
        raise bad_input("start_utc", start_utc, "ISO 8601 time", "e.g. 2026-07-01T20:00Z") from exc
    if t0.tzinfo is None:
        t0 = t0.replace(tzinfo=dt.UTC)
    offset = calendar.timegm(t0.utctimetuple()) + t0.microsecond * 1e-6 - float(log.t[0])
    out = ensure_writable_dir(folder)

    xyz = log.gps_xyz + np.r_[log.origin, 0.0]
    tr = Transformer.from_crs(map_crs, CRS.from_epsg(4979), always_xy=True)
    lon, lat = (np.asarray(v, float) for v in tr.transform(xyz[:, 0], xyz[:, 1]))
    sig = log.gps_sigma
    if sig is None:
        sig = np.broadcast_to(np.asarray(log.sensors.gps.sigma_white_m, float), xyz.shape)
    kinds = [_kind(0.5 * (s[0] + s[1])) for s in sig]
    utc = log.t[log.gps_k] + offset
    text = {"nmea": _nmea, "gpx": _gpx, "rtklib": _rtklib}[gps_format](
        utc, lat, lon, xyz[:, 2], sig, kinds
    )
    with atomic_path(out / GPS_FILES[gps_format]) as tmp:
        tmp.write_text(text)

    od = np.vstack([np.zeros((1, 6)), log.odometry])
    cols = {"t_s": log.t}
    cols.update({n: od[:, i] for i, n in enumerate(("rx", "ry", "rz", "tx", "ty", "tz"))})
    _csv(out / "odometry.csv", cols)
    if log.tilt_up is not None:
        up = {"t_s": log.t}
        up.update({f"up_{a}": log.tilt_up[:, i] for i, a in enumerate("xyz")})
        _csv(out / "tilt.csv", up)
    for stale in ("tilt.csv",) if log.tilt_up is None else ():
        (out / stale).unlink(missing_ok=True)
    tracks = {
        "t_s": log.t[log.obs_k],
        "landmark_id": log.obs_id,
        "u_px": log.obs_uv[:, 0],
        "v_px": log.obs_uv[:, 1],
    }
    _csv(out / "tracks.csv", tracks)
    write_camera(out / "camera.yaml", log.sensors.camera)
    stops = write_stops(out / STOPS_FILE, log.t, log.control_id)  # stops on control points
    for name in set(GPS_FILES.values()) - {GPS_FILES[gps_format]}:
        (out / name).unlink(missing_ok=True)  # one GPS file per folder
    man = {
        "format": FIELD_FORMAT,
        "crs": map_crs.to_string(),
        "origin": [float(v) for v in log.origin],
        "seed": log.seed,
        "clock_offset_s": offset if write_clock_offset else None,
        "lever_arm_m": [0.0, 0.0, 0.0],
        "gps": {"file": GPS_FILES[gps_format], "format": gps_format, "crs": "EPSG:4979"},
        "sensors": log.sensors.to_dict(),
    }
    if stops is not None:
        man["stops"] = STOPS_FILE
    with atomic_path(out / MANIFEST) as tmp:
        tmp.write_text(json.dumps(man, indent=2) + "\n")
    return out
