"""RTKLIB solution files (``.pos``, rnx2rtkp / RTKPOST / RTKNAVI / demo5 output).

``%`` header lines, the last of which names the columns; one solution per data row (Emlid
Reach's ``.LLH`` position log is RTKLIB's llh layout in GPS time without the header:
:data:`HEADERLESS`). Every output option of RTKLIB's "solution format" is read:

==========  ==========================================================  ===================
positions   header columns after the time                               per-fix 1-sigma
==========  ==========================================================  ===================
llh (deg)   ``latitude(deg) longitude(deg) height(m) Q ns sdn sde sdu``  ``sdn, sde, sdu``
llh (dms)   ``latitude(d'") longitude(d'") height(m) ...`` (d m s each)   ``sdn, sde, sdu``
xyz (ECEF)  ``x-ecef(m) y-ecef(m) z-ecef(m) Q ns sdx sdy sdz sdxy ...``   ECEF covariance
                                                                        rotated to E, N, U
enu         ``e-baseline(m) n-baseline(m) u-baseline(m) Q ns sde sdn``   ``sde, sdn, sdu``
            ``sdu ...`` from the ``% ref pos :`` header line
==========  ==========================================================  ===================

Time: the first header column says the time system, ``GPST`` (UTC = GPST - the GPS-UTC leap
seconds of the date, :func:`gps_utc_leap_s`), ``UTC`` or ``JST`` (UTC + 9 h); each row gives
a calendar ``YYYY/MM/DD HH:MM:SS.sss`` or GPS ``week seconds`` (RTKLIB's "ww ssss" option).
ECEF and ENU solutions are converted to WGS 84 latitude / longitude / ellipsoidal height
(EPSG:4978 -> EPSG:4979, pyproj); RTKLIB's cross terms ``sdxy, sdyz, sdzx`` are signed square
roots of the covariances. Counted, not fatal: rows that do not parse (``unparseable_row``),
``Q = 0`` or an unknown Q (``no_solution``) and the time-order reasons of
:meth:`.fixes.GPSFixes.collect`. Any other header is an InputError naming it.
"""

from __future__ import annotations

import calendar
import math
import re
from collections import Counter
from pathlib import Path

import numpy as np

from terrain.errors import bad_input

from .fixes import GPSFixes

__all__ = [
    "GPS_UTC_LEAP_S",
    "HEADERLESS",
    "LEAP_SECONDS",
    "Q_KIND",
    "gps_utc_leap_s",
    "read_rtklib",
]

#: GPS time minus UTC (s) since 2017-01-01 (IERS Bulletin C: no leap second since).
GPS_UTC_LEAP_S = 18
#: (UTC date from which it holds, GPS - UTC in s): IERS Bulletin C, GPS epoch 1980-01-06.
LEAP_SECONDS = (
    ("1981-07-01", 1), ("1982-07-01", 2), ("1983-07-01", 3), ("1985-07-01", 4),
    ("1988-01-01", 5), ("1990-01-01", 6), ("1991-01-01", 7), ("1992-07-01", 8),
    ("1993-07-01", 9), ("1994-07-01", 10), ("1996-01-01", 11), ("1997-07-01", 12),
    ("1999-01-01", 13), ("2006-01-01", 14), ("2009-01-01", 15), ("2012-07-01", 16),
    ("2015-07-01", 17), ("2017-01-01", 18),
)  # fmt: skip
#: RTKLIB Q -> solution kind (a key of .fixes.UERE_M).
Q_KIND = {1: "rtk_fixed", 2: "rtk_float", 3: "dgps", 4: "dgps", 5: "single", 6: "ppp"}
#: Column names after the time, by solution format (the sigma columns follow Q and ns).
_QS = ("Q", "ns")
_LAYOUTS = {
    "llh": ("latitude(deg)", "longitude(deg)", "height(m)", *_QS, "sdn(m)", "sde(m)", "sdu(m)"),
    "dms": ("latitude(d'\")", "longitude(d'\")", "height(m)", *_QS, "sdn(m)", "sde(m)", "sdu(m)"),
    "xyz": ("x-ecef(m)", "y-ecef(m)", "z-ecef(m)", *_QS, "sdx(m)", "sdy(m)", "sdz(m)"),
    "enu": ("e-baseline(m)", "n-baseline(m)", "u-baseline(m)", *_QS, "sde(m)", "sdn(m)", "sdu(m)"),
}  # fmt: skip
_TIME_SYSTEMS = ("GPST", "UTC", "JST")
#: Files that are RTKLIB solutions without its header, by suffix: Emlid Reach's position
#: log ``.LLH`` (RTKLIB's llh columns in GPS time; its ``.XYZ`` twin is not taken by suffix,
#: an ASCII point cloud's suffix too).
HEADERLESS = {".llh": ("GPST", *_LAYOUTS["llh"])}
_GPS_EPOCH = calendar.timegm((1980, 1, 6, 0, 0, 0))
_LEAP_POSIX = tuple(
    (calendar.timegm((*map(int, d.split("-")), 0, 0, 0)), s) for d, s in LEAP_SECONDS
)


