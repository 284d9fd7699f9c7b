"""NMEA 0183 GPS logs: GGA positions, RMC dates, GST error estimates (``pynmea2``).

* ``GGA`` gives the time of day, latitude / longitude, fix quality, HDOP, altitude above
  the geoid and the geoid separation; the ellipsoidal height is ``altitude + separation``.
  A GGA without the separation does not say which surface its altitude is above: the fix is
  flagged (``GPSFixes.height_unstated``) and its altitude kept as read.
* ``RMC`` or ``ZDA`` gives the date (GGA has none); without either, ``gps.date`` in
  ``survey.json``. A GGA time of day that falls back by more than 12 h rolls the date over
  to the next day; GGA logged before the first dated sentence take its date, or the day
  before when their time of day is more than 12 h after its (a log started before midnight).
* A logger's prefix before the ``$`` (a time stamp, a channel name) is ignored: the
  sentence starts at the first ``$`` of the line.
* ``GST`` (optional) gives the receiver's own 1-sigma of latitude, longitude and altitude
  (m); when present for a fix it is used instead of the fix quality x HDOP table
  (:data:`.fixes.UERE_M`).

Counted, not fatal: sentences with a bad or missing checksum (fatal above
:data:`MAX_BAD_CHECKSUM_FRACTION` of the ``$`` lines: the file is then corrupt, not noisy),
sentences pynmea2 cannot parse, GGA without a solution (quality 0 or empty position), GGA
whose time of day (``bad_time``) or position (``bad_position``: digits or hemisphere letter)
is malformed under a valid checksum, dead reckoning / manual / simulator fixes (quality 6, 7,
8), and the time-order reasons of :meth:`.fixes.GPSFixes.collect`.

pynmea2 parses and checks each sentence; its fields are read as text and converted here
(:func:`_raw`).
"""

from __future__ import annotations

import calendar
import datetime as dt
import math
from collections import Counter
from pathlib import Path

from terrain.errors import bad_input

from .fixes import UERE_M, GPSFixes, sigma_from_dop

__all__ = ["MAX_BAD_CHECKSUM_FRACTION", "QUALITY", "read_nmea"]

#: Above this fraction of ``$`` lines with a bad checksum the file is refused (a serial
#: link drops a character now and then; a third of the lines bad is a wrong baud rate).
MAX_BAD_CHECKSUM_FRACTION = 0.05
#: GGA fix quality -> solution kind (a key of UERE_M) or the reason the fix is skipped.
QUALITY = {
    0: "no_solution",
    1: "single",
    2: "dgps",
    3: "single",  # PPS
    4: "rtk_fixed",
    5: "rtk_float",
    6: "dead_reckoning_fix",
    7: "manual_input_fix",
    8: "simulator_fix",
}


def _posix(date: dt.date, tod: dt.time) -> float:
    whole = calendar.timegm((date.year, date.month, date.day, tod.hour, tod.minute, tod.second))
    return whole + tod.microsecond * 1e-6


def _float(text) -> float:
    try:
        return float(text)
    except (TypeError, ValueError):
        return math.nan


def read_nmea(
    path: str | Path, date: str | None = None, sigma_table: dict[str, float] | None = None
) -> GPSFixes:
    """Read an NMEA 0183 log into :class:`.fixes.GPSFixes`.

    Parameters
    ----------
    path : path
        Text file of NMEA sentences, one per line.
    date : str, optional
        UTC date ``YYYY-MM-DD`` of the first GGA when the log has no RMC or ZDA sentences.
    sigma_table : dict, optional
        Per-axis 1-sigma at HDOP 1 by solution kind (default :data:`.fixes.UERE_M`).
    """
    import pynmea2

    table = {**UERE_M, **(sigma_table or {})}
    path = Path(path)
    lines = [ln.strip() for ln in path.read_text(errors="replace").splitlines()]
    lines = [ln for ln in lines if ln]
    if not lines:
        raise bad_input(str(path.name), "an empty file", "NMEA sentences", "log GGA + RMC")
    skipped: Counter = Counter()
    n_dollar = 0
    sentences = []
    for ln in lines:
        if "$" not in ln:
            skipped["not_nmea_line"] += 1
            continue
        ln = ln[ln.index("$") :]  # a logger's time stamp / channel prefix before the sentence
        n_dollar += 1
        if "*" not in ln:
            skipped["bad_checksum"] += 1
            continue
        try:
            sentences.append(pynmea2.parse(ln, check=True))
        except pynmea2.ChecksumError:
            skipped["bad_checksum"] += 1
        except pynmea2.ParseError:
            skipped["unparseable_sentence"] += 1
    if n_dollar == 0:
        raise bad_input(
            str(path.name),
            lines[0][:40],
            "NMEA sentences ($..*hh)",
            "export the receiver's NMEA log (GGA with RMC or ZDA), or name the GPS file's "
            "format in survey.json gps.format",
        )
    frac = skipped["bad_checksum"] / n_dollar
    if frac > MAX_BAD_CHECKSUM_FRACTION:
        raise bad_input(
            f"{path.name} checksums",
            f"{skipped['bad_checksum']} of {n_dollar} sentences ({100 * frac:.1f} %) bad",
            f"at most {100 * MAX_BAD_CHECKSUM_FRACTION:.0f} % (a corrupt, not a noisy, log)",
            "check the serial link's baud rate / re-export the log",
        )
    gst = {}
    for s in sentences:
        # a GST whose time is empty or malformed is not used (its fix falls back to the table)
        if s.sentence_type == "GST" and (tod := _time_or_none(s)) is not None:
            sig = (
                _float(_raw(s, "std_dev_longitude")),
                _float(_raw(s, "std_dev_latitude")),
                _float(_raw(s, "std_dev_altitude")),
            )
            if all(math.isfinite(v) and v > 0 for v in sig):
                gst[tod] = sig
    day = dt.date.fromisoformat(date) if date else None
    rows: list[tuple] = []
    pending: list = []  # (GGA, time of day) before the first date
    last_t = None
    for s in sentences:
        kind = s.sentence_type
        if kind in ("RMC", "ZDA") and (s_day := _date(s)) is not None:
            day = s_day
            if pending:  # GGA before the first date: the same day, or the day before
                ref = _time_or_none(s)  # the dated sentence's own time, if it has one
                for g, g_tod in pending:
                    before = _posix(day, g_tod) - _posix(day, ref or g_tod) > 12 * 3600
                    g_day = day - dt.timedelta(days=1) if before else day
                    rows.append(_gga_row(g, g_day, g_tod, gst, table, skipped))
                    last_t = _posix(g_day, g_tod)
                pending.clear()
            continue
        if kind != "GGA":
            continue
        try:
            tod = _time_of_day(s)
        except ValueError:
            skipped["bad_time"] += 1
            continue
        if tod is None:
            skipped["no_time"] += 1
            continue
        if last_t is not None and day is not None:
            if last_t - _posix(day, tod) > 12 * 3600:  # midnight, no RMC to say so
                day = day + dt.timedelta(days=1)
        if day is None:
            pending.append((s, tod))
            continue
        rows.append(_gga_row(s, day, tod, gst, table, skipped))
        last_t = _posix(day, tod)
    if pending:
        raise bad_input(
            f"{path.name} date",
            f"{len(pending)} GGA sentences and no RMC or ZDA",
            "a UTC date: RMC or ZDA sentences in the log or gps.date in survey.json",
            'add "gps": {"date": "YYYY-MM-DD"} to survey.json',
        )
    return GPSFixes.collect([r for r in rows if r is not None], skipped, "nmea", path.name)


