"""The lawnmower (boustrophedon) survey: N parallel swaths across a region (Section III-A).

The reference swaths are shared with the piecewise-continuous planner (Eq 10), which wanders
around the same lines. Frame and heading conventions: :mod:`survey.plan`.

Geometry: the region is projected on the across-track axis and split into ``n_swaths`` strips
of equal width; each swath line runs through the centre of its strip, edge to edge, clipped
to the region (:func:`shapely.intersection`, vectorised over all swaths). A hole (or a concave
boundary) splits a swath into pieces, driven in order. Consecutive pieces and swaths are joined
by straight *transit legs*; a transit leg may cross a hole — driving around it is not
modelled, and samples on transit legs are marked ``sample_swath == -1``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import shapely

from terrain.errors import bad_input

from .plan import SurveyPlan, build_plan, heading_vectors
from .region import as_region

__all__ = ["ReferenceSwaths", "default_heading", "lawnmower", "reference_swaths"]

_MIN_PIECE = 1e-9  # m: shorter clipped pieces (a line touching a vertex) are dropped


def default_heading(region: Any) -> float:
    """Heading (degrees clockwise from north, in [0, 180)) of the region's long axis.

    The long side of the minimum rotated rectangle (:func:`shapely.minimum_rotated_rectangle`):
    swaths along it are the longest and need the fewest turns. For a square the tie goes to
    the smaller heading (a north-aligned square gives 0). Rounded to 1e-6 degrees so that an
    axis-aligned box gives exactly 0 or 90.
    """
    poly = as_region(region)
    ring = np.asarray(shapely.minimum_rotated_rectangle(poly).exterior.coords)[:3]
    edges = np.diff(ring, axis=0)  # two adjacent sides of the rectangle
    lengths = np.hypot(edges[:, 0], edges[:, 1])
    angles = np.round(np.rad2deg(np.arctan2(edges[:, 0], edges[:, 1])) % 180.0, 6) % 180.0
    if np.isclose(lengths[0], lengths[1], rtol=1e-9):
        return float(angles.min())
    return float(angles[int(np.argmax(lengths))])


@dataclass(frozen=True)
class ReferenceSwaths:
    """Reference swath lines of a region, clipped into drivable pieces (swath frame, m).

    Attributes
    ----------
    heading_deg : float
        Heading of the first swath, degrees clockwise from north.
    origin : tuple of float
        Swath-frame origin (region centroid), easting/northing in m.
    offsets : ndarray of shape (n_swaths,)
        Across-track coordinate of each swath line (centres of equal strips), m.
    strip_width : float
        Across-track width of the region / n_swaths, m (the swath spacing).
    piece_swath : ndarray of shape (p,), int
        Swath index of each piece, in driving order.
    piece_along : ndarray of shape (p, 2)
        Along-track coordinate of each piece's start and end, in driving direction, m.
    """

    heading_deg: float
    origin: tuple[float, float]
    offsets: np.ndarray
    strip_width: float
    piece_swath: np.ndarray
    piece_along: np.ndarray

    @property
    def spacing(self) -> float:
        """Distance between neighbouring swath lines = strip width = width / n_swaths, m."""
        return self.strip_width

    def to_world(self, along: np.ndarray, across: np.ndarray) -> np.ndarray:
        """Swath-frame ``(along, across)`` (broadcast together) -> easting/northing (..., 2)."""
        u, v = heading_vectors(self.heading_deg)
        a = np.asarray(along, float)[..., None]
        c = np.asarray(across, float)[..., None]
        return np.asarray(self.origin) + a * u + c * v


def _number(value: Any) -> float:
    """``float(value)``, or NaN for anything that is not a real number (then rejected)."""
    if isinstance(value, bool):
        return float("nan")
    try:
        return float(value)
    except (TypeError, ValueError):
        return float("nan")


def _check_common(n_swaths: Any, spacing: Any, heading: Any, margin: Any) -> None:
    n = _number(n_swaths)
    if not (np.isfinite(n) and n.is_integer() and n >= 1):
        raise bad_input("n_swaths", n_swaths, "an integer >= 1", "e.g. n_swaths=4")
    if not _number(spacing) > 0 or not np.isfinite(_number(spacing)):
        raise bad_input("spacing", spacing, "a positive sample spacing in metres", "e.g. 5.0")
    if heading is not None and not np.isfinite(_number(heading)):
        raise bad_input(
            "heading",
            heading,
            "a finite angle, degrees clockwise from north",
            "e.g. heading=90.0 (east)",
        )
    if margin is not None and not (np.isfinite(_number(margin)) and _number(margin) >= 0):
        raise bad_input("margin", margin, "a distance >= 0 m", "e.g. margin=5.0")


def reference_swaths(
    region: Any, n_swaths: int, heading: float | None = None, margin: float | None = None
) -> ReferenceSwaths:
    """Clip ``n_swaths`` strip-centre lines to ``region`` (see the module notes).

    ``margin`` (m, default 0) shrinks the region (:meth:`shapely.buffer` by ``-margin``,
    holes grow) before clipping, so swath ends keep that distance from every boundary; the
    strips themselves still split the full region. Swaths that miss the shrunk region (or a
    MultiPolygon gap) have no pieces. Swath ``i`` runs along ``+heading`` when it is the
    0th, 2nd, ... swath that has pieces, else along ``heading + 180``.
    """
    poly = as_region(region)
    _check_common(n_swaths, 1.0, heading, margin)
    n = int(n_swaths)
    h = float(default_heading(poly) if heading is None else heading) % 360.0
    cen = poly.centroid
    origin = (float(cen.x), float(cen.y))
    u, v = heading_vectors(h)
    ext = shapely.get_coordinates(poly) - np.asarray(origin)
    along, across = ext @ u, ext @ v
    lo, hi = float(across.min()), float(across.max())
    w = (hi - lo) / n
    offsets = lo + w * (np.arange(n) + 0.5)  # centres of n equal strips
    clip = poly if not margin else poly.buffer(-float(margin), join_style="mitre")
    if clip.is_empty:
        raise bad_input("margin", margin, "a margin that leaves part of the region", "shrink it")
    a0, a1 = float(along.min()) - 1.0, float(along.max()) + 1.0
    o = np.asarray(origin) + offsets[:, None] * v
    ends = np.stack([o + a0 * u, o + a1 * u], axis=1)  # (n, 2 ends, 2)
    shapely.prepare(clip)
    clipped = shapely.intersection(shapely.linestrings(ends), clip)
    parts, idx = shapely.get_parts(clipped, return_index=True)
    keep = (shapely.get_type_id(parts) == 1) & (shapely.length(parts) > _MIN_PIECE)
    parts, idx = parts[keep], idx[keep]
    coords, cidx = shapely.get_coordinates(parts, return_index=True)
    a = (coords - np.asarray(origin)) @ u
    amin = np.full(parts.size, np.inf)
    amax = np.full(parts.size, -np.inf)
    np.minimum.at(amin, cidx, a)
    np.maximum.at(amax, cidx, a)
    # Boustrophedon: alternate the direction over the swaths that have pieces.
    has = np.zeros(n, bool)
    has[idx] = True
    direction = np.where(np.cumsum(has) % 2 == 1, 1.0, -1.0)[idx]
    order = np.lexsort((amin * direction, idx))
    idx, amin, amax, direction = idx[order], amin[order], amax[order], direction[order]
    piece_along = np.where(direction[:, None] > 0, np.c_[amin, amax], np.c_[amax, amin])
    return ReferenceSwaths(h, origin, offsets, w, idx.astype(np.int64), piece_along)


def lawnmower(
    region: Any,
    n_swaths: int,
    heading: float | None = None,
    spacing: float = 5.0,
    margin: float | None = None,
    crs: Any = None,
) -> SurveyPlan:
    """A lawnmower plan: ``n_swaths`` parallel straight swaths driven boustrophedon.

    Parameters
    ----------
    region : shapely Polygon/MultiPolygon or bounds (west, south, east, north)
        Survey area, m, projected CRS; holes allowed (see :func:`survey.region.as_region`).
    n_swaths : int
        Number of reference swaths, >= 1; the swath spacing is the region's across-track
        width / ``n_swaths``.
    heading : float, optional
        Direction of travel of the first swath, degrees clockwise from north (any finite
        value; taken modulo 360). Default: :func:`default_heading`, the long axis of the
        minimum rotated rectangle (fewest turns, longest swaths).
    spacing : float
        Distance between sensor samples along the driven path, m (default 5).
    margin : float, optional
        Distance kept between swath ends and the region boundary, m (default 0: edge to edge).
    crs : optional
        Projected CRS of the coordinates, recorded in the plan.

    Returns
    -------
    SurveyPlan
        ``pattern="lawnmower"``; the waypoints are the ends of every swath piece; legs between
        pieces are transit legs (may cross holes; samples on them have swath -1).
    """
    _check_common(n_swaths, spacing, heading, margin)
    ref = reference_swaths(region, n_swaths, heading, margin)
    p = ref.piece_swath.size
    if p == 0:
        raise bad_input("region", "no swath inside", "a region the swaths cross", "check margin")
    across = ref.offsets[ref.piece_swath]
    waypoints = ref.to_world(ref.piece_along, across[:, None]).reshape(-1, 2)
    swath = np.repeat(ref.piece_swath, 2)
    transit = np.arange(2 * p - 1) % 2 == 1  # piece, transit, piece, ...
    params = {
        "n_swaths": int(n_swaths),
        "heading_deg": ref.heading_deg,
        "spacing": float(spacing),
        "margin": 0.0 if margin is None else float(margin),
        "swath_spacing": ref.spacing,
        "heading_source": "given" if heading is not None else "minimum_rotated_rectangle",
        "empty_swaths": sorted(set(range(int(n_swaths))) - set(ref.piece_swath.tolist())),
    }
    return build_plan(
        waypoints,
        swath,
        transit,
        float(spacing),
        pattern="lawnmower",
        params=params,
        swath_offsets=ref.offsets,
        heading_deg=ref.heading_deg,
        origin=ref.origin,
        crs=crs,
    )
