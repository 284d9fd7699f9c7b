"""RTKLIB solution files (``.pos``, rnx2rtkp / RTKPOST / RTKNAVI output).

Accepted layout: ``%`` header lines, the last of which names the columns
``GPST|UTC latitude(deg) longitude(deg) height(m) Q ns sdn(m) sde(m) sdu(m) ...``; data rows
``YYYY/MM/DD HH:MM:SS.sss lat lon h Q ns sdn sde sdu ...`` (time as a calendar date, lat/lon
in decimal degrees, ellipsoidal height). GPST is converted to UTC with
:data:`GPS_UTC_LEAP_S` leap seconds. The solution's own ``sdn, sde, sdu`` are each fix's
1-sigma. Any other header (ECEF ``x-ecef(m)``, ENU baselines, d/m/s angles, GPS week /
seconds) is an InputError naming it. Counted: rows that do not parse, ``Q = 0`` and the
time-order reasons of :meth:`.fixes.GPSFixes.collect`.
"""

from __future__ import annotations

import calendar
import math
from collections import Counter
from pathlib import Path

from terrain.errors import bad_input

from .fixes import GPSFixes

__all__ = ["GPS_UTC_LEAP_S", "Q_KIND", "read_rtklib"]

#: GPS time minus UTC (s) since 2017-01-01 (IERS Bulletin C: no leap second since).
GPS_UTC_LEAP_S = 18
#: RTKLIB Q -> solution kind (a key of .fixes.UERE_M).
Q_KIND = {1: "rtk_fixed", 2: "rtk_float", 3: "dgps", 4: "dgps", 5: "single", 6: "ppp"}
_COLUMNS = ("latitude(deg)", "longitude(deg)", "height(m)", "Q", "ns", "sdn(m)", "sde(m)", "sdu(m)")


def _posix(date: str, time: str) -> float:
    y, mo, d = (int(v) for v in date.split("/"))
    hh, mm, ss = time.split(":")
    sec = float(ss)
    whole = calendar.timegm((y, mo, d, int(hh), int(mm), int(sec)))
    return whole + (sec - int(sec))


def read_rtklib(path: str | Path) -> GPSFixes:
    """Read an RTKLIB ``.pos`` solution (lat/lon/height form) into :class:`.fixes.GPSFixes`."""
    path = Path(path)
    lines = path.read_text(errors="replace").splitlines()
    header = [ln for ln in lines if ln.startswith("%")]
    data = [ln for ln in lines if ln.strip() and not ln.startswith("%")]
    if not lines or not any(ln.strip() for ln in lines):
        raise bad_input(path.name, "an empty file", "an RTKLIB .pos solution", "")
    cols = header[-1].lstrip("%").split() if header else []
    if not cols or cols[0] not in ("GPST", "UTC") or tuple(cols[1:9]) != _COLUMNS:
        raise bad_input(
            f"{path.name} header",
            " ".join(cols) or "(none)",
            "'%  GPST|UTC  latitude(deg) longitude(deg) height(m) Q ns sdn(m) sde(m) sdu(m) ...'",
            "export with RTKLIB's solution format 'lat/lon/height', time 'ww ssss' off, "
            "degrees not d/m/s",
        )
    shift = GPS_UTC_LEAP_S if cols[0] == "GPST" else 0
    if not data:
        raise bad_input(path.name, "a header only", "solution rows", "process the survey")
    skipped: Counter = Counter()
    rows = []
    for ln in data:
        tok = ln.split()
        try:
            t = _posix(tok[0], tok[1]) - shift
            lat, lon, h = float(tok[2]), float(tok[3]), float(tok[4])
            q = int(tok[5])
            sn, se, su = float(tok[7]), float(tok[8]), float(tok[9])
        except (IndexError, ValueError):
            skipped["unparseable_row"] += 1
            continue
        kind = Q_KIND.get(q)
        if kind is None:
            skipped["no_solution"] += 1
            continue
        sig = tuple(v if math.isfinite(v) and v > 0 else math.nan for v in (se, sn, su))
        rows.append((t, lat, lon, h, *sig, kind))
    return GPSFixes.collect(rows, skipped, "rtklib", path.name)