def _raw(s, name: str) -> str:
    """Field ``name`` of a parsed sentence as logged (``""`` when the sentence is short).

    The fields are read and converted here, not through pynmea2's attributes: those convert
    inside a bare ``except:`` that returns the raw text on any error, so a Ctrl-C there was
    lost (``glacimap run`` finished instead of stopping) and a malformed time reached the
    caller as text.
    """
    i = type(s).name_to_idx[name]  # pynmea2's own field index, built per sentence class
    return s.data[i] if i < len(s.data) else ""


def _time_of_day(s) -> dt.time | None:
    """The sentence's UTC time of day; ``None`` when empty, ``ValueError`` when malformed."""
    from pynmea2.nmea_utils import timestamp

    text = _raw(s, "timestamp")
    if not text:
        return None
    try:
        return timestamp(text)
    except (IndexError, ValueError) as exc:
        raise ValueError(f"time of day {text!r}") from exc


def _time_or_none(s) -> dt.time | None:
    """The time of day of a sentence that is not a fix (GST, RMC, ZDA); ``None`` when empty
    or malformed."""
    try:
        return _time_of_day(s)
    except ValueError:
        return None


def _date(s) -> dt.date | None:
    """The UTC date of an RMC or ZDA sentence (None when empty or invalid)."""
    from pynmea2.nmea_utils import datestamp

    try:
        if s.sentence_type == "ZDA":
            return dt.date(int(_raw(s, "year")), int(_raw(s, "month")), int(_raw(s, "day")))
        return datestamp(_raw(s, "datestamp"))
    except ValueError:
        return None


def _degrees(text: str, hemisphere: str, letters: str) -> float:
    """``dddmm.mmmm`` and its hemisphere letter (``letters``: positive then negative, "NS" or
    "EW") to signed decimal degrees; ``ValueError`` when either is malformed (pynmea2's
    ``latitude`` reads a missing letter as 0 degrees)."""
    from pynmea2.nmea_utils import dm_to_sd

    if len(hemisphere) != 1 or hemisphere not in letters:
        raise ValueError(f"hemisphere {hemisphere!r}, not one of {letters}")
    sd = dm_to_sd(text)
    return -sd if hemisphere == letters[1] else sd


def _gga_row(s, day, tod, gst, table, skipped) -> tuple | None:
    try:
        q = int(_raw(s, "gps_qual"))
    except ValueError:
        q = 0
    kind = QUALITY.get(q, "unknown_quality_fix")
    lat, lon = _raw(s, "lat"), _raw(s, "lon")
    if kind not in table or not lat or not lon:
        skipped["no_solution" if (not lat or not lon) else kind] += 1
        return None
    try:
        lat_deg = _degrees(lat, _raw(s, "lat_dir"), "NS")
        lon_deg = _degrees(lon, _raw(s, "lon_dir"), "EW")
    except ValueError:
        skipped["bad_position"] += 1
        return None
    sep = _raw(s, "geo_sep")
    h = _float(_raw(s, "altitude")) + (_float(sep) if sep else 0.0)
    sig = gst.get(tod) or sigma_from_dop(kind, _float(_raw(s, "horizontal_dil")), None, table)
    # without the separation the altitude's surface is not stated (ellipsoid or sea level)
    return (_posix(day, tod), lat_deg, lon_deg, h, *sig, kind, not sep)