def gps_utc_leap_s(gpst_posix: float) -> int:
    """GPS - UTC (s) at a GPS time given as POSIX-like seconds (IERS table,
    :data:`LEAP_SECONDS`; 0 before 1981-07-01)."""
    out = 0
    for start, leap in _LEAP_POSIX:
        if gpst_posix - leap >= start:
            out = leap
    return out


def _calendar(date: str, time: str) -> float:
    y, mo, d = (int(v) for v in date.split("/"))
    hh, mm, ss = time.split(":")
    sec = float(ss)
    whole = calendar.timegm((y, mo, d, int(hh), int(mm), int(sec)))
    return whole + (sec - int(sec))


def _time(tok: list[str]) -> float:
    """Seconds of the row's time scale (POSIX-like) from ``date time`` or ``week seconds``."""
    if "/" in tok[0]:
        return _calendar(tok[0], tok[1])
    week, sec = int(tok[0]), float(tok[1])
    if not (0 <= sec < 604800.0 and week >= 0):
        raise ValueError("not a GPS week / seconds")
    return _GPS_EPOCH + week * 604800 + sec


def _to_utc(t: float, system: str) -> float:
    if system == "GPST":
        return t - gps_utc_leap_s(t)
    return t - 9 * 3600.0 if system == "JST" else t


def _dms(tok: list[str]) -> float:
    d, m, s = (float(v) for v in tok)
    sign = -1.0 if tok[0].strip().startswith("-") else 1.0
    return sign * (abs(d) + m / 60.0 + s / 3600.0)


def _layout(cols: list[str]) -> str | None:
    for name, want in _LAYOUTS.items():
        if tuple(cols[1:9]) == want:
            return name
    return None


def _ecef_to_llh(xyz: np.ndarray) -> np.ndarray:
    from pyproj import Transformer

    tr = Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)
    lon, lat, h = tr.transform(xyz[:, 0], xyz[:, 1], xyz[:, 2])
    return np.column_stack([lat, lon, h])


def _llh_to_ecef(lat: float, lon: float, h: float) -> np.ndarray:
    from pyproj import Transformer

    tr = Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    return np.array(tr.transform(lon, lat, h), float)


def _enu_rotation(lat_deg: float, lon_deg: float) -> np.ndarray:
    """Rows: the E, N, U unit vectors in ECEF at ``lat, lon`` (geodetic)."""
    la, lo = math.radians(lat_deg), math.radians(lon_deg)
    return np.array(
        [
            [-math.sin(lo), math.cos(lo), 0.0],
            [-math.sin(la) * math.cos(lo), -math.sin(la) * math.sin(lo), math.cos(la)],
            [math.cos(la) * math.cos(lo), math.cos(la) * math.sin(lo), math.sin(la)],
        ]
    )


def _signed_square(v: float) -> float:
    """RTKLIB writes covariances as ``sign(c) sqrt(|c|)``."""
    return math.copysign(v * v, v)


def _ref_pos(header: list[str], name: str) -> np.ndarray:
    """ECEF of the ``% ref pos :`` line (lat lon h in deg or d m s, or ECEF x y z)."""
    for ln in header:
        m = re.match(r"%\s*ref pos\s*:(.*)", ln)
        if not m:
            continue
        vals = [float(v) for v in m.group(1).split()]
        if len(vals) == 3 and max(abs(v) for v in vals) > 1e5:  # ECEF metres
            return np.array(vals)
        if len(vals) == 3:
            return _llh_to_ecef(*vals)
        if len(vals) == 7:
            tok = m.group(1).split()
            return _llh_to_ecef(_dms(tok[0:3]), _dms(tok[3:6]), vals[6])
    raise bad_input(
        f"{name} ref pos",
        "an e/n/u-baseline solution without a '% ref pos :' header line",
        "the base position the baselines start from",
        "export with RTKLIB's header on (out-outhead = on), or as lat/lon/height",
    )


