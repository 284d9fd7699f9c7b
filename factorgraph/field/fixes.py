"""GPS fixes as every field reader returns them, their sigmas, time order and projection.

Every GPS reader (:mod:`.nmea`, :mod:`.gpx`, :mod:`.rtklib`) turns its records into a
:class:`GPSFixes`: UTC time, geographic latitude / longitude and ellipsoidal height, a
per-fix 1-sigma (E, N, U) and the receiver's quality label. Records that cannot be used are
counted by reason, never silently dropped.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from terrain.errors import bad_input

__all__ = [
    "UERE_M",
    "VERTICAL_FACTOR",
    "GPSFixes",
    "crs_area_warning",
    "project_fixes",
    "sigma_from_dop",
    "utm_zone",
]

#: Per-axis horizontal 1-sigma (m) at HDOP 1 by solution kind: the user-equivalent range
#: error. Autonomous SPS ~2.5 m, SBAS / DGPS ~0.8 m, RTK float ~0.3 m, RTK fixed ~0.02 m
#: (receiver datasheets, e.g. u-blox ZED-F9P: 1.5 m CEP SPS, 0.01 m + 1 ppm RTK). Override
#: per survey with ``gps.sigma_by_quality`` in ``survey.json``.
UERE_M = {"single": 2.5, "dgps": 0.8, "rtk_float": 0.3, "rtk_fixed": 0.02, "ppp": 0.1}
#: Vertical over horizontal 1-sigma when the file states no vertical sigma (VDOP / HDOP is
#: 1.5-2 for an open sky; the geometry of satellites above the horizon only).
VERTICAL_FACTOR = 1.7
#: What to do when every record of a GPS file was skipped for this reason.
NO_FIX_HINTS = {
    "no_elevation": "export the track with heights (GPX <ele>): the map's heights are the GPS "
    "heights, a 2-D track cannot give them",
    "no_time": "export the track with time stamps: fixes are matched to the odometry by time",
    "no_solution": "the receiver had no position solution: check the antenna and the log",
    "2d_fix_no_height": "log 3-D fixes: a 2-D fix has no height",
    "unparseable_row": "check the file's format against docs/field-format.md",
    "bad_time": "the GGA times of day are not hhmmss[.ss]: check the receiver's NMEA output",
    "bad_position": "the GGA positions are not ddmm.mmmm with an N/S and E/W letter: check "
    "the receiver's NMEA output",
}


def sigma_from_dop(kind: str, hdop: float, vdop: float | None, table: dict[str, float]) -> tuple:
    """Per-axis 1-sigma (E, N, U) in m: ``uere * hdop`` horizontally, ``uere * vdop`` (or
    ``VERTICAL_FACTOR * uere * hdop``) vertically. A missing or non-positive HDOP gives NaN
    (the reader then uses the stated sensor model)."""
    uere = table[kind]
    if not (hdop is not None and math.isfinite(hdop) and hdop > 0):
        return (math.nan, math.nan, math.nan)
    up = uere * vdop if vdop is not None and math.isfinite(vdop) and vdop > 0 else None
    return (uere * hdop, uere * hdop, up if up is not None else VERTICAL_FACTOR * uere * hdop)


@dataclass
class GPSFixes:
    """Usable fixes of one GPS file, in time order.

    Attributes
    ----------
    utc_s : ndarray of shape (n,)
        UTC time, POSIX seconds.
    lat_deg, lon_deg, h_m : ndarray of shape (n,)
        Geographic position; ``h_m`` ellipsoidal height (m) unless the survey says otherwise.
    sigma : ndarray of shape (n, 3)
        Per-fix 1-sigma (E, N, U) in m; NaN where the file states nothing.
    quality : ndarray of shape (n,), str
        Solution kind (a key of :data:`UERE_M`).
    skipped : Counter
        Records not used, by reason.
    n_records : int
        Position records read (used + skipped).
    fmt : str
        ``"nmea"``, ``"gpx"`` or ``"rtklib"``.
    height_datum : str
        What the file states its heights are above: ``"ellipsoidal"`` (WGS 84) or a geoid of
        :data:`terrain.vertical_datum.GEOIDS` (an RTKLIB solution in geodetic heights).
    height_unstated : ndarray of shape (n,), bool, or None
        Fixes whose record does not say which surface its height is above (GPX ``ele``, an
        NMEA GGA without the geoid separation); None: every fix states it.
    """

    utc_s: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    h_m: np.ndarray
    sigma: np.ndarray
    quality: np.ndarray
    skipped: Counter = field(default_factory=Counter)
    n_records: int = 0
    fmt: str = ""
    height_datum: str = "ellipsoidal"
    height_unstated: np.ndarray | None = None

    @classmethod
    def collect(cls, rows: list[tuple], skipped: Counter, fmt: str, source: str) -> GPSFixes:
        """Fixes from ``rows`` of ``(utc_s, lat, lon, h, sE, sN, sU, kind)`` in file order
        (a ninth element True: the record does not state its height's datum).

        Non-finite positions are counted as ``nan_fix``; a time equal to the last kept one as
        ``duplicate_time``, earlier as ``backwards_time`` (the first record wins).
        """
        n_records = len(rows) + sum(skipped.values())
        if not rows:
            main = skipped.most_common(1)[0][0] if skipped else ""
            raise bad_input(
                source,
                f"no usable position record ({n_records} read; skipped {dict(skipped)})",
                "GPS fixes with a solution",
                NO_FIX_HINTS.get(
                    main,
                    "check that the receiver logged positions (NMEA GGA, GPX trkpt, RTKLIB .pos)",
                ),
            )
        kept: list[tuple] = []
        last = -math.inf
        for row in rows:
            if not all(math.isfinite(v) for v in row[:4]):
                skipped["nan_fix"] += 1
            elif row[0] == last:
                skipped["duplicate_time"] += 1
            elif row[0] < last:
                skipped["backwards_time"] += 1
            else:
                kept.append(row)
                last = row[0]
        if not kept:
            raise bad_input(source, dict(skipped), "at least one finite fix", "repair the file")
        a = np.array([r[:7] for r in kept], float)
        unstated = np.array([len(r) > 8 and bool(r[8]) for r in kept])
        return cls(
            utc_s=a[:, 0],
            lat_deg=a[:, 1],
            lon_deg=a[:, 2],
            h_m=a[:, 3],
            sigma=a[:, 4:7],
            quality=np.array([r[7] for r in kept], dtype=object).astype(str),
            skipped=skipped,
            n_records=n_records,
            fmt=fmt,
            height_unstated=unstated if unstated.any() else None,
        )

    def subset(self, keep: np.ndarray) -> GPSFixes:
        """The fixes where ``keep`` is True (counts unchanged)."""
        return GPSFixes(
            self.utc_s[keep],
            self.lat_deg[keep],
            self.lon_deg[keep],
            self.h_m[keep],
            self.sigma[keep],
            self.quality[keep],
            self.skipped,
            self.n_records,
            self.fmt,
            self.height_datum,
            None if self.height_unstated is None else self.height_unstated[keep],
        )


def project_fixes(fixes: GPSFixes, gps_crs: str, map_crs: str) -> np.ndarray:
    """Projected easting, northing (m) and height (n, 3) of the fixes in ``map_crs``.

    ``gps_crs`` is the geographic CRS of the file (EPSG:4326 / EPSG:4979: WGS 84); the height
    passes through unchanged, unless ``gps_crs`` is compound with a geoid's height (e.g.
    ``EPSG:4326+5773``, WGS 84 + EGM96, or a national height such as ``EPSG:4326+5941``):
    then it is carried to the ellipsoid (:func:`terrain.vertical_datum.ellipsoidal_height`).
    A map CRS that is not projected, a vertical CRS glacimap cannot carry, or a transform
    that gives non-finite coordinates (a fix outside the CRS's area), is an InputError.
    """
    from pyproj import CRS, Transformer
    from pyproj.exceptions import CRSError, ProjError

    try:
        src, dst = CRS.from_user_input(gps_crs), CRS.from_user_input(map_crs)
    except CRSError as exc:
        raise bad_input("crs", f"{gps_crs} -> {map_crs}", "CRSs pyproj knows", str(exc)) from exc
    if not dst.is_projected:
        raise bad_input(
            "crs",
            map_crs,
            "a projected map CRS (metres east / north)",
            "give the site's UTM zone or national grid, e.g. crs='EPSG:32608'",
        )
    if not src.is_geographic:
        raise bad_input("gps crs", gps_crs, "a geographic CRS (lat/lon)", "e.g. EPSG:4326")
    h = fixes.h_m
    if src.is_compound:  # heights above a geoid or a national datum: to the ellipsoid
        from terrain.vertical_datum import ellipsoidal_height, split_vertical

        _, datum = split_vertical(src)
        h = ellipsoidal_height(h, fixes.lon_deg, fixes.lat_deg, datum, "gps crs")
        src = src.sub_crs_list[0]
    try:
        tr = Transformer.from_crs(src, dst, always_xy=True)
        e, n = tr.transform(fixes.lon_deg, fixes.lat_deg, errcheck=False)
    except ProjError as exc:  # pragma: no cover - PROJ set-up failures
        raise bad_input("crs", map_crs, "a CRS the GPS can be projected to", str(exc)) from exc
    e, n = np.asarray(e, float), np.asarray(n, float)
    bad = ~(np.isfinite(e) & np.isfinite(n))
    if bad.any():
        i = int(np.argmax(bad))
        raise bad_input(
            "crs",
            f"{map_crs}: fix at lat {fixes.lat_deg[i]:.6f}, lon {fixes.lon_deg[i]:.6f} projects "
            "to inf",
            "a map CRS whose area covers the survey",
            "pick the UTM zone of the site",
        )
    return np.column_stack([e, n, h])


def crs_area_warning(
    lon_deg: np.ndarray, lat_deg: np.ndarray, map_crs: str, max_scale_error: float = 0.002
) -> str | None:
    """Words when the survey lies outside the map CRS's area of use (EPSG's bounds) and the
    CRS's scale error there exceeds ``max_scale_error`` (0.2 %: twice UTM's worst inside a
    zone, 0.1 % at its edge on the equator; a site just across a zone boundary is common and
    fine), with the site's UTM zone; None otherwise.

    A CRS outside its area still projects, but with a distorted scale (UTM 33N at 134.5 W,
    58.4 N: 3.7 %, pyproj ``get_factors``): the map's metres are not metres."""
    from pyproj import CRS, Proj

    crs = CRS.from_user_input(map_crs)
    area = crs.area_of_use
    if area is None:
        return None
    lon, lat = float(np.median(lon_deg)), float(np.median(lat_deg))
    w, s, e, n = area.west, area.south, area.east, area.north
    in_lon = (w <= lon <= e) if w <= e else (lon >= w or lon <= e)  # crossing 180
    if in_lon and s <= lat <= n:
        return None
    f = Proj(crs).get_factors(lon, lat)
    scale = max(abs(f.meridional_scale - 1.0), abs(f.parallel_scale - 1.0))
    if scale <= max_scale_error:
        return None
    hint = f"; the site's UTM zone is {utm_zone(lon_deg, lat_deg)}"
    return (
        f"the map CRS {crs.to_string()}'s area of use ({w:g} to {e:g} E, {s:g} to {n:g} N) "
        f"misses this survey at {lon:.3f} E, {lat:.3f} N: its scale is off by "
        f"{100 * scale:.1f} % there{hint}"
    )


def utm_zone(lon_deg: np.ndarray, lat_deg: np.ndarray) -> str:
    """``EPSG:326zz`` / ``EPSG:327zz``: the WGS 84 UTM zone of the fixes' median position
    (a polar stereographic CRS outside UTM's latitudes)."""
    from terrain.grid import utm_crs

    lat = float(np.median(lat_deg))
    crs = utm_crs(float(np.median(lon_deg)), lat)
    if crs is None:
        return "EPSG:3031 (polar stereographic south)" if lat < 0 else "EPSG:3413 (north)"
    return f"EPSG:{crs.to_epsg()}"
