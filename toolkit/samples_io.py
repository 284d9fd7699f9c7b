"""Read terrain samples from CSV for ``glacimap reconstruct``: coordinates with the checkpoint
reader's header aliases and CRS rules (a ``crs`` column, a ``.crs``/``.prj`` sidecar or the
caller's), never a guessed CRS; geographic coordinates projected to their UTM zone."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from pyproj import CRS, Transformer
from pyproj.aoi import AreaOfInterest
from pyproj.database import query_utm_crs_info

from factorgraph.field.table import read_text_table
from terrain import ElevationSamples
from terrain.errors import bad_input

from .certify_io import read_checkpoints

__all__ = ["SampleTable", "read_samples"]

#: Optional columns of a samples table (what ``glacimap localize`` / ``process`` write).
OPTIONAL = ("z_var", "track_z_std_m", "shared_offset_std_m", "t_s")


class SampleTable:
    """Samples plus the error-budget columns, in a projected CRS (metres)."""

    def __init__(self, samples: ElevationSamples, track: np.ndarray, shared: float, note: str):
        self.samples, self.track_z_std, self.shared_z_std, self.note = samples, track, shared, note


def _utm_for(lon: np.ndarray, lat: np.ndarray) -> CRS:
    info = query_utm_crs_info(
        datum_name="WGS 84",
        area_of_interest=AreaOfInterest(
            float(lon.min()), float(lat.min()), float(lon.max()), float(lat.max())
        ),
    )
    return CRS.from_epsg(int(info[0].code))


def read_samples(path: str | Path, crs: Any = None) -> SampleTable:
    """Read ``x, y, z[, z_var, track_z_std_m, shared_offset_std_m, t_s]`` (aliases as for
    checkpoints: easting/northing/elevation, lon/lat/height...). ``t_s`` (each sample's mean
    observation time, s) goes into the samples' ``extra["t_s"]``: the along-track term of
    :func:`terrain.volume_change` needs it; a file without it still reads (the term is then
    stated as not available).

    Raises
    ------
    InputError
        No file, missing columns, no CRS anywhere (pass ``--crs``), non-finite values.
    """
    path = Path(path)
    if not path.is_file():
        raise bad_input("SAMPLES", str(path), "an existing CSV file", "check the path")
    table = read_checkpoints(path, crs=crs)
    if table.crs is None:
        raise bad_input(
            "--crs",
            None,
            f"the CRS of {path.name}'s coordinates (a crs column, a {path.stem}.crs sidecar or "
            "--crs)",
            "pass --crs EPSG:32608 (or the survey's projected CRS); glacimap never guesses it",
        )
    import pandas as pd  # a quoted crs column (a WKT with commas) is one field

    cells = read_text_table(path, "SAMPLES").columns()  # the checkpoints' delimiters, encodings
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
    xy, note, map_crs = table.xy, "", table.crs
    if map_crs.is_geographic:
        map_crs = _utm_for(xy[:, 0], xy[:, 1])
        tr = Transformer.from_crs(table.crs, map_crs, always_xy=True)
        xy = np.column_stack(tr.transform(xy[:, 0], xy[:, 1]))
        note = f"geographic coordinates projected to {map_crs.to_string()} ({map_crs.name})"
    z_var = extra_cols[names["z_var"]] if "z_var" in names else np.zeros(table.n)
    track = extra_cols[names["track_z_std_m"]] if "track_z_std_m" in names else np.sqrt(z_var)
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
        track = np.sqrt(samples.z_var)
    return SampleTable(samples, np.asarray(track, float), shared, note)
