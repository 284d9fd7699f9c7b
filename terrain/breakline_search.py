"""Breaklines found in the samples: where the ground steps, for a user who has not drawn them.

A surveyor draws an ice cliff or a scarp as a breakline (:class:`terrain.BreaklineMean`)
when they know where it is. :func:`find_breaklines` proposes them from the samples alone, in
the way edge detectors find steps in images (Canny 1986: a local test for a step, the
strongest response kept where responses crowd, then the edge points linked into lines):

1. **A local test for a step.** Around each centre (the samples, thinned to at most
   ``MAX_CENTRES``), the samples within ``radius`` m are fitted by a cubic surface (10
   columns), then by the cubic plus a step ``h * [n . (x - p) > 0]`` across a straight line
   through ``p`` with normal ``n``, for ``N_DIRECTIONS`` directions and ``N_OFFSETS``
   offsets of the line across the disc. The step's reduction of the residual sum of squares
   is ``(s^T r0)^2 / (s^T s - |Q^T s|^2)`` (partial regression: ``r0`` the cubic's
   residuals, ``Q`` its orthonormal basis), so all lines of a centre cost one QR.
   The same lines are tried as a slightly soft step (logistic of ``SOFT`` radius) and as a
   ramp (``RAMP`` radius: ground that bends smoothly); the best line's offset is then
   refined to the gaps between the samples across it. ``F = reduction / s2``, with ``s2``
   the median over centres of the cubic's residual variance (noise and the ground's
   roughness at this radius).
2. **Edge points.** A line with ``F >= F_MIN``, a step that explains ``F_SHARP`` more than
   the best ramp, ``|h| >= H_MIN * sqrt(s2)``, at least ``MIN_SIDE`` samples on either side
   and not at the disc's outermost offsets gives an edge point (the point of the line
   nearest the centre, its direction, its step). Points are kept strongest first, none
   within a radius of a stronger one (non-maximum suppression).
3. **Lines.** Edge points are linked when they lie within the link distance (``4 radius``,
   2.5 x the survey's widest gap or ``REACH_EXTENT`` of its extent: steps are seen on the
   tracks and not between them), both directions agree with the segment between them within
   ``LINK_ANGLE_DEG``, the step rises to the same side and the two steps' heights are within
   ``LINK_STEP_RATIO``. Each linked set of at least ``MIN_POINTS`` points is ordered along
   its principal axis (a point off the others' line left out); an end within 1.5 radii (or
   2.5 x the widest gap) of the samples' bounding box is carried past it (the step runs on
   across the survey), any other end runs on ``OPEN_RUN_ON`` of the link distance past its
   last point (an open end: :class:`terrain.BreaklineMean` tapers the step there, the
   taper chosen at fit).
4. **Each line confirmed** by :meth:`terrain.BreaklineMean.fit`'s local least squares (planes
   on stretches beside it, its width and taper chosen): kept when its step is at least
   ``STEP_Z`` of its sds and ``H_MIN`` residual sds; the others are listed with the reason.

Nothing here fits a GP: a line found is a proposal, which ``TerrainGP(mean=BreaklineMean(
found.lines))`` fits like a drawn one (each step's height by GLS with its 1-sigma);
``glacimap reconstruct --breaklines auto`` does just that and says what was found and why
any line was dropped (docs/terrain.md "Breaklines found in the samples").
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree
from scipy.special import expit

from .breakline import BreaklineMean
from .errors import InputError, bad_input, positive_number
from .gaps import largest_gap
from .samples import ElevationSamples

__all__ = ["BreaklineSearch", "find_breaklines"]

#: Scale of the ramps a step must beat, in radii: a logistic rising 12-88 % over a radius.
RAMP = 1.0 / 4.0
#: Scale of a step a little softer than sharp, in radii (1 m in a 16 m disc).
SOFT = 1.0 / 16.0
#: Smallest disc radius, m: four times the widest step width ``BreaklineMean`` tries.
MIN_RADIUS = 16.0
#: Line directions tried at each centre (0 to 180 degrees; the step's sign gives the rest).
N_DIRECTIONS = 16
#: Offsets of the line across the disc, from -radius / 2 to radius / 2.
N_OFFSETS = 9
#: Samples each side of a tested line, at least.
MIN_SIDE = 8
#: Samples in a centre's disc used to size the radius (the median disc holds about this many).
DISC_SAMPLES = 40
#: Centres tested, at most (the samples thinned evenly).
MAX_CENTRES = 6000
#: A step's reduction of the residual sum of squares, in units of the cubic's residual
#: variance (a chi-square with one degree of freedom under no step: 36 is 6 sigma, beyond
#: the scan's ~10^5 lines tried).
F_MIN = 36.0
#: What a step explains beyond the best ramp, in the same units (3 sigma: the ramps are
#: the same lines, so this is a test of shape, not of place).
F_SHARP = 9.0
#: A step at least this many times the cubic's residual sd.
H_MIN = 4.0
#: Directions agree within this many degrees to link two edge points.
LINK_ANGLE_DEG = 40.0
#: Edge points this share of the survey's extent apart may be linked (a step seen on two
#: tracks and not in the gap between them).
REACH_EXTENT = 0.3
#: Linked edge points' steps differ by at most this factor (a step's height changes slowly
#: along its line; a bend of the ground beside it reads as a smaller one).
LINK_STEP_RATIO = 2.5
#: An open end runs on past its last edge point this share of the link distance: a step
#: dies out between the last track that sees it and the next one, and the taper chosen at
#: fit fades it (half a radius stopped bei's fading scarp 50 m short at 50,000 samples).
OPEN_RUN_ON = 0.5
#: Edge points in a line, at least.
MIN_POINTS = 3
#: A line's step (local least squares) at least this many of its sds.
STEP_Z = 5.0


@dataclass(frozen=True)
class BreaklineSearch:
    """What :func:`find_breaklines` found.

    Attributes
    ----------
    lines : list of ndarray of shape (k, 2)
        The lines, m, in the samples' CRS, strongest first.
    steps_m, steps_sd_m : list of float
        Each line's step and its 1-sigma, m, up to its left, by the local least squares of
        :meth:`terrain.BreaklineMean.fit` (planes on the stretches beside it): what confirmed
        the line. Where the found line strays from the step that fit takes a wide width and
        can read high (4.7 +- 0.45 m for a 3 m step in ``tests/test_breakline_search.py``);
        the map's GLS height (``TerrainGP(mean=BreaklineMean(lines))``: 3.37 +- 0.14) is
        the one to read.
    points : list of int
        Edge points behind each line.
    dropped : list of str
        Linked lines not kept, each with its reason (counted, not silently dropped).
    radius_m : float
        The disc radius of the local test, m.
    residual_sd_m : float
        ``sqrt(s2)``: the cubic's median residual sd at that radius, m.
    n_centres, n_edge_points, n_unlinked : int
        Centres tested, edge points kept after suppression, and edge points in no line
        (counted, not silently dropped: a step too short to be a line, or a lone bump).
    edge_points : ndarray of shape (n_edge_points, 2)
        Where the edge points lie, m.
    """

    lines: list[np.ndarray]
    steps_m: list[float]
    steps_sd_m: list[float]
    points: list[int]
    dropped: list[str]
    radius_m: float
    residual_sd_m: float
    n_centres: int
    n_edge_points: int
    n_unlinked: int
    edge_points: np.ndarray = field(repr=False)

    def summary(self) -> str:
        """One sentence for the console."""
        found = "; ".join(
            f"line {j + 1}: {len(line)} vertices, {_length(line):.0f} m, "
            f"step {h:.2f} +- {sd:.2f} m from {k} edge points"
            for j, (line, h, sd, k) in enumerate(
                zip(self.lines, self.steps_m, self.steps_sd_m, self.points, strict=True)
            )
        )
        return (
            f"breakline search ({self.radius_m:.1f} m discs at {self.n_centres} centres, "
            f"residual sd {self.residual_sd_m:.2f} m): {len(self.lines)} line(s)"
            + (f" ({found})" if found else "")
            + f"; {self.n_unlinked} of {self.n_edge_points} edge points in no line"
            + (f"; {len(self.dropped)} line(s) dropped" if self.dropped else "")
        )


def _length(line: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(line, axis=0), axis=1).sum())


def _radius(xy: np.ndarray) -> float:
    """The radius whose disc round the median sample holds :data:`DISC_SAMPLES` samples."""
    k = min(DISC_SAMPLES, len(xy) - 1)
    return max(float(np.median(cKDTree(xy).query(xy, k=k + 1)[0][:, -1])), MIN_RADIUS)


def _surface(u: np.ndarray) -> np.ndarray:
    """The smooth ground of a disc: a cubic surface in the disc's unit coordinates (10
    columns; a quadratic left 1 m of misfit on olinda's 36 m discs)."""
    x, y = u[:, 0], u[:, 1]
    return np.column_stack([x**0, x, y, x * x, x * y, y * y, x**3, x * x * y, x * y * y, y**3])


