"""Checkpoint heights in the certified DEM's vertical datum (``glacimap certify``).

A surveyor's GNSS checkpoints are ellipsoidal heights (or heights above a national geoid);
SRTM, NASADEM and ASTER are above EGM96, GLO-30 above EGM2008, glacimap's maps above the
ellipsoid. Compared as they are, the geoid's undulation (tens of metres) becomes the DEM's
"bias" and most of its RMSE. Each side's datum is what it states -- the DEM's compound CRS
or a glacimap product's ``vertical_datum``, the checkpoints' compound or 3-D CRS
(``EPSG:4979``: ellipsoidal) -- else what the caller says (``dem_heights``,
``checkpoint_heights``); when both are known and differ, the checkpoints are carried to the
DEM's datum at their positions (:mod:`terrain.vertical_datum`), and the certificate's
``checkpoints.heights`` records both datums and the shift.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from terrain.vertical_datum import (
    datum_words,
    dem_height_datum,
    geoid_height,
    split_vertical,
    stated_or_given,
)

__all__ = ["checkpoints_in_dem_datum"]


def checkpoints_in_dem_datum(
    cps: Any, raster: Any, dem_heights: str | None = None, checkpoint_heights: str | None = None
) -> tuple[Any, dict[str, Any]]:
    """``cps`` with their heights in ``raster``'s vertical datum, and the record of it.

    Parameters
    ----------
    cps : toolkit.certify_io.Checkpoints
    raster : toolkit.dem_io.DemRaster
    dem_heights, checkpoint_heights : str, optional
        ``"ellipsoidal"``, ``"egm96"``, ``"egm2008"`` or a national vertical CRS
        (``"EPSG:5941"``) where the DEM / the checkpoints do
        not state their datum (an option that contradicts their own statement is an error).

    Returns
    -------
    (Checkpoints, dict)
        The checkpoints (new heights where carried, else the same object) and
        ``{"dem", "checkpoints", "shift_m", "note"}`` (datums or None, the mean shift added
        to the checkpoints' heights, words).
    """
    dem_stated = split_vertical(raster.grid.crs)[1] or dem_height_datum(raster.provenance)
    cp_stated = cps.height_datum or (None if cps.crs is None else split_vertical(cps.crs)[1])
    d_dem = stated_or_given(dem_stated, dem_heights, "--dem-heights", "DEM")
    d_cp = stated_or_given(cp_stated, checkpoint_heights, "--checkpoint-heights", "checkpoints")
    record: dict[str, Any] = {"dem": d_dem, "checkpoints": d_cp, "shift_m": 0.0}
    if d_dem is None or d_cp is None or d_dem == d_cp:
        known = d_dem or d_cp
        unknown = "the DEM states" if d_dem is None else "the checkpoints state"
        record["note"] = (
            f"both in heights above {datum_words(known)}"
            if d_dem == d_cp and known is not None
            else f"heights compared as stored ({unknown} no vertical datum"
            + (f"; taken as above {datum_words(known)}" if known else "")
            + "): pass --dem-heights / --checkpoint-heights (ellipsoidal, egm96, egm2008, "
            "EPSG:CODE) if the two differ"
        )
        return cps, record
    from pyproj import CRS, Transformer

    crs = split_vertical(cps.crs)[0] if cps.crs is not None else raster.grid.crs
    to_ll = Transformer.from_crs(CRS.from_user_input(crs), "EPSG:4326", always_xy=True)
    ok = np.all(np.isfinite(cps.xy), axis=1)
    lon, lat = to_ll.transform(np.where(ok, cps.xy[:, 0], 0.0), np.where(ok, cps.xy[:, 1], 0.0))
    lon, lat = np.asarray(lon, float), np.asarray(lat, float)
    ok &= np.isfinite(lon) & np.isfinite(lat)  # unprojectable rows: counted by certify

    def undulation(datum: str, field: str) -> np.ndarray:
        n = np.zeros(cps.n)
        if datum != "ellipsoidal":  # errors name the option of the datum that needs a grid
            n[ok] = geoid_height(lon[ok], lat[ok], datum, field)
        return n

    # h = H + N: into the DEM's datum
    shift = undulation(d_cp, "--checkpoint-heights") - undulation(d_dem, "--dem-heights")
    record["shift_m"] = float(np.mean(shift[ok])) if ok.any() else 0.0
    record["note"] = (
        f"checkpoint heights above {datum_words(d_cp)} carried to the DEM's "
        f"({datum_words(d_dem)}): {record['shift_m']:+.2f} m on average"
    )
    return replace(cps, z=cps.z + shift), record
