"""The geometry of a breakline's step (:class:`terrain.BreaklineMean`): signed distances, the
side a line run on straight leaves a point on, and the step of a line that ends inside the
survey, a double layer whose strength dies out towards that end.

A line run on straight beyond both ends splits the plane in two, and its step column is
``expit(d / w)``, ``d`` the signed distance (m, positive left). A line that stops inside the
survey (a cliff or scarp that fades out) cannot split the plane: going round its end the
ground is continuous. Its column is instead the harmonic function whose only jump is
``tau(s)`` across the line (a double layer of strength ``tau``; Kellogg 1929, ch. VI: of all
functions with that jump, the one of least Dirichlet energy, so no ramp the samples did not
ask for)::

    J(x) = H(x) - (1 / 2 pi) * integral of (1 - tau(s)) dtheta_x(s)  over the run-on line

``H`` the side of the line run on at both ends (1 left, 0 right), ``theta_x(s)`` the
direction from ``x`` to the run-on line's point at arc position ``s``, and ``tau`` 1 along the
line, 0 on the run-on ray beyond an *open* end, and going smoothly (smoothstep) from 1 to 0
over the last ``T`` metres (the taper) before it. ``H`` is the double layer of strength 1 on
the run-on line plus 1/2, so ``J`` is the double layer of strength ``tau`` (plus 1/2): the
ray and the taper are subtracted, each as straight pieces whose strength is linear along
them, in closed form (:func:`double_layer`). With both ends run on ``J = H``. Within a few
widths of the line the jump is given the step's width: ``S = J + tau(s*) (expit(d / w) -
H)``, ``s*`` the arc position of the nearest point of the line, ``tau`` piecewise linear
between the same nodes as the pieces, so that the jumps cancel exactly.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .errors import bad_input

__all__ = [
    "Taper",
    "arc_positions",
    "double_layer",
    "left_side",
    "line_coords",
    "run_on",
    "median_spacing",
    "plane_columns",
    "signed_distances",
    "taper_of",
]

#: How far beyond its ends a breakline is run on straight to split the plane, m.
REACH_M = 1e7
#: Points a chunk of :func:`double_layer` takes: (chunk, pieces) arrays of 8 bytes.
_CHUNK = 8192


def unit(v: np.ndarray) -> np.ndarray:
    return v / np.hypot(*v)


#: Turns (degrees) tried for the ray beyond an open end when the straight one would cross
#: the line (an arc of more than 180 degrees): within 90 of the tangent, where the taper is 0.
_TURNS = (0.0, 20.0, -20.0, 40.0, -40.0, 60.0, -60.0, 80.0, -80.0)


def _turn(v: np.ndarray, degrees: float) -> np.ndarray:
    a = np.radians(degrees)
    return np.array([np.cos(a) * v[0] - np.sin(a) * v[1], np.sin(a) * v[0] + np.cos(a) * v[1]])


def run_on(coords: np.ndarray, open_ends: tuple[bool, bool] = (False, False)):
    """The directions (unit, away from the line) in which line ``coords`` (k, 2) is run on
    beyond its head and tail: straight on; at an open end, if the straight ray would cross
    the line, the first of :data:`_TURNS` that does not (the ray only splits the plane
    there: its double layer is subtracted again, :func:`taper_of`)."""
    import itertools

    import shapely

    out = [unit(coords[0] - coords[1]), unit(coords[-1] - coords[-2])]
    turns = [_TURNS if is_open else (0.0,) for is_open in open_ends]
    for a, b in itertools.product(*turns):
        head, tail = _turn(out[0], a), _turn(out[1], b)
        ends = [coords[0] + REACH_M * head, coords[-1] + REACH_M * tail]
        if shapely.LineString(np.vstack([ends[0], coords, ends[1]])).is_simple:
            return head, tail
    return tuple(out)  # crosses whatever: left_side says so


def left_side(coords: np.ndarray, directions: Any = None):
    """The half of the plane left of the line ``coords`` (k, 2) run on beyond its ends
    (straight, or along ``directions``, :func:`run_on`), a prepared shapely polygon; an
    ``InputError`` when the run-on line crosses itself."""
    import shapely
    from shapely.ops import split

    directions = run_on(coords) if directions is None else directions
    head = coords[0] + REACH_M * directions[0]
    tail = coords[-1] + REACH_M * directions[1]
    line = shapely.LineString(np.vstack([head, coords, tail]))
    c = coords.mean(axis=0)
    r = 0.5 * REACH_M  # the run-on ends lie beyond the box: the line cuts it
    plane = shapely.box(c[0] - r, c[1] - r, c[0] + r, c[1] + r)
    pieces = list(split(plane, line).geoms)
    if len(pieces) != 2:
        raise bad_input(
            "lines",
            f"{len(pieces)} pieces",
            "a line that does not cross itself, run on straight beyond its ends (it splits "
            "the plane in two)",
            "split it into lines that do not cross themselves",
        )
    a, b = coords[0], coords[1]
    probe = (a + b) / 2 + 1e-3 * np.array([-(b - a)[1], (b - a)[0]]) / np.hypot(*(b - a))
    left = [p for p in pieces if p.contains(shapely.Point(probe))]
    piece = left[0] if left else pieces[1]
    shapely.prepare(piece)
    return piece


def signed_distances(xy: np.ndarray, coords: np.ndarray, left: Any, within: float) -> np.ndarray:
    """Signed distance (m, positive on ``left``, :func:`left_side`) from ``xy`` (n, 2) to
    the line ``coords``, shape (n,): exact (shapely) within ``within`` m, found by a k-d
    tree of its vertices densified every 0.25 m; beyond, +-inf."""
    import shapely
    from scipy.spatial import cKDTree

    line = shapely.LineString(coords)
    dense = shapely.get_coordinates(shapely.segmentize(line, 0.25))
    d = cKDTree(dense).query(xy, distance_upper_bound=within + 0.125)[0]  # inf beyond
    near = np.isfinite(d)
    d[near] = shapely.distance(line, shapely.points(xy[near]))
    return np.where(shapely.contains_xy(left, xy[:, 0], xy[:, 1]), d, -d)


def arc_positions(xy: np.ndarray, coords: np.ndarray) -> np.ndarray:
    """Arc position (m from the first vertex) of each point's nearest point on the line."""
    import shapely

    return shapely.line_locate_point(shapely.LineString(coords), shapely.points(xy))