def _reductions(Q: np.ndarray, S: np.ndarray, r0: np.ndarray, usable: np.ndarray):
    """Each column of ``S`` (m, c): its reduction of the residual sum of squares beside the
    surface whose orthonormal basis is ``Q`` (m, 10) (partial regression), with its
    numerator ``s^T r0`` and denominator ``s^T s - |Q^T s|^2`` (= ``s^T s - b^T A^-1 b``)."""
    QS = Q.T @ S
    denom = np.einsum("ij,ij->j", S, S) - np.einsum("ij,ij->j", QS, QS)
    num = S.T @ r0
    red = np.where(usable & (denom > 1e-9), num**2 / np.maximum(denom, 1e-12), 0.0)
    return red, num, denom


def _logistic(across: np.ndarray, offsets: np.ndarray, scale: float) -> np.ndarray:
    """``expit((across[:, :, None] - offsets) / scale)`` flattened to (m, d * o), by one
    exponential per sample and direction: ``1 / (1 + exp(-a / s) exp(o / s))`` (|a|, |o| are
    at most a radius and ``s`` at least a sixteenth of one, so neither factor overflows)."""
    e = np.exp(-across / scale)[:, :, None] * np.exp(offsets / scale)
    return (1.0 / (1.0 + e)).reshape(len(across), -1)


