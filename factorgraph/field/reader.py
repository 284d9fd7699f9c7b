"""Read a rover's field folder (docs/field-format.md) into a :class:`MeasurementLog`.

Order of work: manifest -> odometry (keyframes, rover clock) -> GPS file (any of NMEA, GPX,
RTKLIB) -> projection to the map CRS -> clock offset (given, or estimated) -> gross-outlier
gate -> fixes onto keyframes -> tilt, camera, tracks. Every record not used is counted by
reason in the :class:`IngestReport`, which the log carries as ``log.ingest``.
"""

from __future__ import annotations

import difflib
import json
from collections import Counter
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from terrain.errors import bad_input

from ..log import MeasurementLog
from ..sensors import SensorSuite
from .clock import check_overlap, estimate_clock_offset
from .fixes import UERE_M, GPSFixes, crs_area_warning, project_fixes, utm_zone
from .gate import gross_outliers
from .gpx import read_gpx
from .intrinsics import read_camera, undistort
from .nmea import read_nmea
from .odometry import nearest_keyframe, read_odometry, read_tilt, read_tracks
from .report import IngestReport
from .rtklib import read_rtklib
from .stops import STOPS_FILE, read_stops

__all__ = ["FIELD_FORMAT", "GPS_SUFFIXES", "MANIFEST", "read_field_log"]

FIELD_FORMAT = "glacimap-field/1"
MANIFEST = "survey.json"
#: GPS file suffix -> format (when ``gps.format`` is not given).
GPS_SUFFIXES = {".nmea": "nmea", ".nma": "nmea", ".gpx": "gpx", ".pos": "rtklib", ".llh": "rtklib"}
_KEYS = {
    "format", "crs", "origin", "seed", "clock_offset_s", "sync_tolerance_s", "lever_arm_m",
    "gps", "odometry", "tilt", "tracks", "camera", "sensors", "stops", "images",
}  # fmt: skip
#: The frames folder (PNG + ``timestamps.csv`` on the rover clock) when ``images`` is not named.
IMAGES_DIR = "images"
_GPS_KEYS = {"file", "format", "crs", "date", "sigma_by_quality"}


def _check_keys(where: str, got: dict, known: set[str]) -> None:
    for key in sorted(set(got) - known):
        near = difflib.get_close_matches(key, sorted(known), n=1)
        hint = f"did you mean {near[0]!r}?" if near else f"known keys: {sorted(known)}"
        raise bad_input(f"{where} key", key, "a documented key (docs/field-format.md)", hint)


def _manifest(folder: Path) -> dict[str, Any]:
    path = folder / MANIFEST
    if not folder.is_dir():
        raise bad_input("folder", str(folder), "a field folder", "see docs/field-format.md")
    if not path.is_file():
        raise bad_input(
            "folder", str(folder), f"a field folder with {MANIFEST}", "see docs/field-format.md"
        )
    try:
        man = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise bad_input(MANIFEST, str(exc)[:120], "valid JSON", "repair it") from exc
    if not isinstance(man, dict) or man.get("format") != FIELD_FORMAT:
        got = man.get("format") if isinstance(man, dict) else type(man).__name__
        raise bad_input(
            f"{MANIFEST} format", got, repr(FIELD_FORMAT), f'add "format": "{FIELD_FORMAT}"'
        )
    _check_keys(MANIFEST, man, _KEYS)
    gps = man.get("gps", {})
    if isinstance(gps, str):
        gps = {"file": gps}
    _check_keys(f"{MANIFEST} gps", gps, _GPS_KEYS)
    man["gps"] = gps
    return man


def sniff_gps_format(path: Path) -> str | None:
    """``nmea``, ``gpx`` or ``rtklib`` from the first kilobytes of a file (loggers write NMEA
    as ``.txt``, ``.log`` or ``.ubx.nmea``; RTKLIB as ``.txt``); None when none fits."""
    try:
        head = path.read_bytes()[:8192].decode("utf-8", errors="replace")
    except OSError:
        return None
    lines = [ln.strip() for ln in head.splitlines() if ln.strip()][:50]
    if "<gpx" in head[:2000]:
        return "gpx"
    if (
        lines
        and lines[0].startswith("%")
        and any(ln.startswith("%") and ("GPST" in ln or "UTC" in ln) for ln in lines)
    ):
        return "rtklib"
    nmea = sum(1 for ln in lines if "$" in ln and "*" in ln and "GGA" in ln)
    return "nmea" if nmea else None


