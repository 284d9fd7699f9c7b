"""Landmark selection: the paper's rules (Section II-E / IV) turning landmark estimates into
terrain samples.

Rules, in order (each landmark is removed by the first rule it fails, and counted there):

1. ``max_sigma``: the largest 1-sigma semi-axis of the landmark's *relative* covariance
   ellipsoid (shared GPS offset removed, see :mod:`factorgraph.marginals`) is <= 0.5 m.
   Applying the rule to the full covariance would reject every landmark whenever the
   unobservable mean GPS bias exceeds 0.5 m, although the map's shape is known far better.
2. ``min_first_seen_distance``: the landmark was initialised more than 5 m from the rover
   (the paper's thinning of redundant near-path landmarks).

Elevation variance: Eq 7 marginalizes x, y out of the 3x3 covariance (``var = Sigma_zz``).
``variance="slope"`` uses var(z - g^T [x, y]) with ``g`` the local surface slope (a
least-squares plane through the neighbouring landmarks): a horizontal error on a slope is an
elevation error against the surface at the estimated (x, y).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from scipy.spatial import cKDTree

from terrain.errors import bad_input
from terrain.samples import ElevationSamples

from .result import LocalizationResult

__all__ = ["LandmarkSelection", "local_slopes", "select_landmarks"]


@dataclass
class LandmarkSelection:
    """Selected landmarks as terrain samples, plus the per-landmark diagnostics table.

    Attributes
    ----------
    samples : ElevationSamples
        x, y (projected CRS of the log, m), z (m), z_var (m^2) of the kept landmarks;
        ``extra``: ``landmark_id`` and ``t_s`` (mean observation time, s).
    table : dict of ndarray
        One row per landmark in the graph: ``landmark_id``, ``x``, ``y``, ``z``,
        ``sigma_max_m`` (largest relative 1-sigma semi-axis), ``sigma_max_full_m``,
        ``z_std_m``, ``first_seen_distance_m``, ``n_views``, ``t_s`` (mean observation
        time, s: :meth:`LocalizationResult.landmark_time_s`), ``kept``, ``reason``.
    counts : dict
        Landmarks removed by each rule, and ``kept`` / ``in_graph`` totals; tracks that never
        became landmarks are in ``never_initialised`` (by reason).
    shared_offset_std_m : ndarray of shape (3,)
        1-sigma of the map-wide rigid offset (E, N, U), m. The vertical entry is the
        constant term the terrain product states beside ``elevation_std``.
    settings : dict
    """

    samples: ElevationSamples
    table: dict[str, np.ndarray]
    counts: dict[str, Any]
    shared_offset_std_m: np.ndarray
    settings: dict[str, Any] = field(default_factory=dict)


def local_slopes(xyz: np.ndarray, k: int = 12) -> np.ndarray:
    """Surface slope (dz/dx, dz/dy) at each point (n, 3) from a plane through its ``k``
    nearest neighbours (least squares). Returns (n, 2); zeros when fewer than 3 points."""
    n = len(xyz)
    if n < 3:
        return np.zeros((n, 2))
    k = min(k, n)
    _, idx = cKDTree(xyz[:, :2]).query(xyz[:, :2], k=k)
    nb = xyz[idx]  # (n, k, 3)
    d = nb - nb.mean(axis=1, keepdims=True)
    G = np.einsum("nki,nkj->nij", d[..., :2], d[..., :2]) + 1e-9 * np.eye(2)
    r = np.einsum("nki,nk->ni", d[..., :2], d[..., 2])
    return np.linalg.solve(G, r[..., None])[..., 0]


def select_landmarks(
    result: LocalizationResult,
    max_sigma: float = 0.5,
    min_first_seen_distance: float = 5.0,
    variance: Literal["eq7", "slope"] = "eq7",
    relative: bool = True,
    rule: Literal["ellipse", "elevation"] = "ellipse",
) -> LandmarkSelection:
    """Apply the paper's selection rules and return terrain samples.

    Parameters
    ----------
    result : LocalizationResult
        Output of :func:`factorgraph.localize`.
    max_sigma : float
        Largest allowed 1-sigma semi-axis of the landmark covariance ellipsoid (m).
    min_first_seen_distance : float
        Minimum rover-to-landmark distance at initialisation (m).
    variance : {"eq7", "slope"}
        Elevation variance by Eq 7, or slope-aware (module docstring).
    relative : bool
        Apply ``max_sigma`` to the relative covariance (default) or the full one.
    rule : {"ellipse", "elevation"}
        What ``max_sigma`` bounds. ``"ellipse"``: the largest 1-sigma semi-axis of the 3-D
        ellipsoid (the paper's words). ``"elevation"``: the slope-aware elevation 1-sigma,
        ``sqrt(var(z - grad z . [x, y]))`` -- the error a landmark puts into an elevation map,
        horizontal error included where the surface slopes. With consumer GPS the horizontal
        axes stay near 1 m relative (the bias wanders with tau ~ 60 s), so only the second
        rule can select anything at 0.5 m (docs/localization.md).

    Returns
    -------
    LandmarkSelection
    """
    if not isinstance(result, LocalizationResult):
        raise bad_input("result", type(result).__name__, "a LocalizationResult", "localize()")
    for name, v in (("max_sigma", max_sigma), ("min_first_seen_distance", min_first_seen_distance)):
        if not (np.isfinite(v) and v >= 0):
            raise bad_input(name, v, "a finite value >= 0 (m)", "use the paper's 0.5 / 5.0")
    if variance not in ("eq7", "slope"):
        raise bad_input("variance", variance, "'eq7' or 'slope'", "pick one")
    if rule not in ("ellipse", "elevation"):
        raise bad_input("rule", rule, "'ellipse' or 'elevation'", "pick one")
    cov_rel, cov_full = result.landmark_cov_relative, result.landmark_cov
    cov = cov_rel if relative else cov_full

    def largest_sigma(c: np.ndarray) -> np.ndarray:
        return np.sqrt(np.clip(np.linalg.eigvalsh(c)[:, -1], 0.0, None)) if len(c) else np.zeros(0)

    sig = largest_sigma(cov_rel)
    sig_full = largest_sigma(cov_full)
    sig_rule = sig if relative else sig_full
    xyz = result.landmark_xyz
    # Eq 7: marginalize x, y out of the landmark covariance -> var(z) = Sigma_zz
    z_var_eq7 = np.clip(cov[:, 2, 2], 1e-12, None)
    z_var_slope = z_var_eq7
    if len(xyz):
        g = local_slopes(xyz)
        z_var_slope = np.clip(
            cov[:, 2, 2]
            - 2 * np.einsum("ni,ni->n", g, cov[:, :2, 2])
            + np.einsum("ni,nij,nj->n", g, cov[:, :2, :2], g),
            1e-12,
            None,
        )
    z_var = z_var_slope if variance == "slope" else z_var_eq7
    if rule == "elevation":
        sig_rule = np.sqrt(z_var_slope)
    reason = np.full(len(xyz), "kept", dtype=object)
    fail_sigma = ~(sig_rule <= max_sigma)
    reason[fail_sigma] = "sigma_above_max"
    fail_dist = ~fail_sigma & ~(result.first_seen_distance_m > min_first_seen_distance)
    reason[fail_dist] = "first_seen_too_close"
    kept = reason == "kept"
    if not kept.any():
        raise bad_input(
            "landmarks",
            f"{len(xyz)} in the graph, {int(fail_sigma.sum())} above max_sigma={max_sigma} m, "
            f"{int(fail_dist.sum())} first seen within {min_first_seen_distance} m",
            "at least one landmark passing the rules (no landmark passed)",
            "survey longer (GPS averages out over minutes) or loosen max_sigma",
        )
    proj = result.to_projected(xyz)
    t_obs = result.landmark_time_s()
    samples = ElevationSamples(
        proj[kept, :2],
        proj[kept, 2],
        z_var[kept],
        crs=result.log.crs,
        extra={"landmark_id": result.landmark_id[kept], "t_s": t_obs[kept]},
        duplicates="average",
    )
    table = {
        "landmark_id": result.landmark_id,
        "x": proj[:, 0],
        "y": proj[:, 1],
        "z": proj[:, 2],
        "sigma_max_m": sig,
        "sigma_max_full_m": sig_full,
        "z_std_m": np.sqrt(z_var),
        "z_std_slope_m": np.sqrt(z_var_slope),
        "first_seen_distance_m": result.first_seen_distance_m,
        "n_views": result.n_views,
        "t_s": t_obs,
        "kept": kept,
        "reason": reason.astype(str),
    }
    counts = {
        "in_graph": int(len(xyz)),
        "sigma_above_max": int(fail_sigma.sum()),
        "first_seen_too_close": int(fail_dist.sum()),
        "kept": int(kept.sum()),
        "never_initialised": dict(result.dropped),
    }
    settings = {
        "max_sigma_m": float(max_sigma),
        "min_first_seen_distance_m": float(min_first_seen_distance),
        "variance": variance,
        "relative": bool(relative),
        "rule": rule,
    }
    shared = np.sqrt(np.clip(np.diag(result.shared_offset_cov), 0.0, None))
    return LandmarkSelection(samples, table, counts, shared, settings)