def _scan(xy, z, centres, radius):
    """Each centre's best step line: its reduction of the residual sum of squares, the best
    ramp's, the cubic's residual sum of squares and degrees of freedom (nan / 0: too few
    samples), ``(step, x, y, direction index)`` of the line's point nearest the centre, and
    the directions' normals (d, 2)."""
    tree = cKDTree(xy)
    angles = np.pi * np.arange(N_DIRECTIONS) / N_DIRECTIONS
    normals = np.column_stack([np.cos(angles), np.sin(angles)])  # (d, 2)
    offsets = radius * np.linspace(-0.5, 0.5, N_OFFSETS)
    n_c = len(centres)
    gain = np.zeros(n_c)
    rss0 = np.full(n_c, np.nan)
    dof = np.zeros(n_c)
    best = np.zeros((n_c, 4))  # step, point x, point y, direction index
    smooth = np.zeros(n_c)  # the best ramp's reduction
    for i, idx in enumerate(tree.query_ball_point(centres, radius)):
        if len(idx) < 2 * MIN_SIDE:
            continue
        u = (xy[idx] - centres[i]) / radius  # local, unit disc
        Q = np.linalg.qr(_surface(u))[0]  # the cubic's basis, once for every line below
        r0 = z[idx] - Q @ (Q.T @ z[idx])
        rss0[i], dof[i] = float(r0 @ r0), len(idx) - Q.shape[1]
        across_all = (u @ normals.T) * radius  # (m, d), m along each normal
        proj = across_all[:, :, None] - offsets  # (m, d, o), m from each line
        S = (proj > 0).reshape(len(idx), -1).astype(float)  # step columns (m, d * o)
        n_up = S.sum(axis=0)
        enough = (n_up >= MIN_SIDE) & (len(idx) - n_up >= MIN_SIDE)
        if not enough.any():
            continue
        red, num, denom = _reductions(Q, S, r0, enough)
        # a step a little wider than sharp, and the same lines as ramps: ground that bends
        # smoothly is fitted as well by a ramp; a step is not
        soft = _reductions(Q, _logistic(across_all, offsets, SOFT * radius), r0, enough)
        ramps = _logistic(across_all, offsets, RAMP * radius)
        smooth[i] = _reductions(Q, ramps, r0, enough)[0].max()
        scale = SOFT * radius if soft[0].max() > red.max() else 0.0
        if scale:
            red, num, denom = soft
        j = int(np.argmax(red))
        d, o = divmod(j, N_OFFSETS)
        if o in (0, N_OFFSETS - 1):
            continue  # the line lies beyond the disc's middle: a nearer centre finds it
        # between the lattice's offsets: the line moved to each gap between the samples'
        # positions across it within half a lattice step (an indicator changes only there)
        across = u @ normals[d] * radius
        half = 0.5 * (offsets[1] - offsets[0])
        near = np.sort(across[np.abs(across - offsets[o]) <= half])
        tries = np.r_[offsets[o], 0.5 * (near[1:] + near[:-1])]
        cols = across[:, None] - tries
        cols = expit(cols / scale) if scale else (cols > 0).astype(float)
        n_up = (across[:, None] > tries).sum(axis=0)
        ok = (n_up >= MIN_SIDE) & (len(idx) - n_up >= MIN_SIDE)
        fine, fnum, fden = _reductions(Q, cols, r0, ok)
        k = int(np.argmax(fine))
        gain[i] = fine[k]
        best[i] = (fnum[k] / fden[k], *(centres[i] + tries[k] * normals[d]), d)
    return gain, smooth, rss0, dof, best, normals