def _gps_file(folder: Path, spec: dict[str, Any]) -> tuple[Path, str]:
    if "file" in spec:
        path = folder / spec["file"]
        if not path.is_file():
            raise bad_input(
                f"{MANIFEST} gps.file", spec["file"], "an existing file", "check the name"
            )
    else:
        found = sorted(p for p in folder.iterdir() if p.suffix.lower() in GPS_SUFFIXES)
        if not found:  # a logger's .txt / .log: recognised by its content
            found = sorted(
                p for p in folder.iterdir()
                if p.is_file() and p.suffix.lower() in (".txt", ".log", ".ubx", ".dat", "")
                and sniff_gps_format(p)
            )  # fmt: skip
        if len(found) != 1:
            raise bad_input(
                "GPS file",
                [p.name for p in found],
                f"exactly one of *{', *'.join(GPS_SUFFIXES)} (or gps.file in {MANIFEST})",
                'name it in survey.json: "gps": {"file": ...}',
            )
        path = found[0]
    fmt = spec.get("format") or GPS_SUFFIXES.get(path.suffix.lower()) or sniff_gps_format(path)
    if fmt not in ("nmea", "gpx", "rtklib"):
        raise bad_input("gps.format", fmt, "'nmea', 'gpx' or 'rtklib'", f"set it for {path.name}")
    return path, fmt


def _read_gps(path: Path, fmt: str, spec: dict[str, Any]) -> GPSFixes:
    table = spec.get("sigma_by_quality")
    if table is not None:  # a misspelt kind would silently keep the default sigma
        if not isinstance(table, dict):
            raise bad_input(
                f"{MANIFEST} gps.sigma_by_quality", table, "a {kind: m} map", 'e.g. {"single": 2.5}'
            )
        _check_keys(f"{MANIFEST} gps.sigma_by_quality", table, set(UERE_M))
        bad = {k: v for k, v in table.items() if not (isinstance(v, int | float) and v > 0)}
        if bad:
            raise bad_input(
                f"{MANIFEST} gps.sigma_by_quality", bad, "1-sigma > 0 (m)", "fix the value"
            )
    if fmt == "nmea":
        return read_nmea(path, date=spec.get("date"), sigma_table=table)
    if fmt == "gpx":
        return read_gpx(path, sigma_table=table)
    return read_rtklib(path)


def _gaps(t: np.ndarray) -> dict[str, float]:
    if t.size < 3:
        return {"count": 0, "longest_s": 0.0, "total_s": 0.0, "threshold_s": 0.0}
    d = np.diff(t)
    thr = max(3.0 * float(np.median(d)), 2.0)
    big = d[d > thr]
    return {
        "count": int(big.size),
        "longest_s": float(big.max()) if big.size else 0.0,
        "total_s": float(big.sum()),
        "threshold_s": thr,
    }


def _images_folder(folder: Path, man: dict[str, Any]) -> Path | None:
    """The folder of camera frames: ``survey.json`` ``images``, else ``images/`` if present."""
    if "images" in man:
        path = folder / str(man["images"])
        if not (path / "timestamps.csv").is_file():
            raise bad_input(
                f"{MANIFEST} images",
                str(man["images"]),
                "a folder with the frames and timestamps.csv (t_s on the rover clock, file)",
                "check the name, or remove the key",
            )
        return path
    path = folder / IMAGES_DIR
    return path if path.is_dir() else None


def _observations(folder, man, t_kf, tol, images_dir, rep):
    """The feature observations of ``tracks.csv``; none yet when the front-end will track
    ``images_dir`` instead (then a tracks table, if any, is not read)."""
    name = man.get("tracks", "tracks.csv")
    if images_dir is not None:
        return np.zeros(0, int), np.zeros(0, int), np.zeros((0, 2)), {}
    if not (folder / name).is_file():
        fix = "add tracks.csv, or the camera frames with images/timestamps.csv"
        if (folder / str(man.get("images", IMAGES_DIR))).is_dir():
            fix = "track the frames in images/: drop --no-images (images=False)"
        raise bad_input(
            "tracks", str(folder / name), "a tracks table, or camera frames in images/", fix
        )
    rep.tracks = name
    return read_tracks(folder / name, t_kf, tol)