@dataclass(frozen=True)
class Taper:
    """A line's strength ``tau`` and the pieces of the double layer subtracted from its
    half-plane step (:func:`taper_of`).

    Attributes
    ----------
    s, tau : ndarray of shape (k,)
        Arc positions (m) and ``tau`` there; ``tau`` is linear between them.
    a, b : ndarray of shape (m, 2)
        Each subtracted piece's start and end (m), oriented along the line.
    wa, wb : ndarray of shape (m,)
        The subtracted strength ``1 - tau`` at ``a`` and ``b`` (1 on a run-on ray).
    ends : tuple of (ndarray (2,), ndarray (2,), ndarray (2,) or None)
        Each open end, the unit direction of the ray it is run on along, and its outward
        unit tangent where its band is across the line (None: round the ray; :meth:`band`).
    length : float
        The taper, m.
    zone : ndarray of shape (j, 2)
        The nodes of the line where ``tau < 1`` or next to one (the taper's pieces' ends).
    piece : float
        Half the longest such piece, m: a point whose nearest point on the line lies on the
        taper is within its distance to the line plus this of a node.
    """

    s: np.ndarray
    tau: np.ndarray
    a: np.ndarray
    b: np.ndarray
    wa: np.ndarray
    wb: np.ndarray
    ends: tuple
    length: float
    zone: np.ndarray
    piece: float

    def at(self, s: np.ndarray) -> np.ndarray:
        """``tau`` at arc positions ``s`` (m): linear between the nodes."""
        return np.interp(s, self.s, self.tau)

    def band(self, xy: np.ndarray) -> np.ndarray:
        """``tau`` carried across the plane, (n,): the product over the open ends of
        ``smoothstep(r / length)``. ``r`` (m) is the distance back from the end along the
        line's outward tangent (a band across the line: 1 from ``length`` behind the end, 0
        beyond it) where only the taper lies within ``length`` of that band's edge;
        otherwise (a line that curls back past its end) the distance to the ray the end is
        run on along (0 on the ray, 1 from ``length`` off it). On the line near an end ``r``
        is the distance to the end; on it ``band`` is ``tau``."""
        out = np.ones(len(xy))
        for end, ray, tangent in self.ends:
            v = xy - end
            if tangent is not None:  # the ray is within 90 degrees of it: r <= 0 on it
                r = -(v @ tangent)
            else:
                along = np.maximum(v @ ray, 0.0)[:, None]
                r = np.hypot(*(v - along * ray).T)
            out *= _smoothstep(r / self.length)
        return out