def _suppress(points: np.ndarray, strength: np.ndarray, spacing: float) -> np.ndarray:
    """Indices kept strongest first, none within ``spacing`` of a stronger kept one."""
    order = np.argsort(-strength, kind="stable")
    tree = cKDTree(points)
    taken = np.zeros(len(points), dtype=bool)
    kept = []
    for i in order:
        if taken[i]:
            continue
        kept.append(i)
        taken[tree.query_ball_point(points[i], spacing)] = True
    return np.asarray(kept, dtype=int)


def _links(
    pts: np.ndarray, normal: np.ndarray, step: np.ndarray, reach: float
) -> tuple[int, np.ndarray]:
    """Connected sets of edge points linked along their lines (module notes, step 3)."""
    cos_max = np.cos(np.radians(LINK_ANGLE_DEG))
    pairs = cKDTree(pts).query_pairs(reach, output_type="ndarray")
    if len(pairs):
        a, b = pairs[:, 0], pairs[:, 1]
        v = pts[b] - pts[a]
        v /= np.linalg.norm(v, axis=1, keepdims=True)
        # |v . u| with u = (-n_y, n_x) the line's direction at each end
        along_a = np.abs(v[:, 1] * normal[a, 0] - v[:, 0] * normal[a, 1])
        along_b = np.abs(v[:, 1] * normal[b, 0] - v[:, 0] * normal[b, 1])
        same = (normal[a] * normal[b]).sum(axis=1) >= cos_max
        alike = np.maximum(step[a], step[b]) <= LINK_STEP_RATIO * np.minimum(step[a], step[b])
        keep = (along_a >= cos_max) & (along_b >= cos_max) & same & alike
        pairs = pairs[keep]
    graph = coo_matrix(
        (np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])) if len(pairs) else ([], ([], [])),
        shape=(len(pts), len(pts)),
    )
    return connected_components(graph, directed=False)


