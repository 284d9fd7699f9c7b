"""ICESat-2 land-ice heights (ATL06) as samples: ``glacimap reconstruct ATL06_*.h5``.

ATL06 (Smith et al. 2019, *Remote Sensing of Environment* 233, 111352) gives the surface
height of 40 m segments every 20 m along six beams (``gt1l`` ... ``gt3r``): per segment
``land_ice_segments/latitude``, ``longitude``, ``h_li`` (m above the WGS 84 ellipsoid,
ITRF2014), ``h_li_sigma`` (its 1-sigma from the photons' fit, m), ``sigma_geo_h`` (the
geolocation's vertical 1-sigma, m) and ``atl06_quality_summary`` (0: no likely problem).
Read through h5py:

- every beam the file holds; a segment flagged by ``atl06_quality_summary`` or without a
  height (the fill value 3.4028235e38) is left out and counted;
- each kept segment is a sample: its position projected to ``--crs`` or to the UTM zone of
  the segments' median (polar sites name EPSG:3031 / 3413 themselves), its height as given
  (the map's datum is the ellipsoid, as for GNSS logs), its variance ``h_li_sigma^2 +
  sigma_geo_h^2`` (independent between segments: no along-track term).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from pyproj import CRS, Transformer

from terrain import ElevationSamples
from terrain.errors import bad_input
from terrain.grid import utm_crs

from .samples_io import SampleTable

__all__ = ["BEAMS", "read_atl06"]

BEAMS = ("gt1l", "gt1r", "gt2l", "gt2r", "gt3l", "gt3r")
#: ATL06's fill value for a float field (``_FillValue``): anything above is no value.
FILL = 1e38


def _field(group: Any, name: str, n: int, default: float) -> np.ndarray:
    """A segment field as float (fill values -> NaN); ``default`` where the file has none."""
    if name not in group:
        return np.full(n, default)
    values = np.asarray(group[name][:], dtype=float)
    fill = group[name].attrs.get("_FillValue")
    bad = np.abs(values) >= FILL
    if fill is not None:
        bad |= values == float(np.asarray(fill).ravel()[0])
    return np.where(bad, np.nan, values)


def read_atl06(path: str | Path, crs: Any = None) -> SampleTable:
    """An ATL06 granule's good land-ice segments as samples (module docstring).

    Parameters
    ----------
    path : path-like
        An ATL06 HDF5 file (``.h5``), whole or subset (any of its beams).
    crs : str or pyproj.CRS, optional
        The map's projected CRS; default the UTM zone of the segments' median.

    Raises
    ------
    InputError
        A file h5py cannot read or without ``gt*/land_ice_segments``; no good segment; a
        polar site without ``crs``; a geographic ``crs``.
    """
    import h5py

    path = Path(path)
    try:
        handle = h5py.File(path, "r")
    except OSError as exc:
        raise bad_input("SAMPLES", path.name, "an HDF5 file h5py reads", str(exc)) from exc
    parts, notes = [], []
    with handle as f:
        beams = [b for b in BEAMS if f"{b}/land_ice_segments" in f]
        if not beams:
            raise bad_input(
                "SAMPLES",
                path.name,
                "an ICESat-2 ATL06 granule (groups gt1l ... gt3r / land_ice_segments)",
                "pass an ATL06 file, or export other HDF5 data to CSV",
            )
        for beam in beams:
            seg = f[f"{beam}/land_ice_segments"]
            n = seg["h_li"].shape[0]
            cols = {
                k: _field(seg, k, n, d)
                for k, d in (
                    ("latitude", np.nan),
                    ("longitude", np.nan),
                    ("h_li", np.nan),
                    ("h_li_sigma", np.nan),
                    ("sigma_geo_h", 0.0),
                    ("atl06_quality_summary", 0.0),
                )
            }
            parts.append(cols)
    cat = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    total = cat["h_li"].size
    flagged = cat["atl06_quality_summary"] != 0
    missing = ~flagged & ~np.isfinite(
        cat["h_li"] + cat["h_li_sigma"] + cat["latitude"] + cat["longitude"]
    )
    keep = ~flagged & ~missing
    notes.append(
        f"{path.name}: ICESat-2 ATL06, beams {', '.join(beams)}: {total:,} segments, "
        f"{int(keep.sum()):,} kept"
    )
    if flagged.any():
        notes.append(f"left out {int(flagged.sum()):,} flagged by atl06_quality_summary")
    if missing.any():
        notes.append(f"left out {int(missing.sum()):,} without a height or its 1-sigma")
    if not keep.any():
        raise bad_input(
            "SAMPLES",
            f"{path.name} ({total:,} segments)",
            "some segments with atl06_quality_summary 0 and a height",
            "use another granule (or its other beams)",
        )
    lon, lat = cat["longitude"][keep], cat["latitude"][keep]
    if crs is not None:
        target = CRS.from_user_input(crs)
        if not target.is_projected:
            raise bad_input("--crs", crs, "a projected CRS in metres (the map's)", "e.g. EPSG:3413")
        said = "the CRS given"
    else:
        target = utm_crs(float(np.median(lon)), float(np.median(lat)))
        said = "the UTM zone of the segments"
        if target is None:
            raise bad_input(
                "--crs",
                None,
                f"the map's CRS for {path.name} (lat {np.median(lat):.2f}: beyond UTM's)",
                "pass --crs EPSG:3413 (Arctic) or EPSG:3031 (Antarctic)",
            )
    xy = np.column_stack(
        Transformer.from_crs("EPSG:4326", target, always_xy=True).transform(lon, lat)
    )
    notes.append(f"projected to {target.to_string()} ({said})")
    z_var = cat["h_li_sigma"][keep] ** 2 + cat["sigma_geo_h"][keep] ** 2
    notes.append(
        "heights above the WGS 84 ellipsoid (ITRF2014); variance h_li_sigma^2 + sigma_geo_h^2 "
        "(median 1-sigma " + f"{np.sqrt(np.median(z_var)):.3f} m)"
    )
    samples = ElevationSamples(xy, cat["h_li"][keep], z_var, crs=target.to_string())
    if samples.n_merged:
        notes.append(f"{samples.n_merged} segments at a repeated position merged")
    return SampleTable(samples, np.zeros(samples.n), 0.0, "; ".join(notes))
