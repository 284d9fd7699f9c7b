"""The paper's piecewise-continuous survey (Section III-A, Eq 10).

Around every reference swath of the lawnmower (:func:`survey.lawnmower.reference_swaths`), the
rover advances ``step`` m along-track per move and moves across-track by following gradient
descent (``flag = 0``) or ascent (``flag = 1``) of the *prior* terrain; the flag toggles at
random. Concretely, for a move from across-track offset ``c`` (relative to the swath line):

    g = grad z_prior(q)                       (m/m, bilinear in the precomputed gradient grid)
    c' = c + sign(flag) * step * (g . v) / |g|  sign = -1 for descent, +1 for ascent   (Eq 10)

i.e. the move's across-track share is that of the unit steepest-ascent (or -descent)
direction: at most 45 degrees off the swath line, 0 on flat ground, independent of relief.
``c'`` is clipped to ``[-max_deviation, max_deviation]``. If the straight leg to the new point
leaves the region (a hole or the boundary), the rover instead keeps ``c``, then tries ``c/2``,
then returns to the swath line (``c = 0``), whichever leg first stays inside the region.
Each swath piece starts on the region boundary (``c = 0``) and ends at the along-track
position where its reference piece ends, at the offset reached there (inside the region, but
not necessarily on a slanted boundary). Only legs are checked against the region: every leg of
a swath is covered by it, except in the rare case where even the leg back to the swath line
leaves it (taken anyway).
Frames, headings and transit legs follow :mod:`survey.plan`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import shapely

from terrain.errors import bad_input
from terrain.grid import Grid, check_same_crs, north_up

from .lawnmower import _check_common, reference_swaths
from .plan import SurveyPlan, build_plan, heading_vectors
from .region import as_region

__all__ = ["piecewise_continuous"]

_INSIDE_TOL = 1e-6  # m: the region is grown by this much for the inside test
_FLAT = 1e-12  # m/m: gradients smaller than this count as flat (no lateral move)


def _prior_gradient(prior: Any, bounds: tuple[float, ...], crs: Any):
    """Precompute the prior's gradient once; return (grid, gx, gy) with gx, gy (ny, nx), m/m."""
    try:
        prior = north_up(prior)  # gradient rows north first, as the grid's
        grid = Grid.from_dataarray(prior)
    except (KeyError, AttributeError, TypeError, ValueError) as exc:
        raise bad_input(
            "prior",
            type(prior).__name__,
            "an xarray DataArray DEM (dims y, x; CRS attrs) such as terrain.random_terrain",
            "build it with Grid.data_array or terrain.coarse_dem",
        ) from exc
    check_same_crs(crs, grid.crs, "plan", "prior")
    if grid.nx < 2 or grid.ny < 2:
        raise bad_input("prior", grid.shape, "at least 2 x 2 cells", "use a finer prior")
    pw, ps, pe, pn = grid.bounds
    w, s, e, n = bounds
    tol = 1e-6
    if w < pw - tol or s < ps - tol or e > pe + tol or n > pn + tol:
        raise bad_input(
            "prior",
            f"prior bounds {tuple(round(b, 3) for b in grid.bounds)}",
            f"a DEM covering the region bounds {tuple(round(b, 3) for b in bounds)}",
            "extend the prior (e.g. a larger coarse DEM) or shrink the region",
        )
    z = np.asarray(prior.values, dtype=float)
    if not np.all(np.isfinite(z)):
        raise bad_input("prior", "NaN/inf cells", "finite elevations", "fill the gaps first")
    dx, dy = grid.resolution
    gy = -np.gradient(z, dy, axis=0)  # rows run north to south
    gx = np.gradient(z, dx, axis=1)
    return grid, gx, gy


