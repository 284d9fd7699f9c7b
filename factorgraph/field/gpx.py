"""GPX 1.0 / 1.1 tracks (``gpxpy``): every ``trkpt`` of every track segment is a fix.

Track segments are read in the order of their first time stamp, not of the file: devices
and editors write tracks newest first, or a merged file in any order; the points inside a
segment keep their order (a time that goes back there is a clock glitch, counted).

A point needs a ``time`` (UTC) and an ``ele`` (with ``geoidheight``, GPX 1.1's geoid
separation, ``ele + geoidheight`` is the ellipsoidal height; without, ``ele``'s datum is not
stated: ``GPSFixes.height_unstated``); ``hdop`` / ``vdop`` with the ``fix`` type give
its 1-sigma (:func:`.fixes.sigma_from_dop`; ``fix`` absent counts as an autonomous fix, no
hdop leaves the stated sensor model in charge). Counted, not fatal: points without time or
elevation, ``fix`` ``none`` (no solution) or ``2d`` (no height), and the time-order reasons of
:meth:`.fixes.GPSFixes.collect`. A GPX without any track point is an InputError (routes and
waypoints are plans, not measurements).
"""

from __future__ import annotations

import calendar
import datetime as dt
import math
from collections import Counter
from pathlib import Path

from terrain.errors import bad_input

from .fixes import UERE_M, GPSFixes, sigma_from_dop

__all__ = ["FIX_KIND", "read_gpx"]

#: GPX ``fix`` -> solution kind (a key of UERE_M) or the reason the point is skipped.
FIX_KIND = {
    None: "single",
    "3d": "single",
    "pps": "single",
    "dgps": "dgps",
    "none": "no_solution",
    "2d": "2d_fix_no_height",
}


def _posix(t) -> float:
    if t.tzinfo is not None:
        t = t.astimezone(dt.UTC)
    return calendar.timegm(t.timetuple()[:6]) + t.microsecond * 1e-6


def _first_time(points) -> float:
    """UTC of a segment's first timed point (segments without times last)."""
    times = [_posix(p.time) for p in points if p.time is not None]
    return times[0] if times else math.inf


def read_gpx(path: str | Path, sigma_table: dict[str, float] | None = None) -> GPSFixes:
    """Read the track points of a GPX file into :class:`.fixes.GPSFixes`."""
    import gpxpy
    import gpxpy.gpx

    table = {**UERE_M, **(sigma_table or {})}
    path = Path(path)
    text = path.read_text(errors="replace")
    if not text.strip():
        raise bad_input(path.name, "an empty file", "a GPX track", "export the track again")
    try:
        doc = gpxpy.parse(text)
    except gpxpy.gpx.GPXException as exc:
        raise bad_input(path.name, str(exc)[:120], "a valid GPX file", "re-export it") from exc
    segments = [seg.points for trk in doc.tracks for seg in trk.segments if seg.points]
    points = [p for seg in sorted(segments, key=_first_time) for p in seg]
    if not points:
        what = f"{len(doc.tracks)} tracks, {len(doc.routes)} routes, {len(doc.waypoints)} waypoints"
        raise bad_input(
            f"{path.name} tracks",
            f"no track points ({what})",
            "a recorded track (<trk><trkseg><trkpt time=... ele=...>)",
            "export the recorded track, not a route or waypoints",
        )
    skipped: Counter = Counter()
    rows = []
    for p in points:
        kind = FIX_KIND.get(p.type_of_gpx_fix, "unknown_fix_type")
        if kind not in table:
            skipped[kind] += 1
        elif p.time is None:
            skipped["no_time"] += 1
        elif p.elevation is None:
            skipped["no_elevation"] += 1
        else:
            sig = sigma_from_dop(
                kind,
                math.nan if p.horizontal_dilution is None else float(p.horizontal_dilution),
                None if p.vertical_dilution is None else float(p.vertical_dilution),
                table,
            )
            # ``ele`` alone does not say which surface it is above (sea level or the
            # ellipsoid); with ``geoidheight`` (GPX 1.1, as NMEA's separation) it is sea level
            sep = p.geoid_height
            h = float(p.elevation) + (0.0 if sep is None else float(sep))
            rows.append((_posix(p.time), p.latitude, p.longitude, h, *sig, kind, sep is None))
    return GPSFixes.collect(rows, skipped, "gpx", path.name)
