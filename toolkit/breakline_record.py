"""The breaklines a map was fitted with, read back from its product: what the certificate
records and the accuracy report shows (a client reads the cliff's step there, not in the
console of whoever made the map).

A product fitted with a :class:`terrain.BreaklineMean` records its lines as a GeoJSON Feature
(``breaklines``: vertices in the map's CRS, each line's width, taper and open ends), its
coefficients with their 1-sigma (``mean_coefficients``: ``step1_m``...) and, on a satellite
prior that smooths the steps, what the DEM lacks of each (``breakline_dem_lacks``;
:func:`terrain.dem_reading.dem_lacks`). :func:`breakline_rows` joins them per line.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

import numpy as np

__all__ = ["breakline_rows"]


def breakline_rows(provenance: Mapping[str, Any]) -> list[dict[str, Any]]:
    """One row per breakline of the map whose product attributes are ``provenance``
    (:attr:`toolkit.certify_io.DemRaster.provenance`); ``[]`` for a map without.

    Each row: ``line`` (1-based), ``n_vertices``, ``length_m``, ``step_m`` and ``step_sd_m``
    (the GLS height up to the line's left, m), ``width_m``, ``open_ends`` (``"first"``,
    ``"last"``, both or none: where the step dies out inside the survey), ``taper_m`` (over
    how long; None for a line run on across), ``dem_lacks_m`` and ``dem_lacks_sd_m`` (what
    the prior DEM lacks of the step in its own metres; None without such a prior) and
    ``vertices`` (k, 2 list, m, the map's CRS).
    """
    text = str(provenance.get("breaklines", "") or "")
    if not text:
        return []
    feature = json.loads(text)
    props = feature.get("properties") or {}
    coef = json.loads(str(provenance.get("mean_coefficients", "") or "{}"))
    lacks_text = str(provenance.get("breakline_dem_lacks", "") or "")
    lacks = json.loads(lacks_text) if lacks_text else []
    rows = []
    for j, coords in enumerate(feature["geometry"]["coordinates"]):
        xy = np.asarray(coords, dtype=float)
        step = coef.get(f"step{j + 1}_m", [None, None])
        ends = (props.get("open_ends") or [[False, False]] * (j + 1))[j]
        lack = lacks[j] if j < len(lacks) else {}
        rows.append(
            {
                "line": j + 1,
                "n_vertices": len(xy),
                "length_m": float(np.linalg.norm(np.diff(xy, axis=0), axis=1).sum()),
                "step_m": step[0],
                "step_sd_m": step[1],
                "width_m": _item(props.get("widths_m"), j),
                "open_ends": [name for name, o in zip(("first", "last"), ends, strict=True) if o],
                "taper_m": _item(props.get("tapers_m"), j),
                "dem_lacks_m": lack.get("m"),
                "dem_lacks_sd_m": lack.get("sd_m"),
                "vertices": xy.tolist(),
            }
        )
    return rows


def _item(values: list | None, j: int) -> Any:
    return None if values is None or j >= len(values) else values[j]
