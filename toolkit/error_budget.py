"""The map's 1-sigma with the survey's correlated errors put back.

The GP treats every landmark's elevation error as independent (per-point ``z_var``), so a
cell seen by a hundred landmarks gets a 1-sigma about ten times smaller than one landmark's.
That is right for the per-landmark part of the error and wrong for the two parts the
localization shares between landmarks:

* the map-wide rigid offset (the unobservable mean GPS bias; ``shared_offset_std_m``), one
  number for the whole map;
* the along-track part: the GPS bias wanders with tau ~ 60 s, so every landmark triangulated
  from the same minute of driving inherits the same trajectory error. Its size is the
  landmark's *relative* vertical 1-sigma (the shared offset removed), which on the default
  survey is ~1 m for almost every landmark -- it is pose error, not triangulation noise.

Neither averages down over neighbours, so both are added to the GP's variance where the map
leans on the data. A third shared part is horizontal: the map-wide offset has east and north
components too (~1.4 m 1-sigma with consumer GPS on a short survey), and a map shifted
sideways by ``d`` is wrong by ``grad z . d`` where the ground slopes -- an error that is
neither constant (no mean removal takes it out) nor in the landmarks' vertical sigma
(Eq 7 marginalizes x, y away). Measured on the example field folder's survey (310 m, seed
7, 6 % rms slope): the map's error after its mean was removed was 0.118 m and correlated
0.88 with ``-grad z . d`` for the realised offset ``d``; the relative 1-sigma without the
term covered 33.9 / 53.4 % of the truth at 68 / 95 %, with it 58.9 / 99.2 %. How much the
map leans on the data is the variance the data explained,
``w = 1 - var_post / var_prior`` (0 far from data, where the map is the satellite prior and
carries none of the survey's error; ~1 among the landmarks):

    var_map(x) = var_gp(x) + w(x) * (sigma_track(x)^2 + sigma_shared^2
                                     + gx(x)^2 sigma_east^2 + gy(x)^2 sigma_north^2
                                     + |grad z(x)|^2 sigma_h^2)

with ``sigma_track(x)`` the median relative vertical 1-sigma of the ``k`` nearest selected
landmarks, and ``sigma_h`` the samples' own horizontal 1-sigma when stated (``horizontal_sd``:
digitised contours, whose lines are drawn metres off; on a real glacier's contours 10 m
puts the held-out levels' coverage from 86.6-90.2 / 65.6-69.5 % to 89.1-92.4 / 69.1-72.1 %
at 95 / 68, docs/terrain.md "A real map's contours as the samples"). Measured on the
default run (seed 0): 95 % interval coverage of the truth went from 0.19 (GP alone) to the
value in the run's certificate (see docs/localization.md).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from terrain.along_track import AlongTrackModel

__all__ = [
    "along_track_variance",
    "correlated_variance",
    "heldout_along_track",
    "heldout_slope_term",
    "inflate_std",
    "slope_squared",
]


def correlated_variance(
    query_xy: np.ndarray,
    landmark_xy: np.ndarray,
    relative_z_std: np.ndarray,
    k: int = 10,
    landmark_t_s: np.ndarray | None = None,
    model: AlongTrackModel | None = None,
) -> np.ndarray:
    """Along-track variance of the mean of the ``k`` nearest landmarks, per query point.

    With observation times: ``(1/k^2) sum_ij f s_i s_j exp(-|t_i - t_j| / tau)`` over the
    ``k`` nearest (the along-track model of :mod:`terrain.along_track`, fraction ``f`` and
    ``tau`` measured on simulated surveys): landmarks seen in the same minute share their
    error, landmarks from another pass of the rover share less. Without times: the median
    ``s_i^2`` (every neighbour assumed to share one error: an upper bound).

    Parameters
    ----------
    query_xy : ndarray of shape (m, 2)
        Projected coordinates (m).
    landmark_xy : ndarray of shape (n, 2)
        Selected landmarks, same CRS.
    relative_z_std : ndarray of shape (n,)
        Their vertical 1-sigma with the shared offset removed (m).
    k : int
        Neighbours (clipped to ``n``).
    landmark_t_s : ndarray of shape (n,), optional
        Each landmark's mean observation time (s, any origin: only differences count).
    model : terrain.AlongTrackModel, optional
        Fraction and correlation time; default: the measured ones.

    Returns
    -------
    ndarray of shape (m,)
        Variance (m^2).
    """
    s = np.asarray(relative_z_std, float)
    if s.size == 0:
        return np.zeros(len(query_xy))
    k = max(1, min(int(k), s.size))
    _, idx = cKDTree(np.asarray(landmark_xy, float)).query(np.asarray(query_xy, float), k=k)
    idx = np.asarray(idx).reshape(len(query_xy), k)
    if landmark_t_s is None:
        return np.median(s[idx] ** 2, axis=1)
    model = model or AlongTrackModel()
    t = np.asarray(landmark_t_s, float)
    out = np.empty(len(query_xy))
    for lo in range(0, len(query_xy), 8192):  # (chunk, k, k) pairs at a time
        i = idx[lo : lo + 8192]
        si, ti = s[i], t[i]
        rho = np.exp(-np.abs(ti[:, :, None] - ti[:, None, :]) / model.tau_s)
        out[lo : lo + 8192] = np.einsum("ci,cij,cj->c", si, rho, si) / (k * k)
    return model.fraction * out


def along_track_variance(
    query_xy: np.ndarray,
    var_gp: np.ndarray,
    prior_var: np.ndarray,
    landmark_xy: np.ndarray,
    relative_z_std: np.ndarray,
    k: int = 10,
    landmark_t_s: np.ndarray | None = None,
) -> np.ndarray:
    """The along-track variance the map adds at ``query_xy``: ``w * correlated_variance``
    with ``w = 1 - var_gp / prior_var`` (clipped to [0, 1]), the share of the prior variance
    the data explained (module docstring). Shapes (m,) but ``query_xy`` (m, 2); m^2."""
    w = lean_weight(var_gp, prior_var)
    return w * correlated_variance(query_xy, landmark_xy, relative_z_std, k, landmark_t_s)


def lean_weight(var_gp: np.ndarray, prior_var: np.ndarray) -> np.ndarray:
    """How much the map leans on the data: ``w = 1 - var_gp / prior_var`` clipped to [0, 1]
    (0 far from data, ~1 among the landmarks), shape of ``var_gp``."""
    return np.clip(1.0 - var_gp / np.maximum(prior_var, 1e-12), 0.0, 1.0)


def heldout_along_track(
    gp,
    xy: np.ndarray,
    landmark_xy: np.ndarray,
    relative_z_std: np.ndarray,
    landmark_t_s: np.ndarray | None = None,
    k: int = 10,
):
    """The ``extra_variance`` hook of :func:`terrain.cross_validate` for samples at ``xy``
    (n, 2): the along-track variance :func:`inflate_std` adds to the map, from each fold's
    training samples only, so the held-out check is of the 1-sigma the product states (less
    the shared offset, which held-out samples carry too). Each sample takes the relative
    1-sigma and time of its nearest landmark (the same point unless duplicates were
    merged)."""
    nearest = cKDTree(np.asarray(landmark_xy, float)).query(np.asarray(xy, float))[1]
    rel = np.asarray(relative_z_std, float)[nearest]
    t = None if landmark_t_s is None else np.asarray(landmark_t_s, float)[nearest]

    def extra(train: np.ndarray, query: np.ndarray, var_f: np.ndarray) -> np.ndarray:
        prior = gp.kernel_.diag(query)
        t_train = None if t is None else t[train]
        return along_track_variance(query, var_f, prior, xy[train], rel[train], k, t_train)

    return extra


def inflate_std(
    product,
    gp,
    landmark_xy: np.ndarray,
    relative_z_std: np.ndarray,
    shared_z_std: float,
    k: int = 10,
    shared_everywhere: bool = False,
    landmark_t_s: np.ndarray | None = None,
    shared_xy_std: tuple[float, float] | None = None,
    horizontal_sd: float | None = None,
):
    """Return ``product`` with ``elevation_std`` including the survey's correlated errors.

    Parameters
    ----------
    product : xarray.Dataset
        ``elevation`` and ``elevation_std`` on ``(y, x)``, from ``gp.predict_grid``.
    gp : terrain.TerrainGP
        The fitted GP (its kernel gives the prior variance).
    landmark_xy, relative_z_std : ndarray
        Selected landmarks and their relative vertical 1-sigma (m).
    shared_z_std : float
        1-sigma of the map-wide vertical offset (m).
    shared_everywhere : bool
        The shared offset reaches every cell, not only those that lean on the data: true when
        the prior mean's vertical offset is fitted to the samples (``RasterMean(offset="fit")``,
        a GLS constant), which carries the survey's offset into the prior too. Measured on the
        default run: weighting it by ``w`` there left 83 % of the truth inside the 95 %
        interval, the map being 0.46 m high everywhere.
    landmark_t_s : ndarray of shape (n,), optional
        The landmarks' mean observation times (s): the along-track term then follows their
        time correlation (:func:`correlated_variance`); without them it is an upper bound.
    shared_xy_std : (float, float), optional
        1-sigma of the map-wide horizontal offset, east and north (m): adds
        ``w * (gx^2 sigma_east^2 + gy^2 sigma_north^2)`` with ``gx, gy`` the map's slope, to
        both 1-sigmas (a sideways shift is not a constant offset). None: no horizontal term.
    horizontal_sd : float, optional
        The samples' own horizontal 1-sigma (m), locally correlated (digitised contours: a
        line drawn a few metres off moves with all its points; a rover's relative drift):
        adds ``w * |grad z|^2 * horizontal_sd^2`` to both 1-sigmas (the map's own error,
        not shared). None or 0: no such term (docs/terrain.md "A real map's contours").

    Returns
    -------
    xarray.Dataset
        A copy with the inflated ``elevation_std`` (total) and ``elevation_std_relative``
        (GP + along-track: the map's own 1-sigma, the shared offset stated once in
        ``attrs["shared_vertical_offset_std_m"]``); ``attrs`` record the method and the
        median 1-sigma of the GP alone and of the added part.
    """
    xx, yy = np.meshgrid(product["x"].values, product["y"].values)
    q = np.column_stack([xx.ravel(), yy.ravel()])
    prior = gp.kernel_.diag(q)
    post = product["elevation_std"].values.ravel() ** 2
    w = lean_weight(post, prior)
    track = w * correlated_variance(q, landmark_xy, relative_z_std, k, landmark_t_s)
    if shared_xy_std is not None or horizontal_sd:  # sideways errors, through the slope
        gx, gy = (g.ravel() ** 2 for g in _slope(product))
        sx, sy = (float(v) for v in shared_xy_std or (0.0, 0.0))
        h2 = float(horizontal_sd or 0.0) ** 2  # the samples' own, not shared
        track = track + w * (gx * (sx**2 + h2) + gy * (sy**2 + h2))
    added = track + (1.0 if shared_everywhere else w) * float(shared_z_std) ** 2
    out = product.copy()
    dims = product["elevation_std"].dims
    out["elevation_std"] = (dims, np.sqrt(post + added).reshape(xx.shape))
    out["elevation_std"].attrs.update(product["elevation_std"].attrs)
    # The map's own 1-sigma: the shared offset left out (stated once, in attrs), so the data
    # gaps show instead of drowning under one number common to every cell.
    out["elevation_std_relative"] = (dims, np.sqrt(post + track).reshape(xx.shape))
    out["elevation_std_relative"].attrs.update(
        {
            **product["elevation_std"].attrs,
            "long_name": "relative 1-sigma of elevation (shared survey offset excluded)",
            "shared_vertical_offset_std_m": float(shared_z_std),
        }
    )
    out.attrs.update(
        {
            "std_error_budget": "GP variance + w * (along-track + shared offset"
            + (" + slope x shared horizontal offset" if shared_xy_std is not None else "")
            + (" + slope x the samples' horizontal 1-sigma" if horizontal_sd else "")
            + "), w = 1 - var_post/var_prior (toolkit.error_budget)",
            "std_along_track": "time-correlated over the k nearest landmarks"
            if landmark_t_s is not None
            else "no observation times: every neighbour shares one error (upper bound)",
            "std_gp_median_m": float(np.median(np.sqrt(post))),
            "std_added_median_m": float(np.median(np.sqrt(added))),
            "shared_vertical_offset_std_m": float(shared_z_std),
        }
    )
    if shared_xy_std is not None:
        out.attrs["shared_horizontal_offset_std_m"] = [float(v) for v in shared_xy_std]
    if horizontal_sd:
        out.attrs["samples_horizontal_std_m"] = float(horizontal_sd)
    return out


def _slope(product) -> tuple[np.ndarray, np.ndarray]:
    """``(dz/dx, dz/dy)`` of ``product["elevation"]`` (y, x) by central differences in
    metres (one-sided at the edges), each the grid's shape; dimensionless."""
    gy, gx = np.gradient(product["elevation"].values, product["y"].values, product["x"].values)
    return gx, gy