def _unspiked(line: np.ndarray, tolerance: float) -> np.ndarray:
    """The ordered points less spikes: while an inner point lies farther than ``tolerance``
    (m) from the segment joining its neighbours, or an end from the line through its two
    neighbours, the farthest is left out (an edge point of a bend beside the line that the
    links took along)."""
    import shapely

    while len(line) > MIN_POINTS:
        seg = shapely.linestrings(np.stack([line[:-2], line[2:]], axis=1))
        off = np.r_[  # an end may stray twice as far: it runs on a bending line's tangent
            0.5 * _off_line(line[0], line[1], line[2]),
            shapely.distance(seg, shapely.points(line[1:-1])),
            0.5 * _off_line(line[-1], line[-2], line[-3]),
        ]
        k = int(np.argmax(off))
        if off[k] <= tolerance:
            break
        line = np.delete(line, k, axis=0)
    return line


def _off_line(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    """Distance (m) from ``p`` to the straight line through ``a`` and ``b``: how far an end
    point strays from where its neighbours' line runs on."""
    u = (a - b) / max(float(np.linalg.norm(a - b)), 1e-9)
    d = p - a
    return abs(float(d[0] * u[1] - d[1] * u[0]))


def _polyline(pts, lo, hi, reach, radius, link) -> tuple[np.ndarray, int]:
    """Edge points ordered along their principal axis, joined by a cubic spline of arc
    length (vertices a quarter radius apart: a sinuous step between tracks is a curve, not
    the chords between them); ends carried on along its tangent past the samples' box when
    within ``reach`` of it, else ``OPEN_RUN_ON`` x ``link`` past the last point. Returns the
    vertices and the number of edge points behind them."""
    from scipy.interpolate import make_interp_spline

    centre = pts.mean(axis=0)
    axis = np.linalg.svd(pts - centre, full_matrices=False)[2][0]
    line = _unspiked(pts[np.argsort((pts - centre) @ axis, kind="stable")], 0.5 * radius)
    t = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(line, axis=0), axis=1))]
    spline = make_interp_spline(t, line, k=min(3, len(line) - 1))
    curve = spline(np.linspace(0.0, t[-1], max(len(line), int(t[-1] / (0.25 * radius)) + 1)))
    ends = []
    for end, at in ((curve[0], 0.0), (curve[-1], t[-1])):
        out = spline.derivative()(at) * (-1.0 if at == 0.0 else 1.0)
        out = out / max(float(np.linalg.norm(out)), 1e-9)
        # distance along ``out`` to the box's edge
        with np.errstate(divide="ignore", invalid="ignore"):
            to = np.where(out > 0, (hi - end) / out, np.where(out < 0, (lo - end) / out, np.inf))
        to_edge = float(np.min(to))
        step = to_edge + radius if to_edge <= reach else OPEN_RUN_ON * link
        ends.append(end + step * out)
    return np.vstack([ends[0], curve, ends[1]]), len(line)


def _confirm(line: np.ndarray, xy: np.ndarray, z: np.ndarray, sd: float):
    """The line's step by :class:`terrain.BreaklineMean`'s local least squares (planes on
    stretches beside it, its width and taper chosen): ``(step, its sd, "")``, or a reason
    to drop it (the step not told from zero, smaller than ``H_MIN`` residual sds, or a line
    the mean refuses)."""
    try:
        mean = BreaklineMean([line]).fit(xy, z)
    except InputError as err:
        return float("nan"), float("nan"), f"{_length(line):.0f} m line refused: {err}"
    k = mean.coef_names.index("step1_m")
    step, step_sd = float(mean.coef_[k]), float(np.sqrt(mean.coef_cov_[k, k]))
    if abs(step) < STEP_Z * step_sd or abs(step) < H_MIN * sd:
        return (
            step,
            step_sd,
            (
                f"{_length(line):.0f} m line: step {step:.2f} +- {step_sd:.2f} m, under "
                f"{STEP_Z:g} sd or {H_MIN:g} x the residual sd ({sd:.2f} m)"
            ),
        )
    return step, step_sd, ""