def _smoothstep(u: np.ndarray) -> np.ndarray:
    u = np.clip(u, 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


def taper_of(
    coords: np.ndarray, open_ends: tuple[bool, bool], length: float, directions: Any = None
) -> Taper:
    """The strength of line ``coords`` (k, 2) whose ``open_ends`` (head, tail) stop inside
    the survey: :meth:`Taper.band` on the line (near an end, ``smoothstep`` of the distance
    to it over ``length`` m; on a straight end, of the arc distance), taken at the line's
    vertices and every ``length / 64`` m, linear between (within 1e-4 of the smoothstep).
    Subtracted: ``1 - tau`` on each piece between nodes where it is not 0, and the run-on
    ray beyond each open end (strength 1), along ``directions`` (:func:`run_on`; default
    straight on)."""
    import shapely

    line = shapely.LineString(coords)
    total = float(line.length)
    directions = run_on(coords) if directions is None else directions
    vertex_s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(coords, axis=0).T))])
    s = np.unique(
        np.clip(np.concatenate([vertex_s, np.arange(0.0, total, length / 64.0)]), 0, total)
    )
    pts = shapely.get_coordinates(shapely.line_interpolate_point(line, s))
    ends = []
    for k in (0, 1):
        if not open_ends[k]:
            continue
        end = coords[0] if k == 0 else coords[-1]
        tangent = unit(coords[0] - coords[1]) if k == 0 else unit(coords[-1] - coords[-2])
        # across the line unless the line comes back within the taper of the band's edge
        # away from its end: there the band would take a step the line still has
        near = (pts - end) @ tangent > -length
        run = np.flatnonzero(near if k == 0 else near[::-1])
        if run.size != run[-1] + 1:
            tangent = None
        ends.append((end.copy(), directions[k], tangent))
    partial = Taper(s, s, pts[:0], pts[:0], s[:0], s[:0], tuple(ends), length, pts, 0.0)
    tau = partial.band(pts)
    keep = np.flatnonzero((tau[:-1] < 1.0) | (tau[1:] < 1.0))  # pieces with 1 - tau > 0
    A, B = [pts[keep]], [pts[keep + 1]]
    zone = np.unique(np.concatenate([keep, keep + 1]))
    piece = 0.5 * float(np.max(np.diff(s)[keep])) if keep.size else 0.0
    wa, wb = [1.0 - tau[keep]], [1.0 - tau[keep + 1]]
    for (end, ray, _), k in zip(ends, [k for k in (0, 1) if open_ends[k]], strict=True):
        tail = k == 1
        far = end + REACH_M * ray  # the run-on ray beyond an open end
        A.append([end if tail else far])
        B.append([far if tail else end])
        wa.append([1.0])
        wb.append([1.0])
    return Taper(
        s,
        tau,
        np.vstack(A),
        np.vstack(B),
        np.concatenate(wa),
        np.concatenate(wb),
        tuple(ends),
        float(length),
        pts[zone] if zone.size else np.asarray(ends[0][0])[None, :],
        piece,
    )


