"""Coverage metrics of a survey (paper, Section III-A and III-B).

* robot-centric coverage ``D_S / D_T`` (distance driven over a maximum distance);
* science-centric coverage %SCC (Eq 11), returned as a fraction;
* centeredness alpha (Eq 12-13) and distributedness beta (Eq 14-16).

All coordinates are easting/northing in metres; ``across`` values are the swath-frame
coordinate of :meth:`survey.plan.SurveyPlan.to_swath_frame`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
import shapely

from terrain.errors import bad_input

if TYPE_CHECKING:
    from .plan import SurveyPlan

__all__ = [
    "candidate_points",
    "centeredness",
    "distributedness",
    "path_length",
    "plan_distributedness",
    "robot_centric_coverage",
    "science_centric_coverage",
]

#: Eq 15: only consecutive samples at least this far apart across-track enter beta_b, m.
BETA_MIN_STEP = 1.0


def _xy(name: str, value: Any, allow_empty: bool = False) -> np.ndarray:
    xy = np.asarray(value, dtype=float)
    if xy.ndim == 1 and xy.size == 2:
        xy = xy.reshape(1, 2)
    if xy.ndim != 2 or xy.shape[1] != 2 or not np.all(np.isfinite(xy)):
        raise bad_input(
            name, getattr(xy, "shape", value), "finite (n, 2) easting/northing", "stack x and y"
        )
    if xy.shape[0] == 0 and not allow_empty:
        raise bad_input(name, xy.shape, "at least one point", "pass a non-empty set")
    return xy


def path_length(waypoints: np.ndarray) -> float:
    """Length of the polyline through ``waypoints`` (k, 2), metres (0 for k < 2)."""
    wp = _xy("waypoints", waypoints, allow_empty=True)
    return float(np.hypot(*np.diff(wp, axis=0).T).sum()) if wp.shape[0] > 1 else 0.0


def robot_centric_coverage(path_length_m: float, total_length_m: float) -> float:
    """Robot-centric coverage ``D_S / D_T`` (Section III-A), dimensionless.

    Parameters
    ----------
    path_length_m : float
        ``D_S``, distance the rover drove (or plans to drive), m, >= 0.
    total_length_m : float
        ``D_T``, the maximum distance (e.g. the path length of a dense reference lawnmower), m,
        > 0.

    Returns
    -------
    float
        ``D_S / D_T``; 1 means "complete" coverage in the robotics sense; may exceed 1.
    """
    ds, dt = float(path_length_m), float(total_length_m)
    if not (np.isfinite(ds) and ds >= 0):
        raise bad_input(
            "path_length_m", path_length_m, "a finite distance >= 0 m", "pass plan.path_length"
        )
    if not (np.isfinite(dt) and dt > 0):
        raise bad_input(
            "total_length_m",
            total_length_m,
            "a finite distance > 0 m",
            "e.g. a dense lawnmower length",
        )
    return ds / dt


def candidate_points(region: Any, spacing: float) -> np.ndarray:
    """The discretised set of all possible samples: grid cell centres inside ``region``.

    Cells of ``spacing`` m are laid from the region's south-west bounds corner; a centre counts
    if it lies inside the region (not in a hole; points on the boundary are excluded).

    Returns
    -------
    ndarray of shape (S, 2)
        Easting/northing of the candidates, m, row-major from the south-west.
    """
    from .region import as_region

    poly = as_region(region)
    if not (np.isfinite(spacing) and spacing > 0):
        raise bad_input("spacing", spacing, "a positive cell size in metres", "e.g. 5.0")
    west, south, east, north = poly.bounds
    x = west + spacing * (np.arange(max(int(np.ceil((east - west) / spacing)), 1)) + 0.5)
    y = south + spacing * (np.arange(max(int(np.ceil((north - south) / spacing)), 1)) + 0.5)
    xx, yy = np.meshgrid(x, y)
    xy = np.column_stack([xx.ravel(), yy.ravel()])
    return xy[shapely.contains_xy(poly, xy[:, 0], xy[:, 1])]


def science_centric_coverage(
    samples_xy: np.ndarray, candidates_xy: np.ndarray, ref: np.ndarray | None = None
) -> float:
    """Science-centric coverage %SCC = T_M / T_S (Eq 11), as a fraction.

    Parameters
    ----------
    samples_xy : ndarray of shape (M, 2)
        Actual sample locations, m.
    candidates_xy : ndarray of shape (S, 2)
        All possible sample locations (e.g. :func:`candidate_points`), m.
    ref : array-like of shape (2,), optional
        ``(X_ref, Y_ref)``; default: the centroid (mean) of the candidates.

    Returns
    -------
    float
        ``sum_m ||x_m - ref|| / sum_s ||x_s - ref||`` (multiply by 100 for the paper's
        percent). Not capped at 1: repeated or far-out samples can exceed it.
    """
    smp = _xy("samples_xy", samples_xy, allow_empty=True)
    cand = _xy("candidates_xy", candidates_xy)
    r = cand.mean(axis=0) if ref is None else _xy("ref", ref)[0]
    # Eq 11: science-centric coverage = T_M / T_S
    t_m = float(np.hypot(*(smp - r).T).sum())
    t_s = float(np.hypot(*(cand - r).T).sum())
    if t_s <= 0:
        raise bad_input("candidates_xy", "all at ref", "candidates spread around ref", "check ref")
    return t_m / t_s


def centeredness(
    samples_xy: np.ndarray,
    ref: np.ndarray,
    d_max: float | None = None,
    region: Any = None,
) -> float:
    """Centeredness alpha (Eq 12-13): CoM offset from ``ref`` over ``D_Max``.

    Parameters
    ----------
    samples_xy : ndarray of shape (M, 2)
        Sample locations, m.
    ref : array-like of shape (2,)
        ``(X_ref, Y_ref)``, m (e.g. the region centroid).
    d_max : float, optional
        ``D_Max``, m: the largest possible distance between a sample set's CoM and ``ref``.
    region : shapely polygon or bounds, optional
        Used when ``d_max`` is None: ``D_Max`` is then the largest distance from ``ref`` to the
        region (attained at an exterior vertex). The CoM of samples inside the region lies in
        its convex hull, so this is the "maximum possible" distance of Eq 13. Pass it (or
        ``d_max``) to compare alpha between plans of the same region.
        With neither, ``D_Max`` is the largest distance from ``ref`` to a sample: the CoM of
        these sample locations (under any weighting) cannot lie farther. This keeps alpha in
        [0, 1] but depends on the sample set.

    Returns
    -------
    float
        alpha in [0, 1] for samples inside the region (or with the sample-based ``D_Max``);
        0 = perfectly centred.
    """
    smp = _xy("samples_xy", samples_xy)
    r = _xy("ref", ref)[0]
    if d_max is None and region is not None:
        from .region import as_region

        d_max = float(shapely.hausdorff_distance(as_region(region), shapely.Point(*r)))
    elif d_max is None:
        d_max = float(np.hypot(*(smp - r).T).max())
        if d_max == 0:
            return 0.0  # every sample at ref: CoM = ref
    if not (np.isfinite(d_max) and d_max > 0):
        raise bad_input("d_max", d_max, "a positive distance in metres", "or pass region=")
    com = smp.mean(axis=0)  # Eq 12: planimetric centre of mass
    return float(np.hypot(*(com - r)) / d_max)  # Eq 13


def _beta_terms(across: np.ndarray, y_swath: float) -> tuple[float, float]:
    m = across.size
    beta_a = float(np.abs(across - y_swath).mean()) if m else float("nan")  # Eq 14
    if m < 2:
        return beta_a, 0.0
    d = np.abs(np.diff(across))
    # Eq 15: sum over consecutive pairs with |dy| >= 1 m, divided by (M - 1) as printed
    return beta_a, float(d[d >= BETA_MIN_STEP].sum() / (m - 1))


def distributedness(samples_across: np.ndarray, y_swath: float) -> float:
    """Distributedness beta = beta_a / beta_b of one swath (Eq 14-16).

    Parameters
    ----------
    samples_across : ndarray of shape (M,)
        Across-track coordinate of the swath's samples in driving order, m.
    y_swath : float
        Across-track coordinate of the reference swath, m.

    Returns
    -------
    float
        ``beta_a / beta_b`` where ``beta_a`` (Eq 14) is the mean distance from the reference
        and ``beta_b`` (Eq 15) is the sum of the consecutive across-track changes of at least
        1 m, divided by ``M - 1`` (the paper's denominator: smaller changes count as zero).
        **NaN** when ``beta_b == 0`` — fewer than two samples, or no consecutive change of
        >= 1 m (e.g. any straight lawnmower swath): Eq 16 is then undefined, whatever
        ``beta_a`` is.
    """
    y = np.asarray(samples_across, dtype=float).ravel()
    if not (np.all(np.isfinite(y)) and np.isfinite(y_swath)):
        raise bad_input("samples_across", y[:5], "finite across-track offsets, m", "drop NaN")
    beta_a, beta_b = _beta_terms(y, float(y_swath))
    return beta_a / beta_b if beta_b > 0 else float("nan")  # Eq 16


def plan_distributedness(plan: SurveyPlan) -> tuple[np.ndarray, float]:
    """Beta (Eq 14-16) of every reference swath of ``plan`` and their mean.

    Uses ``plan.to_swath_frame(plan.samples)[:, 1]`` of the samples with
    ``plan.sample_swath == i`` (transit samples, swath -1, are left out) against
    ``plan.swath_offsets[i]``.

    Returns
    -------
    per_swath : ndarray of shape (n_swaths,)
        Beta of each swath; NaN where undefined (see :func:`distributedness`).
    overall : float
        Unweighted mean of the defined per-swath values; NaN if none is defined.
    """
    across = plan.to_swath_frame(plan.samples)[:, 1]
    ssw = np.asarray(plan.sample_swath)
    per = np.array(
        [
            distributedness(across[ssw == i], off)
            for i, off in enumerate(np.asarray(plan.swath_offsets))
        ]
    )
    ok = np.isfinite(per)
    return per, float(per[ok].mean()) if ok.any() else float("nan")