def read_field_log(
    folder: str | Path,
    crs: str | None = None,
    clock_offset_s: float | None = None,
    sync_tolerance_s: float | None = None,
    images: bool = True,
    progress: Any = None,
) -> tuple[MeasurementLog, IngestReport]:
    """Read a field folder (docs/field-format.md) into a keyframe :class:`MeasurementLog`.

    Parameters
    ----------
    folder : path
        Folder with ``survey.json``, a GPS file (NMEA ``.nmea``, ``.gpx``, RTKLIB ``.pos``),
        ``odometry.csv``, ``tracks.csv`` and/or ``images/`` (camera frames), optional
        ``tilt.csv``, ``camera.yaml`` and ``stops.csv`` (the keyframes the rover stood on
        ground-control points).
    crs : str, optional
        Projected map CRS (overrides ``survey.json`` ``crs``). The local frame is ENU metres
        from ``origin`` (``survey.json``, or the first fix rounded to the metre).
    clock_offset_s : float, optional
        ``utc_s - t_rover_s`` (overrides ``survey.json``); neither given: estimated by
        aligning the GPS course with the odometry's (:mod:`factorgraph.field.clock`).
    sync_tolerance_s : float, optional
        Largest time between a fix and the keyframe it is attached to (default
        ``survey.json`` ``sync_tolerance_s``, else half the median keyframe interval: every fix
        goes to its nearest keyframe). A fix ``dt`` from its keyframe keeps its position,
        its horizontal sigma widened (in quadrature) by the distance driven in ``dt``.
    images : bool
        When the folder has camera frames (``images/`` or ``survey.json`` ``images``), run
        the OpenCV front-end on them (:func:`factorgraph.vision.track_log_frames`; the
        tracks stored beside the frames are reused when their inputs match) and use its
        tracks instead of ``tracks.csv``; False: ``tracks.csv`` (required then).
    progress : callable, optional
        ``progress(k, K)`` while the front-end tracks the frames.

    Returns
    -------
    (MeasurementLog, IngestReport)
        The log (``gps_sigma`` per fix, ``ingest`` = the report as a dict; no truth) and the
        report of what was used and skipped.
    """
    folder = Path(folder)
    man = _manifest(folder)
    sensors = SensorSuite.from_dict(man.get("sensors", {}) or {})
    map_crs = crs or man.get("crs")
    rep = IngestReport()
    t_kf, odom = read_odometry(folder / man.get("odometry", "odometry.csv"))
    step = np.linalg.norm(odom[:, 3:], axis=1)
    travelled = np.concatenate([[0.0], np.cumsum(step)])
    tol = sync_tolerance_s if sync_tolerance_s is not None else man.get("sync_tolerance_s")
    tol = float(tol) if tol is not None else 0.5 * float(np.median(np.diff(t_kf)))
    rep.sync_tolerance_s = tol

    gps_path, fmt = _gps_file(folder, man["gps"])
    fixes = _read_gps(gps_path, fmt, man["gps"])
    rep.gps_file, rep.gps_format, rep.gps_records = gps_path.name, fmt, fixes.n_records
    skipped: Counter = Counter(fixes.skipped)
    if not map_crs:  # never guessed: the error names the site's UTM zone to write in
        raise bad_input(
            f"{MANIFEST} crs",
            None,
            "the map CRS (projected, metres)",
            f'add "crs": "{utm_zone(fixes.lon_deg, fixes.lat_deg)}" (the UTM zone of the GPS '
            "fixes) or the national grid you map in",
        )
    enh = project_fixes(fixes, man["gps"].get("crs", "EPSG:4979"), map_crs)
    area = crs_area_warning(fixes.lon_deg, fixes.lat_deg, map_crs)
    if area:
        rep.warnings.append(area)
    lever = np.asarray(man.get("lever_arm_m", [0.0, 0.0, 0.0]), float)
    if lever.shape != (3,) or not np.isfinite(lever).all() or np.hypot(*lever[:2]) > 1e-3:
        raise bad_input(
            f"{MANIFEST} lever_arm_m",
            lever.tolist(),
            "[0, 0, h]: the antenna h m straight above the body origin (x, y not supported)",
            "mount the antenna above the odometry origin, or correct the fixes beforehand",
        )
    enh[:, 2] -= lever[2]
    rep.lever_arm_m = lever.tolist()
    sigma = np.where(np.isfinite(fixes.sigma), fixes.sigma, np.asarray(sensors.gps.sigma_white_m))

    offset = clock_offset_s if clock_offset_s is not None else man.get("clock_offset_s")
    rep.clock_source = "argument" if clock_offset_s is not None else MANIFEST
    if offset is None:
        offset, rep.clock_fit = estimate_clock_offset(t_kf, odom, fixes.utc_s, enh[:, :2])
        rep.clock_source = "estimated"
    rep.clock_offset_s = float(offset)
    t_fix = fixes.utc_s - rep.clock_offset_s
    check_overlap(t_kf, t_fix, rep.clock_offset_s, rep.clock_source)

    gross = gross_outliers(t_fix, enh, sigma, np.interp(t_fix, t_kf, travelled))
    skipped["gross_outlier"] += int(gross.sum())
    k, gap = nearest_keyframe(t_kf, t_fix)
    outside = (t_fix < t_kf[0] - tol) | (t_fix > t_kf[-1] + tol)
    far = (np.abs(gap) > tol) & ~outside
    skipped["outside_traverse"] += int((outside & ~gross).sum())
    skipped["between_keyframes"] += int((far & ~gross).sum())
    ok = ~(gross | outside | far)
    idx = np.flatnonzero(ok)
    idx = idx[np.lexsort((np.abs(gap[idx]), k[idx]))]  # per keyframe, the nearest fix first
    first = np.r_[True, np.diff(k[idx]) != 0] if idx.size else np.zeros(0, bool)
    skipped["extra_fix_same_keyframe"] += int((~first).sum())
    use = idx[first]
    if use.size < 2:
        raise bad_input(
            f"{gps_path.name}",
            f"{use.size} fixes on keyframes (skipped: {dict(+skipped)})",
            "at least 2 fixes during the traverse",
            "check the clock offset and the GPS file",
        )
    speed = np.r_[step, step[-1:]] / np.maximum(np.r_[np.diff(t_kf), np.diff(t_kf)[-1:]], 1e-9)
    sig = sigma[use].copy()
    sig[:, :2] = np.hypot(sig[:, :2], (speed[k[use]] * np.abs(gap[use]))[:, None])

    origin = man.get("origin")
    if origin is None:
        origin = np.round(enh[use[0], :2])
    origin = np.asarray(origin, float)
    xyz = enh[use] - np.r_[origin, 0.0]

    rep.gps_used = int(use.size)
    rep.gps_skipped = {r: int(n) for r, n in sorted(skipped.items()) if n}
    q = Counter(fixes.quality[use].tolist())
    rep.gps_quality = dict(sorted(q.items()))
    rep.gps_sigma_median_m = [float(v) for v in np.median(sig, axis=0)]
    rep.gps_gaps = _gaps(t_fix[use])

    tilt_up = None
    tilt_name = man.get("tilt", "tilt.csv")
    if (folder / tilt_name).is_file():
        tilt_up, rep.tilt = read_tilt(folder / tilt_name, t_kf, tol)
    camera, dist = sensors.camera, None
    cam_name = man.get("camera", "camera.yaml")
    if (folder / cam_name).is_file():
        camera, dist = read_camera(folder / cam_name, sensors.camera)
        rep.camera = f"{cam_name}" + (" (tracks undistorted)" if dist is not None else "")
    else:
        rep.camera = f"{MANIFEST} sensors.camera (no {cam_name})"
    sensors = replace(sensors, camera=camera)
    images_dir = _images_folder(folder, man) if images else None
    obs_k, obs_id, obs_uv, tskip = _observations(folder, man, t_kf, tol, images_dir, rep)
    rep.tracks_skipped = dict(tskip)
    control_id = None
    stops_name = man.get("stops", STOPS_FILE)
    if (folder / stops_name).is_file():
        control_id, sskip, n_rows = read_stops(folder / stops_name, t_kf, tol)
        on = control_id != ""
        rep.stops = {
            "file": stops_name,
            "rows": int(n_rows),
            "keyframes": int(on.sum()),
            "points": sorted(set(control_id[on].tolist())),
            "skipped": dict(sskip),
        }
        if not on.any():
            control_id = None
    elif "stops" in man:
        raise bad_input(f"{MANIFEST} stops", stops_name, "an existing file", "check the name")
    log = MeasurementLog(
        t=t_kf,
        odometry=odom,
        gps_k=k[use],
        gps_xyz=xyz,
        gps_sigma=sig,
        obs_k=obs_k,
        obs_id=obs_id,
        obs_uv=undistort(obs_uv, camera, dist),
        tilt_up=tilt_up,
        control_id=control_id,
        sensors=sensors,
        origin=origin,
        crs=map_crs,
        seed=man.get("seed"),
        ingest=rep.as_dict(),
    )
    if images_dir is not None:  # the camera front-end on the frames (rover clock = t_kf)
        from ..vision import track_log_frames

        # the lens distortion inside the front-end: its RANSAC and its pixels are pinhole
        log, rep.front_end = track_log_frames(log, images_dir, distortion=dist, progress=progress)
        rep.tracks = f"front-end on {images_dir.name}/"
        log = replace(log, ingest=rep.as_dict())
    return log, rep
