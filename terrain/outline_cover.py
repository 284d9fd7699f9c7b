"""How much of a glacier outline the change grid covers.

A volume change sums ``dh`` over the grid cells inside the outline (:mod:`terrain.volume`).
Where the outline reaches beyond the two DEMs' common grid, those parts have no cell, and a
volume of the covered part alone would be read as the glacier's: a glacier outline from an
inventory (RGI, GLIMS) is often larger than a rover's maps. So the outline's area beyond the
grid is measured here; beyond :data:`OUTSIDE_MAX` of its area the volume is refused, unless
the caller clips the outline to the grid (``glacimap change --clip-outline``) and says so.
Voids *inside* the grid are another matter: they are filled with the outline's mean ``dh``
and counted (``n_cells_filled``).
"""

from __future__ import annotations

from typing import Any

from .errors import bad_input
from .grid import Grid

__all__ = ["OUTSIDE_MAX", "check_outline_covered", "clip_outline", "outline_cover"]

#: The share of an outline's area allowed beyond the grid (its edge cells' half widths).
OUTSIDE_MAX = 0.01


def _union(outline: Any) -> Any:
    import shapely

    geoms = getattr(outline, "geoms", None)
    parts = list(geoms if geoms is not None else outline if isinstance(outline, list | tuple)
                 else [outline])  # fmt: skip
    return shapely.union_all(parts)


def outline_cover(outline: Any, grid: Grid) -> dict[str, float]:
    """The outline's area (m^2), its area beyond ``grid``'s bounds (m^2) and that share."""
    import shapely

    shape = _union(outline)
    area = float(shape.area)
    outside = float(shape.difference(shapely.box(*grid.bounds)).area)
    return {
        "area_m2": area,
        "outside_grid_m2": outside,
        "outside_share": outside / area if area > 0 else 0.0,
    }


def check_outline_covered(outline: Any, grid: Grid, field: str = "outline") -> dict[str, float]:
    """:func:`outline_cover`, refused when the share beyond the grid exceeds
    :data:`OUTSIDE_MAX`.

    Raises
    ------
    InputError
        Naming ``field``, the share and area beyond the grid, and the fixes.
    """
    cover = outline_cover(outline, grid)
    if cover["outside_share"] > OUTSIDE_MAX:
        w, s, e, n = (round(v) for v in grid.bounds)
        raise bad_input(
            field,
            f"{100 * cover['outside_share']:.1f} % of its {cover['area_m2']:,.0f} m^2 beyond the "
            "change grid",
            f"an outline the two DEMs cover (their common grid: W {w}, S {s}, E {e}, N {n}; the "
            "volume of the part they cover would be read as the glacier's)",
            "clip it to the DEMs (glacimap change --clip-outline; in Python "
            "outline.intersection(shapely.box(*grid.bounds))), pick the glaciers they cover "
            "(--outline-where), or supply DEMs that cover it",
        )
    return cover


def clip_outline(outline: Any, grid: Grid, field: str = "outline") -> tuple[Any, dict[str, Any]]:
    """The outline clipped to ``grid``'s bounds and the record of what was cut.

    Raises
    ------
    InputError
        Nothing of the outline lies on the grid.
    """
    import shapely

    cover = outline_cover(outline, grid)
    clipped = _union(outline).intersection(shapely.box(*grid.bounds))
    if clipped.is_empty or clipped.area <= 0:
        raise bad_input(
            field, f"bounds {tuple(round(v) for v in _union(outline).bounds)}",
            f"a polygon over the change grid {tuple(round(v) for v in grid.bounds)}",
            "check the outline's CRS and extent",
        )  # fmt: skip
    return clipped, {**cover, "clipped": True}