def slope_squared(product) -> np.ndarray:
    """``|grad z|^2`` of ``product["elevation"]``, the grid's shape (:func:`_slope`)."""
    gx, gy = _slope(product)
    return gx**2 + gy**2


def heldout_slope_term(gp, product, horizontal_sd: float):
    """The ``extra_variance`` hook of :func:`terrain.cross_validate` for the samples'
    horizontal 1-sigma: ``w * |grad z|^2 * horizontal_sd^2`` at each held-out sample, the
    slope read bilinearly from the map (``product``, the ground's, not the fold's) and
    ``w`` from the fold's own variance there, as :func:`inflate_std` adds it to the map. A
    local error, not a shared one: held-out samples see it, so the check counts it."""
    from scipy.interpolate import RegularGridInterpolator

    y, x, g2 = product["y"].values, product["x"].values, slope_squared(product)
    if y[0] > y[-1]:  # north-up rows: the interpolator wants ascending axes
        y, g2 = y[::-1], g2[::-1]
    slope2 = RegularGridInterpolator((y, x), g2, bounds_error=False, fill_value=None)
    h2 = float(horizontal_sd) ** 2

    def extra(train: np.ndarray, query: np.ndarray, var_f: np.ndarray) -> np.ndarray:
        w = lean_weight(var_f, gp.kernel_.diag(query))
        return w * np.maximum(slope2(np.asarray(query, float)[:, ::-1]), 0.0) * h2

    return extra
