"""Read terrain samples from CSV for ``glacimap reconstruct``: coordinates with the checkpoint
reader's header aliases and CRS rules (a ``crs`` column, a ``.crs``/``.prj`` sidecar or the
caller's), never a guessed CRS; geographic coordinates projected to their UTM zone."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from pyproj import CRS, Transformer

from terrain import ElevationSamples
from terrain.errors import bad_input
from terrain.grid import utm_crs

__all__ = [
    "SampleTable",
    "read_sample_files",
    "read_samples",
    "sample_columns",
    "utm_zone_for",
]

#: Optional columns of a samples table (what ``glacimap localize`` / ``process`` write).
OPTIONAL = ("z_var", "track_z_std_m", "shared_offset_std_m", "t_s")


class SampleTable:
    """Samples plus the error-budget columns, in a projected CRS (metres)."""

    def __init__(self, samples: ElevationSamples, track: np.ndarray, shared: float, note: str):
        self.samples, self.track_z_std, self.shared_z_std, self.note = samples, track, shared, note
        #: The samples were made from the files (a GNSS log's fixes, a layer's or a cloud's
        #: points, block means): ``reconstruct`` writes them beside the map.
        self.derived = False


def _crs_hint(table: Any) -> str:
    """The fix for a table without a CRS: EPSG:4326 when the columns are named or look like
    longitude/latitude (degrees), else a projected CRS."""
    named, degrees = _lonlat_named(table), _degree_like(table.xy)
    if named or degrees:
        why = "named lon/lat" if named else "all within +-180 / +-90"
        return (
            f"the coordinates are {why}: pass --crs EPSG:4326 (WGS 84 longitude/latitude; "
            "they are then projected to their UTM zone), or the CRS they are in"
        )
    return "pass --crs EPSG:32608 (or the survey's projected CRS)"


def _check_not_degrees(table: Any, path: Path) -> None:
    """Refuse longitude/latitude read as metres of a projected CRS: columns named lon/lat, or
    degree-like values spanning under 1 m (no survey does; a lon/lat table under
    ``--crs EPSG:32608`` made a 1 x 1-cell map and then asked for 0.0026 m cells)."""
    named = _lonlat_named(table)
    span = float(np.ptp(table.xy, axis=0).max()) if table.n else 0.0
    if not named and not (_degree_like(table.xy) and span < 1.0):
        return
    why = (
        f"columns named {table.columns.get('x')}/{table.columns.get('y')}"
        if named
        else f"values within +-180 / +-90 spanning {span:.3g} units"
    )
    raise bad_input(
        "--crs",
        table.crs.to_string(),
        f"the CRS {path.name}'s x, y are in; they look like longitude/latitude in degrees "
        f"({why}), not metres of {table.crs.name}",
        "pass --crs EPSG:4326 (they are then projected to their UTM zone), or fix the columns",
    )


def _lonlat_named(table: Any) -> bool:
    return str(table.columns.get("x", "")).lower() in ("lon", "long", "longitude", "lng")


def _degree_like(xy: np.ndarray) -> bool:
    xy = xy[np.isfinite(xy).all(axis=1)]
    return xy.size > 0 and bool((np.abs(xy[:, 0]) <= 180).all() and (np.abs(xy[:, 1]) <= 90).all())


def read_samples(
    path: str | Path,
    crs: Any = None,
    antenna_height_m: float | None = None,
    gnss_heights: str | None = None,
    point_classes: tuple[int, ...] | None = None,
) -> SampleTable:
    """Read ``x, y, z[, z_var, track_z_std_m, shared_offset_std_m, t_s]`` (aliases as for
    checkpoints: easting/northing/elevation, lon/lat/height...). ``t_s`` (each sample's mean
    observation time, s) goes into the samples' ``extra["t_s"]``: the along-track term of
    :func:`terrain.volume_change` needs it; a file without it still reads (the term is then
    stated as not available). A GNSS log (NMEA, GPX, RTKLIB ``.pos``) is read as its fixes
    (:func:`toolkit.gnss_samples.read_gnss_samples`, less ``antenna_height_m``, its heights
    of unstated datum on ``gnss_heights``, default ``"auto"``). A GIS layer (GeoPackage,
    Shapefile, GeoJSON...) is read as its points' or lines' vertices with their attributes as
    the columns (:func:`toolkit.certify_io.read_layer_table`); a LAS / LAZ cloud as its
    ground points, or ``point_classes`` (:func:`toolkit.point_files.read_las`).

    Raises
    ------
    InputError
        No file, missing columns, no CRS anywhere (pass ``--crs``), non-finite values; an
        antenna height for a CSV (its z is the surface's).
    """
    from .gnss_samples import gnss_format, read_gnss_samples
    from .point_files import point_format

    path = Path(path)
    if not path.is_file():
        raise bad_input(
            "SAMPLES", str(path), "an existing CSV, GNSS, GIS or LAS file", "check the path"
        )
    kind = point_format(path)
    if point_classes is not None and kind != "las":
        raise bad_input(
            "--point-classes",
            ",".join(map(str, point_classes)),
            "a LAS / LAZ point cloud as SAMPLES (classes are a cloud's)",
            "drop --point-classes",
        )
    if gnss_format(path) is not None:
        samples, track, note = read_gnss_samples(
            path, crs, antenna_height_m or 0.0, gnss_heights or "auto"
        )
        return SampleTable(samples, track, 0.0, note)
    if antenna_height_m is not None:
        raise bad_input(
            "--antenna-height",
            antenna_height_m,
            "a GNSS log (NMEA, GPX, RTKLIB .pos) as SAMPLES: a CSV's z is the surface's",
            f"subtract the antenna height in {path.name}, or drop --antenna-height",
        )
    if gnss_heights is not None:
        raise bad_input(
            "--gnss-heights",
            gnss_heights,
            "a GNSS log (NMEA, GPX, RTKLIB .pos) as SAMPLES: a CSV's z is read as given",
            f"convert {path.name}'s heights to the survey's datum, or drop --gnss-heights",
        )
    if kind == "atl06":  # ICESat-2 land-ice heights: --crs is the map's, as for GNSS logs
        from .icesat2 import read_atl06

        return read_atl06(path, crs)
    if kind == "raster":  # a DSM's valid cells (voids to fill); reduced as any survey
        from .point_files import read_raster_points

        xy, z, raster_crs, note = read_raster_points(path, crs)
        xy, map_crs, moved = _projected(xy, raster_crs)
        samples = ElevationSamples(xy, z, 0.0, crs=map_crs.to_string())
        note = f"{note}; {moved}" if moved else note
        return SampleTable(samples, np.zeros(samples.n), 0.0, note)
    if kind == "las":  # every kept point (read_sample_files reduces clouds in chunks)
        from .point_clouds import cloud_table

        return cloud_table([path], crs, point_classes, block_size=None)[0]
    if kind == "vector":  # the layer's attributes are the columns
        from .certify_io import read_layer_table

        table, cells = read_layer_table(path, crs, field="SAMPLES")
    else:  # one parse of the file: its x, y, z and the noise columns
        from .certify_io import read_point_table

        table, cells = read_point_table(path, crs, field="SAMPLES")
    if table.crs is None:
        raise bad_input(
            "--crs",
            None,
            f"the CRS of {path.name}'s coordinates (a crs column, a {path.stem}.crs sidecar or "
            "--crs)",
            _crs_hint(table) + "; glacimap never guesses it",
        )
    import pandas as pd

    extra_cols = {
        c: pd.to_numeric(pd.Series(v), errors="coerce").to_numpy(float) for c, v in cells.items()
    }
    names = {str(n).lower(): n for n in extra_cols}
    bad = table.nan_rows()
    if bad.any():  # a map from fewer samples than the file holds is never made silently
        lines = np.flatnonzero(bad) + 2  # file line numbers: the header is line 1
        shown = ", ".join(str(v) for v in lines[:10]) + (" ..." if lines.size > 10 else "")
        raise bad_input(
            "SAMPLES rows",
            f"{lines.size} of {table.n} with an empty or NaN x, y or z (file lines {shown})",
            "a finite x, y and z on every row",
            f"fill or delete those lines of {path.name}",
        )
    if not table.crs.is_geographic:
        _check_not_degrees(table, path)
    xy, map_crs, note = _projected(table.xy, table.crs)
    if table.note:  # how a GIS layer was read
        note = f"{table.note}; {note}" if note else table.note
    z_var, noise_note = _noise(table, extra_cols, names)
    unread = [c for c in table.ignored_columns if str(c).lower() not in OPTIONAL]
    for extra_note in (
        noise_note,
        f"columns not read: {', '.join(map(str, unread))} (read: x, y, z, z_var or a 1-sigma "
        f"column, {', '.join(OPTIONAL[1:])}, crs)"
        if unread
        else "",
    ):
        if extra_note:
            note = f"{note}; {extra_note}" if note else extra_note
    # Without a track_z_std_m column the samples' errors are independent (spot heights from
    # a GNSS or total-station survey): no along-track term. It was sqrt(z_var), fully shared
    # between neighbours: 200,000 uniform spot heights read 94.3 % held-out coverage at 68.
    has_track = "track_z_std_m" in names
    track = extra_cols[names["track_z_std_m"]] if has_track else np.zeros(table.n)
    if not has_track:
        independent = (
            "no track_z_std_m column: the samples' errors are taken as independent (spot "
            "heights); a rover's landmarks share their trajectory's error and should carry it "
            "(glacimap localize writes it in samples.csv)"
        )
        note = f"{note}; {independent}" if note else independent
    shared = (
        float(extra_cols[names["shared_offset_std_m"]][0])
        if "shared_offset_std_m" in names
        else 0.0
    )
    extra = {}
    if "t_s" in names:
        t = np.asarray(extra_cols[names["t_s"]], float)
        if not np.isfinite(t).all():
            raise bad_input(
                "SAMPLES t_s",
                f"{int((~np.isfinite(t)).sum())} rows without a time",
                "a finite observation time (s) on every row, or no t_s column",
                "fix or drop the column",
            )
        extra["t_s"] = t
    samples = ElevationSamples(xy, table.z, z_var, crs=map_crs.to_string(), extra=extra)
    if samples.n != table.n:  # duplicates merged: the along-track term per merged sample
        track = np.sqrt(samples.z_var) if has_track else np.zeros(samples.n)
        merged = (
            f"{samples.n_merged} rows repeat the x, y of another row: merged into one sample "
            f"each (inverse-variance mean of z), {samples.n} samples from {table.n} rows"
        )
        note = f"{note}; {merged}" if note else merged
    return SampleTable(samples, np.asarray(track, float), shared, note)


def utm_zone_for(lon: float, lat: float, fix: str) -> CRS:
    """The UTM zone the samples at ``lon, lat`` (degrees) are projected to; beyond UTM's
    latitudes an ``InputError`` whose fix is ``fix`` (a polar stereographic CRS)."""
    map_crs = utm_crs(lon, lat)
    if map_crs is None:
        raise bad_input(
            "SAMPLES coordinates",
            f"lon {lon:.3f}, lat {lat:.3f}",
            "a site inside UTM's latitudes (80 S - 84 N) to be projected to its zone",
            fix,
        )
    return map_crs


def _projected(xy: np.ndarray, crs: CRS) -> tuple[np.ndarray, CRS, str]:
    """``xy`` in a projected CRS: as they are, or from degrees to their UTM zone (said)."""
    if not crs.is_geographic:
        return xy, crs, ""
    lon, lat = np.median(xy, axis=0)  # the samples' median position
    fix = "project them to a polar stereographic CRS (EPSG:3031 / 3413) and pass --crs"
    map_crs = utm_zone_for(lon, lat, fix)
    tr = Transformer.from_crs(crs, map_crs, always_xy=True)
    xy = np.column_stack(tr.transform(xy[:, 0], xy[:, 1]))
    return (
        xy,
        map_crs,
        f"geographic coordinates projected to {map_crs.to_string()} ({map_crs.name})",
    )


def _noise(table: Any, extra_cols: dict[str, np.ndarray], names: dict[str, str]):
    """The samples' noise variance (m^2) and a note saying where it came from: ``z_var``
    (m^2), else a 1-sigma column (m; the checkpoint aliases: sigma, z_std, elevation_std...)
    squared, else zeros (the fitted nugget carries the noise). A 1-sigma column was ignored
    before: 0.2 m spot heights were taken as exact."""
    sigma_col = table.columns.get("z_std")
    if "z_var" in names:
        z_var = extra_cols[names["z_var"]]
        if sigma_col is not None and not np.allclose(z_var, table.z_std**2, rtol=1e-6, atol=1e-12):
            raise bad_input(
                "SAMPLES columns",
                f"z_var and {sigma_col!r}",
                f"one noise column (z_var, m^2, or a 1-sigma in m), or two that agree (z_var = "
                f"{sigma_col}^2)",
                "drop one of them",
            )
        return z_var, ""
    if sigma_col is not None:
        return (
            np.asarray(table.z_std, float) ** 2,
            f"column {sigma_col!r} read as each sample's 1-sigma (m): z_var = {sigma_col}^2",
        )
    return (
        np.zeros(table.n),
        "no z_var or 1-sigma column: the samples' noise is left to the fitted nugget",
    )


def sample_columns(table: SampleTable) -> dict[str, np.ndarray]:
    """``table`` as the columns :func:`read_samples` reads back (``x, y, z, z_var,
    track_z_std_m, shared_offset_std_m[, t_s], crs``), as ``glacimap localize`` writes them."""
    s = table.samples
    out = {
        "x": s.xy[:, 0],
        "y": s.xy[:, 1],
        "z": s.z,
        "z_var": s.z_var,
        "track_z_std_m": np.asarray(table.track_z_std, float),
        "shared_offset_std_m": np.full(s.n, float(table.shared_z_std)),
    }
    if "t_s" in s.extra:
        out["t_s"] = np.asarray(s.extra["t_s"], float)
    out["crs"] = np.full(s.n, s.crs.to_string() if s.crs is not None else "")  # never guessed
    return out


def read_sample_files(
    paths: list[str | Path],
    crs: Any = None,
    antenna_height_m: float | None = None,
    gnss_heights: str | None = None,
    point_classes: tuple[int, ...] | None = None,
    block_size: float | str | None = None,
) -> SampleTable:
    """:func:`read_samples` of several files (CSVs, GNSS logs, GIS layers, point clouds: a
    survey's days), as one table in the first file's CRS (``crs``, else the first file's own
    or its fixes' UTM zone; every later file is read into it). Positions repeated across
    files are merged as within one (:class:`terrain.ElevationSamples`); ``t_s`` is kept when
    every file has it. ``block_size`` reduces dense points to block means
    (:func:`toolkit.sample_blocks.reduce_table`; None, the default, keeps every sample; the
    CLI's default is ``"auto"``).
    """
    from .gnss_samples import gnss_format
    from .point_files import point_format
    from .sample_blocks import reduce_table

    paths = [Path(p) for p in paths]
    clouds = [p for p in paths if point_format(p) == "las"]
    reduced = None
    if clouds:  # one survey's clouds read together, a chunk at a time (point_clouds.py)
        from .point_clouds import cloud_table

        cloud, reduced = cloud_table(clouds, crs, point_classes, block_size)
        others = [p for p in paths if p not in clouds]
        table = _joined([clouds[0], *others], crs, antenna_height_m, gnss_heights, cloud)
    else:
        if point_classes is not None:
            raise bad_input(
                "--point-classes",
                ",".join(map(str, point_classes)),
                "a LAS / LAZ point cloud as SAMPLES (classes are a cloud's)",
                "drop --point-classes",
            )
        table = _joined(paths, crs, antenna_height_m, gnss_heights)
    if reduced is None:
        table, reduced = reduce_table(table, block_size)
    table.derived = reduced is not None or any(gnss_format(p) or point_format(p) for p in paths)
    return table


def _joined(
    paths: list[Path],
    crs: Any,
    antenna_height_m: float | None,
    gnss_heights: str | None,
    first: SampleTable | None = None,
) -> SampleTable:
    """The files' samples as one table in the first's CRS; ``first``: the first file's
    table, already read (the clouds')."""
    if first is None:
        first = read_samples(paths[0], crs, antenna_height_m, gnss_heights)
    if len(paths) == 1:
        return first
    into = first.samples.crs.to_string()
    tables = [first] + [read_samples(p, into, antenna_height_m, gnss_heights) for p in paths[1:]]
    for t in tables[1:]:  # a later file was read into the first one's CRS, not one given
        t.note = (t.note or "").replace("(the CRS given)", f"(the CRS of {paths[0].name})")
    for p, t in zip(paths[1:], tables[1:], strict=True):
        if not t.samples.crs.equals(first.samples.crs, ignore_axis_order=True):
            raise bad_input(
                f"SAMPLES {p.name}",
                t.samples.crs.to_string(),
                f"the CRS of {paths[0].name} ({into})",
                "reproject the file, or give its rows a crs column",
            )
    timed = all("t_s" in t.samples.extra for t in tables)
    extra = {"t_s": np.concatenate([t.samples.extra["t_s"] for t in tables])} if timed else {}
    cat = ElevationSamples(
        np.vstack([t.samples.xy for t in tables]),
        np.concatenate([t.samples.z for t in tables]),
        np.concatenate([t.samples.z_var for t in tables]),
        crs=into,
        extra=extra,
    )
    track = np.concatenate([t.track_z_std for t in tables])
    notes = [t.note for t in tables if t.note]
    n_in = sum(t.samples.n for t in tables)
    if cat.n != n_in:  # the along-track term per merged sample, as within one file
        track = np.sqrt(cat.z_var) * (track.max() > 0)
        notes.append(f"{n_in - cat.n} samples at a position another file has: merged")
    if not timed:
        notes.append("t_s dropped: not every file has observation times")
    notes.append(f"{len(paths)} files, {cat.n} samples, in {into}")
    shared = max(t.shared_z_std for t in tables)
    if len({t.shared_z_std for t in tables}) > 1 or shared > 0:
        notes.append(
            f"one shared vertical offset for all files, 1-sigma {shared:g} m (the largest "
            "stated; each survey's own offset is not modelled apart)"
        )
    return SampleTable(cat, np.asarray(track, float), shared, "; ".join(notes))


def samples_height_attrs(paths: list[str | Path], given: str | None) -> dict[str, str]:
    """The product attributes that say what a map made from ``paths`` is in height.

    GNSS logs are carried to the WGS 84 ellipsoid (:mod:`toolkit.gnss_samples`), ICESat-2
    heights are above it (:mod:`toolkit.icesat2`): the
    product's default ``vertical_datum`` says so, and ``given`` may only confirm it. A CSV's
    ``z`` is taken as given, so the map is in the CSV's datum: ``given``
    (``--samples-heights``: ``"ellipsoidal"``, ``"egm96"``, ``"egm2008"``, a national
    vertical CRS such as ``"EPSG:5941"``) names it
    (``height_datum``), else the product says it is not stated -- never the GPS ellipsoid by
    default (``glacimap change`` / ``certify`` would carry it as such). A point cloud whose
    header CRS is compound states its own (``EPSG:32632+5773``: EGM96; ``EPSG:25833+5941``:
    NN2000); a vertical CRS glacimap cannot carry (heights in feet) is named, not converted.

    Raises
    ------
    InputError
        An unknown datum; a geoid for GNSS logs, or for CSVs mixed with them.
    """
    from terrain.vertical_datum import height_datum_option

    from .gnss_samples import gnss_format

    field = "--samples-heights"
    given = None if given is None else height_datum_option(given, field)
    from .point_files import point_format

    logs = [gnss_format(p) is not None or point_format(p) == "atl06" for p in paths]
    if any(logs) and given not in (None, "ellipsoidal"):
        raise bad_input(
            field,
            given,
            "ellipsoidal: GNSS logs and ICESat-2 heights are on the WGS 84 ellipsoid",
            "say what a log's heights are with --gnss-heights; convert a CSV's z to "
            "ellipsoidal heights to map it with logs",
        )
    if all(logs):
        return {}
    from .point_files import is_controller_csv

    exports = [p for p in paths if is_controller_csv(p)]  # Emlid: ellipsoidal heights
    if exports and given not in (None, "ellipsoidal"):
        raise bad_input(
            field,
            given,
            f"ellipsoidal: {Path(exports[0]).name}'s heights are its Ellipsoidal height column",
            "drop --samples-heights, or convert the other files' z to ellipsoidal heights",
        )
    if len(exports) == len(paths):
        given = "ellipsoidal"
    if all(point_format(p) in ("las", "raster") for p in paths):  # a compound CRS states it
        from terrain.vertical_datum import stated_or_given

        from .point_clouds import stated_heights

        stated, words = stated_heights(paths)
        if stated is None and words:  # a vertical datum glacimap does not convert
            return {"vertical_datum": words}
        given = stated_or_given(stated, given, field, "clouds' CRS")
    if given is None:
        return {
            "vertical_datum": "the samples' z as given (their vertical datum not stated: "
            "glacimap reconstruct --samples-heights ellipsoidal | egm96 | egm2008 | EPSG:CODE)"
        }
    from terrain.vertical_datum import height_words

    return {
        "height_datum": given,
        "vertical_datum": f"{height_words(given)} (the samples' z, as stated)",
    }
