"""A GNSS survey's own file as the map's samples: ``glacimap reconstruct profile.gpx``.

Glaciologists' most common elevation survey is a kinematic GNSS profile: a receiver on a
sled, a snowmobile or a backpack logging NMEA 0183, GPX or an RTKLIB solution (``.pos``) over
the ice. Each fix is a sample of the surface: its ellipsoidal height minus the antenna's
height above the snow, at its position projected to the map's CRS (the ``--crs`` given, else
the UTM zone of the fixes' median, said in the note; never guessed silently).

The fixes' 1-sigma is the file's own (RTKLIB ``sdu``, NMEA GST, GPX / NMEA DOP through the
solution kind's UERE, :mod:`factorgraph.field.fixes`); a fix whose file states none takes
its kind's UERE times :data:`~factorgraph.field.fixes.VERTICAL_FACTOR`, counted in the note.
The error of every kind but an RTK fixed solution wanders in time (multipath, ionosphere,
orbits): those fixes carry it as the along-track term of the map's 1-sigma
(``track_z_std_m`` = the fix's vertical 1-sigma, with its time ``t_s``: the same model as a
rover's landmarks, :mod:`toolkit.error_budget`); RTK fixed heights are independent spot
heights. Fixes a reader cannot use are counted by reason, never dropped silently.

Heights are carried to the WGS 84 ellipsoid (the map's datum): NMEA's altitude plus its
geoid separation; an RTKLIB solution as its header states (geodetic heights: EGM96 added
back); heights whose datum the file does not state (GPX ``ele``, a GGA without the
separation) on ``--gnss-heights`` (:data:`UNSTATED_HEIGHTS` by default), said in the note.
Mixing a GPX in sea-level heights with an RTKLIB solution in ellipsoidal ones would otherwise
put a step of the geoid's undulation (tens of metres) between the files.
"""

from __future__ import annotations

import math
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from terrain import ElevationSamples
from terrain.errors import InputError, bad_input
from terrain.grid import as_crs, utm_crs

__all__ = [
    "GNSS_SUFFIXES",
    "INDEPENDENT_KINDS",
    "UNSTATED_HEIGHTS",
    "gnss_format",
    "read_gnss_samples",
]

#: File suffixes read as GNSS logs (others are sniffed: NMEA loggers write .txt / .log).
GNSS_SUFFIXES = {".gpx": "gpx", ".nmea": "nmea", ".nma": "nmea", ".pos": "rtklib", ".llh": "rtklib"}
#: Solution kinds whose height errors are taken as independent between fixes.
INDEPENDENT_KINDS = frozenset({"rtk_fixed"})
#: The date given to an NMEA log without RMC / ZDA sentences: only relative times are used.
_NO_DATE = "2000-01-01"


def gnss_format(path: str | Path) -> str | None:
    """``"nmea"``, ``"gpx"`` or ``"rtklib"`` for a GNSS log (by suffix, else by its first
    kilobytes), ``None`` for anything else (a CSV of samples)."""
    from factorgraph.field.reader import sniff_gps_format

    path = Path(path)
    if path.suffix.lower() in GNSS_SUFFIXES:
        return GNSS_SUFFIXES[path.suffix.lower()]
    if path.suffix.lower() in (".csv", ".tsv", ".parquet"):
        return None
    return sniff_gps_format(path) if path.is_file() else None


def _read(path: Path, fmt: str) -> tuple[Any, str]:
    from factorgraph.field.gpx import read_gpx
    from factorgraph.field.nmea import read_nmea
    from factorgraph.field.rtklib import HEADERLESS, read_rtklib

    if fmt == "gpx":
        return read_gpx(path), ""
    if fmt == "rtklib":
        with path.open(errors="replace") as fh:  # Emlid Reach's .LLH: no RTKLIB header
            headerless = path.suffix.lower() in HEADERLESS and not fh.readline().startswith("%")
        note = "an Emlid Reach .LLH log (RTKLIB's llh columns without a header, GPS time)"
        return read_rtklib(path), note if headerless else ""
    try:
        return read_nmea(path), ""
    except InputError as exc:  # GGA without RMC / ZDA: the map needs relative times only
        if f"{path.name} date" not in str(exc):
            raise
        return read_nmea(
            path, date=_NO_DATE
        ), "no UTC date in the log (no RMC / ZDA): times relative"