def _bilinear(grid: Grid, values: tuple[np.ndarray, ...], xy: np.ndarray) -> list[np.ndarray]:
    """Bilinear interpolation of cell-centre rasters at ``xy`` (n, 2); clamped at the edges."""
    dx, dy = grid.resolution
    fx = np.clip((xy[:, 0] - grid.x[0]) / dx, 0.0, grid.nx - 1.0)
    fy = np.clip((grid.y[0] - xy[:, 1]) / dy, 0.0, grid.ny - 1.0)
    i = np.minimum(fx.astype(np.int64), grid.nx - 2)
    j = np.minimum(fy.astype(np.int64), grid.ny - 2)
    tx, ty = fx - i, fy - j
    out = []
    for g in values:
        top = g[j, i] * (1 - tx) + g[j, i + 1] * tx
        bot = g[j + 1, i] * (1 - tx) + g[j + 1, i + 1] * tx
        out.append(top * (1 - ty) + bot * ty)
    return out


def piecewise_continuous(
    region: Any,
    n_swaths: int,
    prior: Any,
    seed: int = 0,
    spacing: float = 5.0,
    step: float = 10.0,
    max_deviation: float | None = None,
    switch_probability: float = 0.1,
    heading: float | None = None,
    *,
    initial_flag: int | None = None,
    margin: float | None = None,
    crs: Any = None,
) -> SurveyPlan:
    """A piecewise-continuous plan: swaths that wander by gradient ascent/descent (Eq 10).

    Parameters
    ----------
    region : shapely Polygon/MultiPolygon or bounds (west, south, east, north)
        Survey area, m, projected CRS; holes allowed.
    n_swaths : int
        Number of reference swaths (>= 1), the same lines as :func:`survey.lawnmower`.
    prior : xarray.DataArray
        Prior terrain (dims y, x, metres, CRS attrs), e.g. :func:`terrain.random_terrain` or
        :func:`terrain.coarse_dem`. Its cell footprints (``Grid.bounds``) must cover the
        region's bounds; within the outer half cell the gradient is held at the edge value.
        The gradient is computed once (``np.gradient``) and interpolated bilinearly.
    seed : int
        Seed of the ``np.random.default_rng`` that draws the flags (default 0). Same seed ->
        identical plan.
    spacing : float
        Distance between sensor samples along the driven path, m (default 5).
    step : float
        Along-track advance of each move, m (default 10); the last move of a swath piece is
        shortened to end on the region boundary.
    max_deviation : float, optional
        Largest across-track distance from the reference swath, m. Default: 0.45 x the swath
        spacing (strictly less than half, so neighbouring swaths never cross). Must be > 0 and,
        with more than one swath, < half the swath spacing.
    switch_probability : float
        Probability, per move, that the flag toggles between descent (0) and ascent (1);
        in [0, 1], default 0.1 (a switch every ~``step / 0.1`` = 100 m on average).
    heading : float, optional
        Direction of travel of the first swath, degrees clockwise from north; default the
        region's long axis (:func:`survey.lawnmower.default_heading`).
    initial_flag : {0, 1}, optional
        Flag at the start of every swath piece; default drawn at random per piece.
    margin : float, optional
        Distance kept between swath ends and the boundary, m (as in :func:`survey.lawnmower`).
    crs : optional
        Projected CRS of the region; must match the prior's. Default: the prior's CRS.

    Returns
    -------
    SurveyPlan
        ``pattern="piecewise_continuous"``; one waypoint per move; legs between swath pieces
        are transit legs (samples on them have swath -1).
    """
    _check_common(n_swaths, spacing, heading, margin)
    if not (np.isfinite(step) and step > 0):
        raise bad_input("step", step, "a positive along-track move in metres", "e.g. 10.0")
    if not (np.isfinite(switch_probability) and 0 <= switch_probability <= 1):
        raise bad_input(
            "switch_probability", switch_probability, "a probability in [0, 1]", "e.g. 0.1"
        )
    if initial_flag not in (None, 0, 1):
        raise bad_input(
            "initial_flag", initial_flag, "0 (descent), 1 (ascent) or None", "pass 0 or 1"
        )
    ref = reference_swaths(region, n_swaths, heading, margin)
    n = int(n_swaths)
    if max_deviation is None:
        max_deviation = 0.45 * ref.spacing
    ok = np.isfinite(max_deviation) and max_deviation > 0
    if not ok or (n > 1 and max_deviation >= ref.spacing / 2):
        raise bad_input(
            "max_deviation",
            max_deviation,
            f"a distance in (0, {ref.spacing / 2:.6g}) m (half the swath spacing)",
            "leave it None for 0.45 x the swath spacing",
        )
    poly = as_region(region)
    grid, gx, gy = _prior_gradient(prior, poly.bounds, crs)
    inside = poly.buffer(_INSIDE_TOL, join_style="mitre")
    shapely.prepare(inside)

    # Tracks: one per swath piece, all advanced together, one move per iteration.
    t_sw, t_a = ref.piece_swath, ref.piece_along
    n_tracks = t_sw.size
    if n_tracks == 0:
        raise bad_input("region", "no swath inside", "a region the swaths cross", "check margin")
    length = np.abs(t_a[:, 1] - t_a[:, 0])
    sgn = np.sign(t_a[:, 1] - t_a[:, 0])
    n_moves = np.maximum(np.ceil(length / step - 1e-9).astype(np.int64), 1)
    k_max = int(n_moves.max())
    rng = np.random.default_rng(seed)
    flag = rng.integers(0, 2, n_tracks) if initial_flag is None else np.full(n_tracks, initial_flag)
    toggles = rng.random((k_max, n_tracks)) < switch_probability
    u, v = heading_vectors(ref.heading_deg)
    off = ref.offsets[t_sw]
    along = t_a[:, :1] + sgn[:, None] * np.minimum(np.arange(k_max + 1) * step, length[:, None])
    c = np.zeros((n_tracks, k_max + 1))
    fallback = np.array([1.0, 0.5, 0.0])  # keep c, halve it, back to the swath line
    for k in range(k_max):
        act = np.flatnonzero(k < n_moves)
        flag[act] ^= toggles[k, act]
        cur = ref.to_world(along[act, k], off[act] + c[act, k])
        gxi, gyi = _bilinear(grid, (gx, gy), cur)
        gnorm = np.hypot(gxi, gyi)
        g_across = np.where(gnorm > _FLAT, (gxi * v[0] + gyi * v[1]) / np.maximum(gnorm, _FLAT), 0)
        # Eq 10: descend (flag 0) or ascend (flag 1) the prior, across-track share of the move
        direction = np.where(flag[act] == 1, 1.0, -1.0)
        dstep = along[act, k + 1] - along[act, k]
        want = c[act, k] + direction * np.abs(dstep) * g_across
        cand = np.column_stack([want, c[act, k : k + 1] * fallback])
        cand = np.clip(cand, -max_deviation, max_deviation)  # (a, 4)
        nxt = ref.to_world(along[act, k + 1][:, None], off[act][:, None] + cand)
        legs = shapely.linestrings(np.stack([np.broadcast_to(cur[:, None], nxt.shape), nxt], -2))
        good = shapely.covered_by(legs, inside)
        good[:, -1] = True  # the swath line itself is inside by construction
        c[act, k + 1] = cand[np.arange(act.size), np.argmax(good, axis=1)]

    rows = [np.arange(int(n_moves[t]) + 1) for t in range(n_tracks)]
    ti = np.repeat(np.arange(n_tracks), n_moves + 1)
    ki = np.concatenate(rows)
    waypoints = ref.to_world(along[ti, ki], off[ti] + c[ti, ki])
    swath = t_sw[ti]
    transit = ti[1:] != ti[:-1]
    params = {
        "n_swaths": n,
        "heading_deg": ref.heading_deg,
        "spacing": float(spacing),
        "seed": int(seed),
        "step": float(step),
        "max_deviation": float(max_deviation),
        "switch_probability": float(switch_probability),
        "initial_flag": initial_flag,
        "margin": 0.0 if margin is None else float(margin),
        "swath_spacing": ref.spacing,
        "heading_source": "given" if heading is not None else "minimum_rotated_rectangle",
        "prior_bounds": list(grid.bounds),
        "prior_shape": list(grid.shape),
    }
    return build_plan(
        waypoints,
        swath,
        transit,
        float(spacing),
        pattern="piecewise_continuous",
        params=params,
        swath_offsets=ref.offsets,
        heading_deg=ref.heading_deg,
        origin=ref.origin,
        crs=grid.crs if crs is None else crs,
    )