def find_breaklines(samples: ElevationSamples, radius: float | None = None) -> BreaklineSearch:
    """Propose breaklines where the samples show a step (see the module notes).

    Parameters
    ----------
    samples : ElevationSamples
        The survey, m, in a projected CRS.
    radius : float, optional
        Disc radius of the local test, m. Default: the radius whose disc round the median
        sample holds 40 samples (about 24 m for 3,000 samples on the benchmark's eight
        tracks over 600 m; 6 m for 50,000).

    Returns
    -------
    BreaklineSearch
        The lines (possibly none), each with its local step and edge points; what was not
        linked, counted.

    Raises
    ------
    terrain.errors.InputError
        ``samples`` not ElevationSamples or fewer than ``4 * MIN_SIDE`` of them; ``radius``
        not a positive number.
    """
    if not isinstance(samples, ElevationSamples):
        fix = "wrap arrays with ElevationSamples(xy, z, z_var)"
        raise bad_input("samples", type(samples).__name__, "terrain.ElevationSamples", fix)
    if samples.n < 4 * MIN_SIDE:
        raise bad_input(
            "samples", f"{samples.n} samples", f"at least {4 * MIN_SIDE}", "survey more ground"
        )
    xy, z = samples.xy, samples.z
    if radius is None:
        radius = _radius(xy)
    radius = positive_number("radius", radius, "a disc radius in metres, e.g. 20")
    stride = max(1, -(-samples.n // MAX_CENTRES))
    centres = xy[::stride]
    gain, smooth, rss0, dof, best, normals = _scan(xy, z, centres, radius)
    tested = np.isfinite(rss0) & (dof > 0)
    s2 = float(np.median(rss0[tested] / dof[tested])) if tested.any() else float("nan")
    empty = np.zeros((0, 2))
    if not np.isfinite(s2) or s2 <= 0:
        return BreaklineSearch(
            [], [], [], [], [], radius, float("nan"), int(tested.sum()), 0, 0, empty
        )
    F = gain / s2
    sharp = (gain - smooth) / s2  # what a step explains that no ramp does
    strong = (
        tested & (F >= F_MIN) & (sharp >= F_SHARP) & (np.abs(best[:, 0]) >= H_MIN * np.sqrt(s2))
    )
    idx = np.flatnonzero(strong)
    if idx.size == 0:
        return BreaklineSearch(
            [], [], [], [], [], radius, float(np.sqrt(s2)), int(tested.sum()), 0, 0, empty
        )
    pts, step = best[idx, 1:3], best[idx, 0]
    normal = normals[best[idx, 3].astype(int)] * np.sign(step)[:, None]  # towards the high side
    kept = _suppress(pts, F[idx], radius)
    pts, step, normal, strength = pts[kept], np.abs(step[kept]), normal[kept], F[idx][kept]
    gap = largest_gap(xy)
    reach = max(4.0 * radius, 2.5 * gap, REACH_EXTENT * float(np.ptp(xy, axis=0).max()))
    edge = max(1.5 * radius, 2.5 * gap)  # an end this near the box's edge runs on past it
    n_sets, label = _links(pts, normal, step, reach)
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    found = []
    for k in range(n_sets):
        members = np.flatnonzero(label == k)
        if members.size < MIN_POINTS:
            continue
        line, used = _polyline(pts[members], lo, hi, edge, radius, reach)
        found.append((float(strength[members].sum()), line, used))
    found.sort(key=lambda t: -t[0])
    linked = sum(f[2] for f in found)
    confirmed, dropped = [], []
    for _, line, k in found:
        step, sd, why = _confirm(line, xy, z, np.sqrt(s2))
        if why:
            dropped.append(why)
        else:
            confirmed.append((line, step, sd, k))
    return BreaklineSearch(
        lines=[f[0] for f in confirmed],
        steps_m=[f[1] for f in confirmed],
        steps_sd_m=[f[2] for f in confirmed],
        points=[f[3] for f in confirmed],
        dropped=dropped,
        radius_m=radius,
        residual_sd_m=float(np.sqrt(s2)),
        n_centres=int(tested.sum()),
        n_edge_points=int(len(pts)),
        n_unlinked=int(len(pts) - linked),
        edge_points=pts,
    )
