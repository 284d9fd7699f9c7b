"""One row per glacier of an inventory: ``glacimap change --per-glacier RGIId``.

A DEM pair over a glacierised region covers many glaciers of an inventory (RGI, GLIMS), and
a regional study reports each one's volume change and specific mass balance (Hugonnet et
al. 2021). Each outline the two DEMs cover is passed to :func:`terrain.volume_change` on its
own, with the *same* stable ground for all: the cells outside every glacier of the file (or
``--stable``), so one glacier's thinning is never another's stable ground. An outline the
DEMs cover only in part is clipped to their grid with ``--clip-outline`` (its covered share
in the row), else left out and counted; outlines wholly beyond the grid are counted.
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

import numpy as np

from terrain.errors import bad_input

__all__ = ["COLUMNS", "glacier_rows", "write_glacier_table"]

#: The table's columns (m, m^2, m^3, m w.e.; the rates with dates).
COLUMNS = (
    "id", "area_m2", "covered_share", "volume_m3", "volume_std_m3", "mean_dh_m",
    "mean_dh_std_m", "n_cells_filled", "b_mwe", "b_std_mwe", "b_rate_mwe_a",
    "b_rate_std_mwe_a", "dhdt_m_a",
)  # fmt: skip


def glacier_rows(
    diff: Any,
    outlines: list,
    ids: list[str],
    *,
    density: tuple[float, float],
    models: Any = None,
    stable: np.ndarray | None = None,
    seed: int = 0,
    dates: Any = None,
    clip: bool = False,
) -> tuple[list[dict[str, Any]], str]:
    """Each glacier's volume change and mass balance, and a note of what was left out.

    Parameters
    ----------
    diff : xarray.Dataset
        :func:`terrain.difference`'s output.
    outlines, ids : list
        The inventory's polygons (the diff's CRS) and their IDs, one each.
    density : (float, float)
        kg m^-3 and its 1-sigma.
    models, seed, dates
        As :func:`terrain.volume_change` and :func:`terrain.mass_balance.mass_balance`.
    stable : ndarray of bool, optional
        Stable cells; default: outside every outline.
    clip : bool
        Clip an outline the grid covers in part (else it is left out, counted).

    Raises
    ------
    InputError
        Two features with one ID.
    """
    import shapely

    from terrain import Grid, volume_change
    from terrain.mass_balance import mass_balance
    from terrain.outline_cover import OUTSIDE_MAX, outline_cover
    from terrain.volume import outline_weights

    seen = {i for i in ids if ids.count(i) > 1}
    if seen:
        raise bad_input("--per-glacier", sorted(seen)[:3], "one feature per ID", "dissolve them")
    grid = Grid.from_dataarray(diff)
    if stable is None:
        stable = outline_weights(grid, shapely.union_all(outlines)) == 0
    box = shapely.box(*grid.bounds)
    rows, beyond, partial = [], 0, 0
    for gid, shape in zip(ids, outlines, strict=True):
        cover = outline_cover(shape, grid)
        if not shape.intersects(box) or outline_weights(grid, shape).sum() == 0:
            beyond += 1
            continue
        if cover["outside_share"] > OUTSIDE_MAX:
            if not clip:
                partial += 1
                continue
            shape = shape.intersection(box)
        vc = volume_change(diff, shape, density, models=models, stable=stable, seed=seed)
        mb = mass_balance(vc, dates)
        rows.append(
            {
                "id": gid,
                "area_m2": vc.area_m2,
                "covered_share": 1.0 - cover["outside_share"],
                "volume_m3": vc.volume_m3,
                "volume_std_m3": vc.volume_std_m3,
                "mean_dh_m": vc.mean_dh_m,
                "mean_dh_std_m": vc.mean_dh_std_m,
                "n_cells_filled": vc.n_cells_filled,
                "b_mwe": mb["specific_mwe"],
                "b_std_mwe": mb["specific_std_mwe"],
                "b_rate_mwe_a": mb.get("rate_mwe_a"),
                "b_rate_std_mwe_a": mb.get("rate_std_mwe_a"),
                "dhdt_m_a": mb.get("dhdt_m_a"),
            }
        )
    note = f"{len(rows)} of {len(ids)} glaciers in the table"
    if beyond:
        note += f"; {beyond} beyond the DEMs"
    if partial:
        note += (
            f"; {partial} only partly on the DEMs left out (more than "
            f"{100 * OUTSIDE_MAX:.0f} % beyond: --clip-outline keeps their covered part)"
        )
    return rows, note


def write_glacier_table(rows: list[dict[str, Any]], path: Path) -> None:
    """``glaciers.csv``: :data:`COLUMNS`, one row per glacier (empty cells for no rate)."""
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(COLUMNS))
        w.writeheader()
        for r in rows:
            w.writerow({k: "" if r.get(k) is None else r[k] for k in COLUMNS})