def double_layer(xy: np.ndarray, a: np.ndarray, b: np.ndarray, wa: np.ndarray, wb: np.ndarray):
    """The double layer (1 / 2 pi) sum_pieces integral w(t) dtheta_x(t) at ``xy`` (n, 2) of
    straight pieces from ``a`` to ``b`` (m, 2) with strength linear from ``wa`` to ``wb``,
    shape (n,). It jumps by ``w`` across a piece, up to its left.

    Closed form: with ``x = a + t0 u + h n`` (``u`` along the piece, ``n`` its left normal)
    and ``X = t - t0``, ``dtheta = h dX / (X^2 + h^2)``, so for ``w = alpha + beta t``::

        integral = (alpha + beta t0) * angle + beta * (h / 2) * log((X2^2 + h^2) / (X1^2 + h^2))

    ``angle`` the one the piece subtends at ``x`` (atan2 of cross and dot).
    """
    xy = np.asarray(xy, dtype=float)
    d = b - a
    ell = np.hypot(d[:, 0], d[:, 1])
    u = d / ell[:, None]
    beta = (wb - wa) / ell
    out = np.empty(len(xy))
    for lo in range(0, len(xy), _CHUNK):
        p = xy[lo : lo + _CHUNK]
        rx = p[:, 0:1] - a[:, 0]
        ry = p[:, 1:2] - a[:, 1]
        t0 = rx * u[:, 0] + ry * u[:, 1]
        h = ry * u[:, 0] - rx * u[:, 1]  # (x - a) . n, n = (-u_y, u_x)
        h[h == 0.0] = -0.0  # a point on a piece is on its right, as left_side has it
        x1, x2 = -t0, ell - t0
        angle = np.arctan2(h * (x2 - x1), x1 * x2 + h * h)
        with np.errstate(divide="ignore", invalid="ignore"):
            log = np.log(np.maximum(x2 * x2 + h * h, 1e-300) / np.maximum(x1 * x1 + h * h, 1e-300))
        ramp = np.where(beta == 0.0, 0.0, 0.5 * h * log)  # 0 where the strength is constant
        out[lo : lo + _CHUNK] = ((wa + beta * t0) * angle + beta * ramp).sum(axis=1)
    return out / (2.0 * np.pi)


def plane_columns(xy: np.ndarray) -> np.ndarray | None:
    """Columns of a plane through samples ``xy`` (m, 2) beside a line, (m, 3): 1, dx, dy
    about their centre, from 6 samples; (m, 2): 1 and the distance along their own line when
    4 or more lie on one (a single straight track across the breakline); else None."""
    c = xy - xy.mean(axis=0)
    plane = np.column_stack([np.ones(len(xy)), c])
    rank = np.linalg.matrix_rank(plane)
    if len(xy) >= 6 and rank == 3:
        return plane
    if len(xy) < 4 or rank != 2:
        return None
    along = c @ np.linalg.svd(c, full_matrices=False)[2][0]  # on their principal axis, m
    return np.column_stack([plane[:, 0], along]) if np.ptp(along) > 0 else None


def line_coords(line: Any, j: int) -> np.ndarray:
    coords = getattr(line, "coords", line)  # a shapely LineString, or (k, 2) vertices
    xy = np.asarray(coords, dtype=float)
    if xy.ndim != 2 or xy.shape[0] < 2 or xy.shape[1] != 2 or not np.all(np.isfinite(xy)):
        raise bad_input(
            f"lines[{j}]",
            getattr(xy, "shape", xy),
            "a line of at least 2 finite (x, y) vertices in the samples' CRS, m",
            "pass a shapely LineString or an array of shape (k, 2)",
        )
    if np.any(np.hypot(*np.diff(xy, axis=0).T) == 0):
        raise bad_input(f"lines[{j}]", "repeated vertex", "distinct consecutive vertices", "")
    return xy


def median_spacing(xy: np.ndarray) -> float:
    """The samples' median nearest-neighbour distance, m."""
    from scipy.spatial import cKDTree

    return float(np.median(cKDTree(xy).query(xy, k=2)[0][:, 1]))