def _gpx_waypoints(path: Path) -> Any:
    """A GPX without track points but with waypoints (a handheld GPS's marked spot heights,
    glaciological stakes): the waypoints as fixes without times, or None for a track."""
    from types import SimpleNamespace

    import gpxpy

    from factorgraph.field.fixes import UERE_M, sigma_from_dop
    from factorgraph.field.gpx import FIX_KIND

    try:
        doc = gpxpy.parse(path.read_text(errors="replace"))
    except Exception:  # gpxpy's GPXException: read_gpx says it in words
        return None
    if any(seg.points for trk in doc.tracks for seg in trk.segments) or not doc.waypoints:
        return None
    rows, skipped = [], Counter()
    for w in doc.waypoints:
        kind = FIX_KIND.get(w.type_of_gpx_fix, "unknown_fix_type")
        if kind not in UERE_M:
            skipped[kind] += 1
        elif w.elevation is None:
            skipped["no_elevation"] += 1
        else:
            hdop = math.nan if w.horizontal_dilution is None else float(w.horizontal_dilution)
            vdop = None if w.vertical_dilution is None else float(w.vertical_dilution)
            sep = w.geoid_height
            h = float(w.elevation) + (0.0 if sep is None else float(sep))
            rows.append((w.latitude, w.longitude, h, sep is None, kind,
                         *sigma_from_dop(kind, hdop, vdop, UERE_M)))  # fmt: skip
    if not rows:
        raise bad_input(
            f"{path.name} waypoints",
            f"{len(doc.waypoints)} waypoints, none with an elevation ({dict(skipped)})",
            "waypoints with <ele> (or a recorded track)",
            "export the waypoints with their elevations",
        )
    lat, lon, h, unstated, kinds, se, sn, su = map(np.array, zip(*rows, strict=True))
    return SimpleNamespace(
        lat_deg=lat.astype(float), lon_deg=lon.astype(float), h_m=h.astype(float),
        height_unstated=unstated.astype(bool), height_datum="ellipsoidal", quality=kinds,
        sigma=np.column_stack([se, sn, su]).astype(float), skipped=skipped,
    )  # fmt: skip


#: What a log's heights are above when it does not say (``--gnss-heights auto``): GPX
#: ``ele`` as consumer receivers write it (sea level: their geoid, EGM96 here); an NMEA GGA
#: without the geoid separation as read (a receiver without a geoid model gives the
#: ellipsoidal height there).
UNSTATED_HEIGHTS = {"gpx": "egm96", "nmea": "ellipsoidal", "rtklib": "ellipsoidal"}