def read_rtklib(path: str | Path) -> GPSFixes:
    """Read an RTKLIB ``.pos`` solution (any position and time format) into
    :class:`.fixes.GPSFixes` (UTC, WGS 84 latitude / longitude / ellipsoidal height; a
    solution written in geodetic heights, ``height=WGS84/geodetic`` in its header, keeps
    them, its ``height_datum`` ``"egm96"``: RTKLIB's default geoid)."""
    path = Path(path)
    lines = path.read_text(errors="replace").splitlines()
    if not any(ln.strip() for ln in lines):
        raise bad_input(path.name, "an empty file", "an RTKLIB .pos solution", "export it again")
    header = [ln for ln in lines if ln.startswith("%")]
    data = [ln for ln in lines if ln.strip() and not ln.startswith("%")]
    cols = header[-1].lstrip("%").split() if header else []
    if not header and path.suffix.lower() in HEADERLESS:  # Emlid Reach .LLH: GPST, llh
        cols = list(HEADERLESS[path.suffix.lower()])
    layout = _layout(cols) if cols and cols[0] in _TIME_SYSTEMS else None
    if layout is None:
        raise bad_input(
            f"{path.name} header",
            " ".join(cols) or "(none)",
            "RTKLIB's column line: '%  GPST|UTC|JST' then 'latitude(deg) longitude(deg) "
            "height(m)', 'latitude(d'\") longitude(d'\") height(m)', 'x-ecef(m) y-ecef(m) "
            "z-ecef(m)' or 'e-baseline(m) n-baseline(m) u-baseline(m)', then 'Q ns' and the "
            "three sigmas",
            "export the solution with RTKLIB's header on (out-outhead = on) and its own "
            "column names",
        )
    if not data:
        raise bad_input(path.name, "a header only", "solution rows", "process the survey")
    base = _ref_pos(header, path.name) if layout == "enu" else None
    n_pos = 7 if layout == "dms" else 3  # tokens of the position
    skipped: Counter = Counter()
    t_utc, pos, qual, sd = [], [], [], []
    for ln in data:
        tok = ln.split()
        try:
            t = _to_utc(_time(tok), cols[0])
            p = tok[2 : 2 + n_pos]
            xyz = (_dms(p[0:3]), _dms(p[3:6]), float(p[6])) if layout == "dms" else p
            xyz = tuple(float(v) for v in xyz)
            rest = [float(v) for v in tok[2 + n_pos :]]
            q, s = int(rest[0]), rest[2:8]
            if len(s) < 3:
                raise IndexError
        except (IndexError, ValueError):
            skipped["unparseable_row"] += 1
            continue
        kind = Q_KIND.get(q)
        if kind is None:
            skipped["no_solution"] += 1
            continue
        t_utc.append(t)
        pos.append(xyz)
        qual.append(kind)
        sd.append(s + [0.0] * (6 - len(s)))
    if not t_utc:
        return GPSFixes.collect([], skipped, "rtklib", path.name)
    pos_a, sd_a = np.array(pos, float), np.array(sd, float)
    llh, sigma = _positions(layout, pos_a, sd_a, base)
    rows = [(t_utc[i], *llh[i], *sigma[i], qual[i]) for i in range(len(t_utc))]
    fixes = GPSFixes.collect(rows, skipped, "rtklib", path.name)
    if layout in ("llh", "dms") and any("height=wgs84/geodetic" in h.lower() for h in header):
        fixes.height_datum = "egm96"  # out-height = geodetic: RTKLIB's geoid, EGM96 by default
    return fixes


def _positions(layout: str, pos: np.ndarray, sd: np.ndarray, base: np.ndarray | None):
    """Latitude, longitude, height (n, 3) and per-fix 1-sigma E, N, U (n, 3) of the rows."""

    def clean(s: np.ndarray) -> np.ndarray:
        return np.where(np.isfinite(s) & (s > 0), s, np.nan)

    if layout in ("llh", "dms"):
        return pos, clean(sd[:, [1, 0, 2]])  # sdn sde sdu -> E N U
    if layout == "enu":
        rot = _enu_rotation(*_ecef_to_llh(base[None])[0, :2])
        llh = _ecef_to_llh(base + pos @ rot)  # ECEF = base + R^T enu
        return llh, clean(sd[:, [0, 1, 2]])  # sde sdn sdu
    llh = _ecef_to_llh(pos)
    sig = np.full((len(pos), 3), np.nan)
    for i in range(len(pos)):
        sx, sy, sz, sxy, syz, szx = sd[i]
        c = np.array(
            [
                [sx * sx, _signed_square(sxy), _signed_square(szx)],
                [_signed_square(sxy), sy * sy, _signed_square(syz)],
                [_signed_square(szx), _signed_square(syz), sz * sz],
            ]
        )
        rot = _enu_rotation(llh[i, 0], llh[i, 1])
        sig[i] = np.sqrt(np.clip(np.diag(rot @ c @ rot.T), 0.0, None))
    return llh, clean(sig)
