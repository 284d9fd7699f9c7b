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

__all__ = ["SAME_LINE_M", "at_shared_width", "breakline_block", "breakline_rows", "step_changes"]

#: Two epochs' lines are one line when no vertex moved by more than this (m).
SAME_LINE_M = 0.01


def breakline_rows(provenance: Mapping[str, Any]) -> list[dict[str, Any]]:
    """One row per breakline of the map whose product attributes are ``provenance``
    (:attr:`toolkit.dem_io.DemRaster.provenance`); ``[]`` for a map without.

    Each row: ``line`` (1-based), ``n_vertices``, ``length_m``, ``step_m`` and ``step_sd_m``
    (the GLS height up to the line's left, m; its 1-sigma carries the width's own),
    ``width_m`` and ``width_sd_m`` (None for a width given, not chosen), ``open_ends`` (``"first"``,
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
                "width_sd_m": _item(props.get("widths_sd_m"), j),
                "open_ends": [name for name, o in zip(("first", "last"), ends, strict=True) if o],
                "taper_m": _item(props.get("tapers_m"), j),
                "dem_lacks_m": lack.get("m"),
                "dem_lacks_sd_m": lack.get("sd_m"),
                "vertices": xy.tolist(),
            }
        )
    return rows


def breakline_block(provenance: Mapping[str, Any]) -> dict[str, Any]:
    """``{"breaklines": rows}`` for a certificate (:func:`breakline_rows`), ``{}`` for a map
    without lines: what a certificate with or without checkpoints states of them."""
    rows = breakline_rows(provenance)
    return {"breaklines": rows} if rows else {}


def step_changes(before: list[dict[str, Any]], after: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per line of ``before`` (:func:`breakline_rows`, vertices kept), the change of its step
    from the ``before`` map to the ``after`` map: ``change_m`` (after - before, m) and
    ``change_sd_m`` (the two maps' 1-sigma combined as independent), or ``reason`` (why
    none is given).

    A change is given for one line drawn in both maps (the same vertices within
    :data:`SAME_LINE_M`) whose two steps are comparable: each 1-sigma carries its width's
    own uncertainty (widths chosen by each map's evidence, 0.41.0 on;
    :func:`terrain.breakline_evidence.width_uncertainty`), or both maps were given the
    same width. Steps fitted at different widths with the 1-sigma given each width are not
    comparable (the same 3 m step read 2.63 +- 0.29 and 4.86 +- 0.55 m at 0.40.0). The two
    maps' width errors are alike where the ground is (the same cliff), so the combined
    1-sigma is conservative: on the eleven real DEMs' 6 m scarps surveyed twice, a 1 m
    growth read +0.43 ... +1.11 m, within 2 sd on 22 of 22 rows (rms z 0.36; unchanged
    ground 0.37), beyond 2 sd of zero on 13 (docs/terrain.md "The width's own
    uncertainty in the step's 1-sigma, and the step's change").
    """
    by_line = {r["line"]: r for r in after}
    out = []
    for b in before:
        a, row = by_line.get(b["line"]), {"line": b["line"]}
        if a is None:
            row["reason"] = f"the after map has no line {b['line']}"
        elif not _same_line(b["vertices"], a["vertices"]):
            row["reason"] = "the line differs between the maps: a change is given for one line"
        elif None in (b["step_m"], a["step_m"], b["step_sd_m"], a["step_sd_m"]):
            row["reason"] = "a map does not record its step's 1-sigma"
        elif (b["width_sd_m"] is None or a["width_sd_m"] is None) and not (
            b["width_sd_m"] is None and a["width_sd_m"] is None and b["width_m"] == a["width_m"]
        ):
            row["reason"] = (
                "the steps were fitted at different widths with a 1-sigma that leaves the "
                "width's out (a map made before 0.41.0, or a width given to one map only)"
            )
        else:
            row["change_m"] = float(a["step_m"]) - float(b["step_m"])
            row["change_sd_m"] = float(np.hypot(a["step_sd_m"], b["step_sd_m"]))
            row["method"] = (
                "each map at its own width, combined as independent"
                if b["width_sd_m"] is not None
                else "the width given to both maps"
            )
        out.append(row)
    return out


def at_shared_width(
    changes: list[dict[str, Any]],
    before: list[dict[str, Any]],
    after: list[dict[str, Any]],
    models: tuple[Any, Any] | None,
) -> list[dict[str, Any]]:
    """``changes`` (:func:`step_changes`) with each change between two widths chosen by
    their maps' evidence read again at one shared width, when both maps' GPs are at hand
    (``models``: the GP route of ``glacimap change``): ``change_m`` and ``change_sd_m``
    from :func:`terrain.breakline_change.shared_width_change`, the shared width and its
    1-sigma (``shared_width_m``, ``shared_width_sd_m``), the independent pair kept as
    ``independent_change_m`` / ``independent_change_sd_m``. On the eleven real scarps the
    independent 1-sigma was 1.3-2.1 x the shared width's (rms z 0.36 / 0.37 against 0.86 /
    0.93 for a 1 m growth / none; a growth told from zero on 16 of 22 rows against 13:
    docs/terrain.md)."""
    from terrain.breakline_change import shared_width_change

    sd_b = {r["line"]: r["width_sd_m"] for r in before}
    sd_a = {r["line"]: r["width_sd_m"] for r in after}
    out = []
    for c in changes:
        c = dict(c)
        chosen = sd_b.get(c["line"]) is not None and sd_a.get(c["line"]) is not None
        if models is not None and "change_m" in c and chosen:
            shared = shared_width_change(models[0], models[1], c["line"] - 1)
            c.update(
                independent_change_m=c["change_m"],
                independent_change_sd_m=c["change_sd_m"],
                change_m=shared["change_m"],
                change_sd_m=shared["change_sd_m"],
                shared_width_m=shared["width_m"],
                shared_width_sd_m=shared["width_sd_m"],
                method="both maps at one shared width",
            )
        out.append(c)
    return out


def _same_line(u: list, v: list) -> bool:
    u, v = np.asarray(u, dtype=float), np.asarray(v, dtype=float)
    return u.shape == v.shape and bool(np.all(np.abs(u - v) <= SAME_LINE_M))


def _item(values: list | None, j: int) -> Any:
    return None if values is None or j >= len(values) else values[j]