def _ellipsoidal(fixes: Any, fmt: str, heights: str) -> tuple[np.ndarray, str]:
    """The fixes' WGS 84 ellipsoidal heights (m) and, in words, what was taken and added.

    A height the file states the datum of (NMEA altitude + separation, an RTKLIB solution's
    header) is read as stated; the others are on ``heights`` (``"auto"``:
    :data:`UNSTATED_HEIGHTS`), carried to the ellipsoid with the geoid's undulation."""
    from terrain.vertical_datum import ellipsoidal_height, height_datum_option

    field = "--gnss-heights"
    heights = height_datum_option(heights, field, allow_auto=True)
    n = fixes.h_m.size
    unstated = np.zeros(n, bool) if fixes.height_unstated is None else fixes.height_unstated
    h = np.asarray(fixes.h_m, float).copy()
    notes = []
    stated = fixes.height_datum
    if stated != "ellipsoidal" and (~unstated).any():  # an RTKLIB solution in geodetic heights
        k = ~unstated
        h[k] = ellipsoidal_height(h[k], fixes.lon_deg[k], fixes.lat_deg[k], stated, field)
        notes.append(
            f"geodetic heights (its header) taken as above {stated.upper()}, RTKLIB's "
            f"default geoid: N {np.mean(h[k] - fixes.h_m[k]):+.2f} m added"
        )
    if unstated.any():
        datum = UNSTATED_HEIGHTS[fmt] if heights == "auto" else heights
        k = unstated
        h[k] = ellipsoidal_height(h[k], fixes.lon_deg[k], fixes.lat_deg[k], datum, field)
        what = (
            f"{int(k.sum())} GGA without a geoid separation"
            if fmt != "gpx"
            else ("GPX ele" if k.all() else f"{int(k.sum())} GPX points without geoidheight")
        )
        how = (
            "as ellipsoidal heights"
            if datum == "ellipsoidal"
            else f"as above {datum.upper()} (N {np.mean(h[k] - fixes.h_m[k]):+.2f} m added)"
        )
        other = "egm96" if datum == "ellipsoidal" else "ellipsoidal"
        why = " (what consumer receivers write)" if heights == "auto" and fmt == "gpx" else ""
        notes.append(
            f"{what} states no datum: read {how}{why}"
            + (f"; pass --gnss-heights {other} if they are not" if heights == "auto" else "")
        )
    return h, "; ".join(notes)


def _map_crs(lon: np.ndarray, lat: np.ndarray, crs: Any) -> tuple[Any, str]:
    if crs is not None:
        out = as_crs(crs, "--crs")
        return out, f"projected to {out.to_string()} (the CRS given)"
    lon0, lat0 = float(np.median(lon)), float(np.median(lat))
    out = utm_crs(lon0, lat0)
    if out is None:
        raise bad_input(
            "GNSS fixes",
            f"median lon {lon0:.3f}, lat {lat0:.3f}",
            "a site inside UTM's latitudes (80 S - 84 N) to be projected to its zone",
            "pass --crs EPSG:3413 (north) or EPSG:3031 (south), polar stereographic",
        )
    return out, f"projected to {out.to_string()} ({out.name}: the fixes' UTM zone)"


