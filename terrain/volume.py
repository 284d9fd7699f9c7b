"""Volume and mass change over a glacier outline, with a 1-sigma that respects correlation.

``dV = sum_q a_q dh_q`` over the cells ``q`` whose centre is inside the outline (``a_q`` the
cell area). Its error variance, by source (all independent):

* **GP posterior** (two glacimap maps, their fitted :class:`terrain.TerrainGP` passed as
  ``models``): for each epoch the posterior variance of the integral ``I = w^T f``,
  ``w^T K_qq w - v^T (K + N)^-1 v`` with ``v = K_Xq w`` (R&W Eq 2.24 applied to a linear
  functional), plus ``R^T cov(beta) R``, ``R = H_q w - H^T (K + N)^-1 v``, for a linear mean
  fitted by GLS (R&W Eq 2.42). ``w^T K_qq w`` is one FFT convolution of the weight raster
  with the kernel (:func:`terrain.variogram.covariance_sum`); ``v`` is summed exactly over
  the outline's cells (the posterior is a small difference of two large numbers: an
  interpolated ``v`` with 1e-3 relative error gave a 7x wrong variance). Exact for the exact
  GP (checked against dense matrices in tests/test_volume_change.py). Where a map reverts
  to its prior mean (far from data) this *is* the prior DEM's error as the GP models it:
  the kernel's prior variance there.
* **Shared survey offset** (one number per survey, fully correlated within it, independent
  between surveys): a vertical offset ``o`` of every sample moves the map's integral by
  ``o * u^T 1``, with ``u`` the linear weights of the estimator (``u^T 1 = sum w`` when the
  mean has a fitted constant: the whole map moves). Variance ``(sigma_o u^T 1)^2`` per survey;
  ``sigma_o`` from the product attribute ``shared_vertical_offset_std_m`` (what
  ``glacimap run`` writes) or the ``shared_offset_std`` argument.
* **Along-track correlated error** of each survey's samples (:mod:`terrain.along_track`):
  the GP takes each sample's ``z_var`` as independent, but samples seen in the same minutes
  share their trajectory error. With ``u`` the estimator's sample weights (``I_hat = u^T z``,
  ``u = (K+N)^-1 (v + H cov(beta) R)``), the variance it misses is
  ``u^T C u - sum_i u_i^2 s_i^2`` with ``C_ij = s_i s_j exp(-|t_i - t_j| / tau)``,
  ``s_i^2 = fraction z_var_i`` and ``t_i`` the sample's observation time
  (``samples.extra["t_s"]``); without times it is stated as not available. For a tiled GP,
  ``u`` is the subset GP's (an approximation, like its posterior term).
* **Co-registration**: when ``dh`` was co-registered, the relative vertical bias was estimated
  on stable ground; the shared offsets are replaced by that estimate's 1-sigma times the area.
* **Variogram** (any other DEM pair, the fallback): :mod:`terrain.variogram` on stable dh.

Mass: ``dM = rho dV``, ``sigma_M^2 = (rho sigma_V)^2 + (dV sigma_rho)^2`` (Huss 2013:
850 +- 60 kg m^-3).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from scipy.linalg import solve_triangular

from .along_track import AlongTrackModel, along_track_quadratic
from .coregister import as_polygons
from .errors import bad_input, positive_number
from .grid import Grid, north_up
from .outline_cover import check_outline_covered
from .variogram import (
    covariance_sum,
    empirical_variogram,
    fit_variogram,
)
from .void_fill import hypsometric_fill

__all__ = ["VolumeChange", "gp_integral", "outline_weights", "volume_change"]


@dataclass(frozen=True)
class VolumeChange:
    """Volume and mass change with the error budget (1-sigma by source, m^3)."""

    volume_m3: float
    volume_std_m3: float
    mean_dh_m: float
    mean_dh_std_m: float
    area_m2: float
    mass_kg: float
    mass_std_kg: float
    density_kg_m3: tuple[float, float]
    method: str
    budget_m3: dict[str, float]
    independent_std_m3: float
    n_cells: int
    n_cells_filled: int
    details: dict[str, Any] = field(default_factory=dict)

    @property
    def mass_gt(self) -> float:
        return self.mass_kg / 1e12

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["density_kg_m3"] = list(self.density_kg_m3)
        d["mass_gt"] = self.mass_gt
        d["mass_std_gt"] = self.mass_std_kg / 1e12
        return d


def outline_weights(grid: Grid, outline: Any) -> np.ndarray:
    """Cell areas (m^2) of the cells whose centre lies inside ``outline``, 0 elsewhere."""
    from rasterio.features import geometry_mask

    geoms = list(
        getattr(outline, "geoms", None)
        or (outline if isinstance(outline, list | tuple) else [outline])
    )
    if not geoms or not all(hasattr(g, "__geo_interface__") for g in geoms):
        raise bad_input("outline", type(outline).__name__, "shapely polygon(s)", "")
    inside = ~geometry_mask(as_polygons(outline, "outline"), grid.shape, grid.transform)
    return inside * (grid.resolution[0] * grid.resolution[1])


def gp_integral(
    gp: Any, grid: Grid, weights: np.ndarray, subset_max: int = 4000, seed: int = 0
) -> dict[str, Any]:
    """Posterior variance of ``I = sum_q w_q f(x_q)`` under a fitted exact ``TerrainGP`` and
    the response ``u^T 1`` of the map's estimate of ``I`` to a common offset of its samples.

    Parameters
    ----------
    gp : terrain.TerrainGP
        Fitted; same CRS as ``grid``. Exact: its Cholesky factor ``L_``. Tiled: an exact GP
        on at most ``subset_max`` of its samples (seeded), an upper bound (``route`` says).
    grid : Grid
        Cells of ``weights``.
    weights : ndarray of shape grid.shape
        Weight per cell (m^2 for a volume).

    Returns
    -------
    dict
        ``prior_m6`` (w^T K w), ``explained_m6`` (v^T (K+N)^-1 v), ``mean_coef_m6``,
        ``posterior_var_m6`` (their combination), ``offset_response_m2`` (u^T 1),
        ``sample_weights`` (u, shape (n,), m^2: the estimate of ``I`` is ``u^T z`` over the
        GP's samples ``sample_index`` — rows of ``gp.samples_``, in order of position;
        ``gp.sample_order_`` names the caller's rows — so an error ``e`` of the samples moves
        it by ``u^T e``) and ``route`` (how the factor was obtained).
    """
    X, L, Wb, cov_b, route, idx = _factor(gp, subset_max, seed)
    W = np.asarray(weights, float)

    def cov(lags: np.ndarray) -> np.ndarray:  # lags in metres, the kernel in its own space
        return gp.kernel_(gp.anisotropy_.apply(lags), np.zeros((1, 2)))[:, 0]

    prior = covariance_sum(W, grid.resolution, cov)  # w^T K_qq w, one FFT convolution
    # v = K_Xq w summed exactly (chunked): the posterior is a small difference of two large
    # numbers, so v must be exact to the last digits (an interpolated v is not).
    sel = W > 0
    q_xy = grid.xy()[sel.ravel()]
    q = gp._kernel_xy(q_xy)
    wq = W[sel]
    v = np.empty(X.shape[0])
    step = max(1, 2**24 // max(wq.size, 1))
    for i in range(0, X.shape[0], step):
        v[i : i + step] = gp.kernel_(X[i : i + step], q) @ wq
    Lv = solve_triangular(L, v, lower=True, check_finite=False)
    L1 = solve_triangular(L, np.ones(v.size), lower=True, check_finite=False)
    explained = float(Lv @ Lv)
    response = float(L1 @ Lv)
    coef = 0.0
    Lu = Lv
    if cov_b is not None:
        hq = np.asarray(gp.mean_.basis(q_xy), float)
        R = wq @ hq - Wb.T @ Lv  # R&W Eq 2.42 for the functional
        coef = float(R @ cov_b @ R)
        Lu = Lv + Wb @ (cov_b @ R)
        response += float((L1 @ Wb) @ cov_b @ R)
    # The estimator's weights: I_hat = u^T y with u = (K+N)^-1 (v + H cov(beta) R), i.e.
    # u = L^-T (L^-1 v + L^-1 H cov(beta) R) (R&W Eq 2.42); u^T 1 is the offset response.
    u = solve_triangular(L, Lu, lower=True, trans="T", check_finite=False)
    return {
        "prior_m6": prior,
        "explained_m6": explained,
        "mean_coef_m6": coef,
        "posterior_var_m6": max(prior - explained, 0.0) + coef,
        "offset_response_m2": response,
        "sample_weights": u,
        "sample_index": idx,
        "route": route,
    }


def _factor(gp: Any, subset_max: int, seed: int):
    """(X centred, L, L^-1 H or None, coefficient covariance or None, route, sample index)
    of a fitted GP (the index: which of the GP's samples ``X`` holds).

    Exact GP: its own factor. Tiled GP (no global factor): an exact GP at the fitted
    hyperparameters on a seeded random subset of at most ``subset_max`` samples. A GP's
    posterior variance only shrinks as data are added, so the subset's integral variance is
    an upper bound of the full GP's (conservative; its size measured in tests).
    """
    from .gp_mean import gls_coefficients, n_coef
    from .linalg import cholesky_jitter

    if not hasattr(gp, "method_"):
        raise bad_input("models", "an unfitted TerrainGP", "fitted GPs", "call fit first")
    if gp.method_ == "exact" and getattr(gp, "L_", None) is not None:
        return (
            gp.X_train_,
            gp.L_,
            getattr(gp, "W_", None),
            getattr(gp, "coef_cov_", None),
            "exact GP posterior",
            np.arange(gp.X_train_.shape[0]),
        )
    n = gp.X_train_.shape[0]
    idx = np.arange(n)
    if n > subset_max:
        idx = np.sort(np.random.default_rng(seed).choice(n, int(subset_max), replace=False))
    X = gp.X_train_[idx]
    noise = gp.z_var_[idx] + gp.nugget_
    K = gp.kernel_(X)
    K[np.diag_indices_from(K)] += noise
    L, _ = cholesky_jitter(K, what="volume_change subset kernel matrix")
    Wb = cov_b = None
    if n_coef(gp.mean_):
        H = np.asarray(gp.mean_.basis(gp.samples_.xy[idx]), float)
        _, cov_b = gls_coefficients(gp.kernel_, X, gp.y_resid_[idx], noise, H, L)
        Wb = solve_triangular(L, H, lower=True, check_finite=False)
    route = f"tiled GP: exact GP on {idx.size} of {n} samples (upper bound)"
    return X, L, Wb, cov_b, route, idx


def _check_density(density: Any) -> tuple[float, float]:
    try:
        rho, sd = (float(v) for v in density)
    except (TypeError, ValueError) as exc:
        raise bad_input("density", density, "(mean, 1-sigma) in kg m^-3", "e.g. (850, 60)") from exc
    rho = positive_number("density", rho, "pass e.g. density=(850.0, 60.0) (Huss 2013)")
    sd = positive_number("density 1-sigma", sd, "e.g. 60.0", allow_zero=True)
    return rho, sd


def volume_change(
    diff: Any,
    outline: Any,
    density: tuple[float, float] = (850.0, 60.0),
    *,
    models: tuple[Any, Any] | None = None,
    shared_offset_std: tuple[float, float] | None = None,
    stable: Any = None,
    seed: int = 0,
    along_track: AlongTrackModel | bool = True,
) -> VolumeChange:
    """Volume change (m^3), mean dh, mass change and the 1-sigma of each, by source.

    Parameters
    ----------
    diff : xarray.Dataset
        From :func:`terrain.difference` (``dh``, ``dh_std``, attrs).
    outline : shapely polygon(s)
        Glacier outline in the diff's CRS: cells whose centre is inside are summed.
    density : (float, float)
        Volume-to-mass conversion and its 1-sigma, kg m^-3 (Huss 2013: 850 +- 60).
    models : (TerrainGP, TerrainGP), optional
        The fitted GPs of *before* and *after* (exact): the GP route. Without them, the
        variogram of dh on stable ground (the cells outside ``outline``, or ``stable``).
    shared_offset_std : (float, float), optional
        1-sigma (m) of each survey's shared vertical offset; default: the diff's
        ``before_/after_shared_vertical_offset_std_m`` attributes (0 when absent).
    stable : boolean array of the diff's shape, optional
        Stable cells for the variogram (default: outside the outline).
    seed : int
        Seed of the variogram's pair subsample.
    along_track : AlongTrackModel or bool
        The along-track correlated error of each GP's samples (:mod:`terrain.along_track`):
        ``True`` the measured default model, ``False`` left out (stated in ``details``).
        Needs each sample's observation time, ``extra["t_s"]`` of the GP's samples (what
        ``select_landmarks`` and ``samples.csv`` carry); without it the term is stated as
        not available in ``details["along_track"]``, not taken as zero.

    Returns
    -------
    VolumeChange

    Raises
    ------
    InputError
        Density <= 0, an outline that covers no cell of the diff or reaches beyond it by
        more than :data:`terrain.outline_cover.OUTSIDE_MAX` of its area (clip it first:
        :func:`terrain.outline_cover.clip_outline`), too few stable cells for the variogram.
    """
    rho, rho_sd = _check_density(density)
    diff = north_up(diff)
    grid = Grid.from_dataarray(diff)
    W = outline_weights(grid, outline)
    inside = W > 0
    if not inside.any():
        raise bad_input(
            "outline",
            f"bounds {tuple(round(b, 1) for b in _bounds(outline))}",
            f"a polygon over cells of the change grid {tuple(round(b) for b in grid.bounds)}",
            "check the outline's CRS and extent",
        )
    cover = check_outline_covered(outline, grid)  # a volume of part of it: refused
    dh = np.asarray(diff["dh"].values, float)
    valid = inside & np.isfinite(dh)
    n_filled = int(inside.sum() - valid.sum())
    if not valid.any():
        raise bad_input("dh", "no finite dh inside the outline", "data on the glacier", "")
    # Cells inside without dh: the mean dh of their elevation band (McNabb et al. 2019),
    # counted in n_cells_filled, the fill's 1-sigma in the budget (terrain.void_fill).
    filled, fill = hypsometric_fill(dh, _band_elevation(diff), W, inside)
    area = float(W.sum())
    volume = float(np.sum(W[inside] * filled[inside]))
    mean_dh = volume / area
    std = (
        np.asarray(diff["dh_std"].values, float) if "dh_std" in diff else np.full(dh.shape, np.nan)
    )
    indep = float(np.sqrt(np.nansum((W * std)[inside] ** 2)))
    coreg = diff.attrs.get("coregistration", "none")
    co = json.loads(coreg) if coreg not in ("none", "", None) else None
    budget: dict[str, float] = {}
    details: dict[str, Any] = {"outline": cover}
    if models is not None:
        method = "gp_posterior"
        model = _along_track_model(along_track)
        details["along_track"] = {"model": None if model is None else model.to_dict()}
        for name, gp in zip(("before", "after"), models, strict=True):
            g = gp_integral(gp, grid, W, seed=seed)
            budget[f"gp_{name}"] = float(np.sqrt(g["posterior_var_m6"]))
            at = _along_track_term(gp, g, model)
            details["along_track"][name] = at
            if at["status"] == "included":
                budget[f"along_track_{name}"] = float(np.sqrt(max(at["variance_m6"], 0.0)))
            g = {k: v for k, v in g.items() if k not in ("sample_weights", "sample_index")}
            details[f"gp_{name}"] = g
            if co is None:
                s_o = _offset_std(diff, name, shared_offset_std)
                budget[f"shared_offset_{name}"] = abs(s_o * g["offset_response_m2"])
                details[f"shared_offset_{name}_std_m"] = s_o
    else:
        method = "variogram"
        st = (~inside if stable is None else np.asarray(stable, bool)) & np.isfinite(dh)
        xy = grid.xy().reshape(*grid.shape, 2)
        lags, gam, cnt = empirical_variogram(xy[st], dh[st], seed=seed)
        vario = fit_variogram(lags, gam, cnt)
        corr = covariance_sum(W, grid.resolution, vario.correlated_covariance)
        nug = vario.nugget * float(np.sum(W**2))
        budget["variogram_correlated"] = float(np.sqrt(max(corr, 0.0)))
        budget["variogram_nugget"] = float(np.sqrt(nug))
        details["variogram"] = vario.to_dict()
        details["stable_cells"] = int(st.sum())
    if co is not None:
        budget["coregistration_bias"] = float(co["vertical_bias_std_m"]) * area
    if n_filled:  # a filled cell's dh is unknown within its band's spread (void_fill)
        budget["filled_cells"] = fill["fill_std_m3"]
        details["void_fill"] = fill
    vol_sd = float(np.sqrt(sum(v**2 for v in budget.values())))
    mass = rho * volume
    mass_sd = float(np.hypot(rho * vol_sd, volume * rho_sd))
    details["method_note"] = (
        "GP posterior covariance integrated over the outline + shared survey offsets + "
        "along-track correlated error of the samples"
        if method == "gp_posterior"
        else "variogram of dh on stable ground (Rolstad 2009 / Hugonnet 2022), integrated over "
        "the outline: the fallback for DEMs without a known error model"
    )
    missing = [
        f"{k}: {v['status']}"
        for k, v in details.get("along_track", {}).items()
        if isinstance(v, dict) and "status" in v and v["status"] != "included"
    ]
    if missing:  # stated, never a silent zero
        details["method_note"] += "; along-track term NOT in the 1-sigma (" + "; ".join(missing)
        details["method_note"] += ")"
    return VolumeChange(
        volume_m3=volume,
        volume_std_m3=vol_sd,
        mean_dh_m=mean_dh,
        mean_dh_std_m=vol_sd / area,
        area_m2=area,
        mass_kg=mass,
        mass_std_kg=mass_sd,
        density_kg_m3=(rho, rho_sd),
        method=method,
        budget_m3=budget,
        independent_std_m3=indep,
        n_cells=int(inside.sum()),
        n_cells_filled=n_filled,
        details=details,
    )


def _band_elevation(diff: Any) -> np.ndarray:
    """The elevation a void's band is read from: the earlier surface, the later one where
    the earlier is a void too, NaN where neither is known."""
    shape = diff["dh"].shape
    z = [np.asarray(diff[k].values, float) for k in ("elevation_before", "elevation_after")
         if k in diff]  # fmt: skip
    if not z:
        return np.full(shape, np.nan)
    return z[0] if len(z) == 1 else np.where(np.isfinite(z[0]), z[0], z[1])


def _along_track_model(along_track: Any) -> AlongTrackModel | None:
    if along_track is True:
        return AlongTrackModel()
    if along_track is False or along_track is None:
        return None
    if not isinstance(along_track, AlongTrackModel):
        raise bad_input(
            "along_track", type(along_track).__name__, "True, False or an AlongTrackModel", ""
        )
    return along_track


def _along_track_term(gp: Any, g: dict[str, Any], model: AlongTrackModel | None) -> dict:
    """The along-track variance of one epoch's integral: ``u^T C u - sum u_i^2 s_i^2`` with
    ``u`` the estimator's sample weights, ``s_i^2 = fraction z_var_i`` and
    ``C_ij = s_i s_j exp(-|t_i - t_j| / tau)`` (:mod:`terrain.along_track`); the diagonal is
    already in the GP term (the GP's noise ``z_var``). A negative value (possible only with
    weights of mixed sign) is kept in ``variance_m6`` and counted as 0 in the budget."""
    if model is None:
        return {"status": "not included (along_track=False)"}
    extra = getattr(getattr(gp, "samples_", None), "extra", {}) or {}
    if "t_s" not in extra:
        return {
            "status": "not available: the samples carry no observation time (t_s): spot "
            "heights, GIS layers and point clouds, whose errors are independent, need none; "
            "a rover's samples.csv written by glacimap localize / process carries it (a "
            "rover's samples without it: re-export them with glacimap)"
        }
    idx = g["sample_index"]
    t = np.asarray(extra["t_s"], float)[idx]
    ok = np.isfinite(t)
    s = np.sqrt(model.fraction * np.asarray(gp.z_var_, float)[idx])
    u = g["sample_weights"]
    var = along_track_quadratic(u[ok], t[ok], s[ok], model.tau_s, off_diagonal=True)
    return {
        "status": "included",
        "variance_m6": float(var),
        "n_samples": int(ok.sum()),
        "n_without_time": int((~ok).sum()),  # counted: their along-track share is left out
        "independent_part_m6": float(np.sum((u[ok] * s[ok]) ** 2)),
    }


def _offset_std(diff: Any, name: str, given: tuple[float, float] | None) -> float:
    if given is not None:
        return positive_number(
            "shared_offset_std", given[0 if name == "before" else 1], "metres", allow_zero=True
        )
    return float(diff.attrs.get(f"{name}_shared_vertical_offset_std_m", 0.0))


def _bounds(outline: Any) -> tuple[float, ...]:
    try:
        from shapely.ops import unary_union

        return tuple(unary_union(list(getattr(outline, "geoms", [outline]))).bounds)
    except Exception:  # noqa: BLE001 - only for the message
        return (float("nan"),) * 4