def read_gnss_samples(
    path: str | Path, crs: Any = None, antenna_height_m: float = 0.0, heights: str = "auto"
) -> tuple[ElevationSamples, np.ndarray, str]:
    """The surface samples of a GNSS log.

    Parameters
    ----------
    path : path
        NMEA 0183 (GGA, with RMC / ZDA for the date and GST for 1-sigmas), GPX 1.0 / 1.1
        (``trkpt`` with ``ele`` and ``time``; a GPX without a track: its waypoints with
        ``ele``, as independent spot heights) or an RTKLIB ``.pos`` solution.
    crs : str or pyproj.CRS, optional
        Projected CRS of the map; default the UTM zone of the fixes' median position.
    antenna_height_m : float
        Height of the antenna's phase centre above the surface, m (subtracted from every
        fix's ellipsoidal height).
    heights : str
        What the heights the log does not state the datum of are above: ``"ellipsoidal"``,
        ``"egm96"``, ``"egm2008"`` (carried to the ellipsoid with the geoid's undulation,
        :mod:`terrain.vertical_datum`), or ``"auto"`` (:data:`UNSTATED_HEIGHTS`: GPX ``ele``
        above EGM96, an NMEA altitude without its separation as ellipsoidal). Said in
        ``note``.

    Returns
    -------
    samples : ElevationSamples
        ``x, y`` in the map's CRS (m), ``z`` = ellipsoidal height - antenna height (m),
        ``z_var`` the fix's vertical variance (m^2), ``extra["t_s"]`` the fix's UTC time (POSIX
        s; the along-track term uses differences only).
    track_z_std : ndarray of shape (n,)
        The along-track 1-sigma (m): the vertical 1-sigma of fixes whose error wanders in
        time, 0 for RTK fixed ones.
    note : str
        What was read, counted, assumed and projected, in words.

    Raises
    ------
    InputError
        Not a GNSS log, no usable fix, a geographic or unknown ``crs``, a negative or
        non-finite antenna height.
    """
    from pyproj import Transformer

    from factorgraph.field.fixes import UERE_M, VERTICAL_FACTOR

    path = Path(path)
    if not (math.isfinite(antenna_height_m) and antenna_height_m >= 0):
        raise bad_input(
            "--antenna-height",
            antenna_height_m,
            "the antenna's height above the surface, m (>= 0)",
            "measure it from the snow to the antenna's reference point, e.g. 1.8",
        )
    fmt = gnss_format(path)
    if fmt is None:
        raise bad_input(str(path.name), "not a GNSS log", "NMEA, GPX or RTKLIB .pos", "")
    waypoints = _gpx_waypoints(path) if fmt == "gpx" else None
    fixes, date_note = (waypoints, "") if waypoints is not None else _read(path, fmt)
    up = np.asarray(fixes.sigma[:, 2], float)
    kinds = np.asarray(fixes.quality).astype(str)
    unstated = ~(np.isfinite(up) & (up > 0))
    up = np.where(unstated, [VERTICAL_FACTOR * UERE_M.get(k, UERE_M["single"]) for k in kinds], up)
    map_crs, crs_note = _map_crs(fixes.lon_deg, fixes.lat_deg, crs)
    tr = Transformer.from_crs("EPSG:4326", map_crs, always_xy=True)
    x, y = tr.transform(fixes.lon_deg, fixes.lat_deg)
    h, height_note = _ellipsoidal(fixes, fmt, heights)
    z = h - antenna_height_m
    if waypoints is not None:  # marked spot heights: independent, no times
        samples = ElevationSamples(np.column_stack([x, y]), z, up**2, crs=map_crs.to_string())
        skipped = {k: v for k, v in waypoints.skipped.items() if v}
        parts = [
            f"{path.name}: no track, {z.size} waypoints read as spot heights (independent errors)",
            f"{sum(skipped.values())} waypoints not used {skipped}" if skipped else "",
            f"heights: ellipsoidal minus the antenna height {antenna_height_m:g} m",
            height_note,
            f"{int(unstated.sum())} waypoints state no DOP: their kind's UERE x {VERTICAL_FACTOR:g}"
            if unstated.any()
            else "",
            crs_note,
            f"{z.size - samples.n} at a repeated position merged" if samples.n != z.size else "",
        ]
        return samples, np.zeros(samples.n), "; ".join(p for p in parts if p)
    t = np.asarray(fixes.utc_s, float)  # UTC, POSIX s: logs of several days combine
    samples = ElevationSamples(
        np.column_stack([x, y]), z, up**2, crs=map_crs.to_string(), extra={"t_s": t}
    )
    wander = np.array([k not in INDEPENDENT_KINDS for k in kinds])
    track = np.where(wander, up, 0.0)
    if samples.n != z.size:  # fixes at one position (a receiver standing still) merged
        track = np.where(np.any(wander), np.sqrt(samples.z_var), 0.0)
    counts = ", ".join(f"{k} {v}" for k, v in sorted(Counter(kinds.tolist()).items()))
    skipped = {k: v for k, v in fixes.skipped.items() if v}
    parts = [
        f"{path.name}: {fmt} log, {z.size} fixes over {(t[-1] - t[0]) / 60:.1f} min ({counts})",
        f"{sum(skipped.values())} records not used {skipped}" if skipped else "",
        f"heights: ellipsoidal minus the antenna height {antenna_height_m:g} m"
        + ("" if antenna_height_m > 0 else " (none given: --antenna-height)"),
        height_note,
        f"{int(unstated.sum())} fixes state no vertical 1-sigma: their kind's UERE x "
        f"{VERTICAL_FACTOR:g}"
        if unstated.any()
        else "",
        f"{int(wander.sum())} fixes' errors wander in time (all but RTK fixed): the along-track "
        "term of the map's 1-sigma"
        if wander.any()
        else "RTK fixed heights: independent spot heights",
        crs_note,
        date_note,
        f"{z.size - samples.n} fixes at a repeated position merged" if samples.n != z.size else "",
    ]
    return samples, np.asarray(track, float), "; ".join(p for p in parts if p)
