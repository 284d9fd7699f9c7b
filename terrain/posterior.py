"""Bayesian GP hyperparameters with emcee: a posterior instead of one plug-in estimate.

The model is TerrainGP's, ``z_i = a + b m(x_i) + f(x_i) + e_i`` with ``f ~ GP(0, k)`` and
``e_i ~ N(0, z_var_i + nugget)``. :func:`sample_hyperparameters` draws the joint posterior of
the kernel's log-parameters, the log-nugget and the mean's offset ``a`` / scale ``b`` with
emcee's affine-invariant ensemble; :meth:`HyperPosterior.predict_grid` averages the GP over
posterior draws, so the map's uncertainty includes the hyperparameters' uncertainty.

Sampled coordinates and weakly informative priors (each a Normal on the sampled coordinate;
``r = z - m(x)`` on the fit subset, or ``z - mean(z)`` without a mean function; ``E`` the
largest side of the data's bounding box; the offset centres on the number when ``mean`` is
one):

================  ==========  ====================================  =========================
parameter         sampled as  prior centre                          prior sd
================  ==========  ====================================  =========================
``variance``      log(m^2)    log var(r)                            2
``lengthscale*``  log(m)      log(E / 10)                           1.5
``nugget``        log(m^2)    log(median z_var + 1e-4)              3
``offset`` (a)    m           mean(z - m(x)), mean(z), or the number abs(mean m) + 10 std(z) + 1
``scale`` (b)     1           1 (only with a mean function)         0.5
================  ==========  ====================================  =========================

For a :class:`SumKernel` each part's variance and length scale priors centre on that part's
initial value instead (this breaks the parts' symmetry). Kernel bounds are hard limits
(log-probability ``-inf`` outside), as are nugget bounds of 1e-8..1e4 m^2.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from numbers import Real
from typing import Any

import numpy as np
from scipy.linalg import LinAlgError, cho_factor, cho_solve
from scipy.optimize import minimize

from .errors import bad_input
from .linalg import one_blas_thread
from .prior import as_mean_function
from .samples import ElevationSamples

__all__ = ["HyperPosterior", "ShortChainWarning", "mixture_mean_std", "sample_hyperparameters"]

_LOG_2PI = np.log(2.0 * np.pi)
NUGGET_BOUNDS = (1e-8, 1e4)  # m^2, hard limits of the sampled nugget
MIN_TAU_MULTIPLE = 50  # a chain shorter than 50 integrated autocorrelation times warns


class ShortChainWarning(RuntimeWarning):
    """The kept chain is shorter than 50 integrated autocorrelation times."""


class _AffineMean:
    """``a + b m(x)`` (m) as a plain callable for TerrainGP; ``m=None`` means ``a``."""

    def __init__(self, a: float, b: float, m: Any) -> None:
        self.a, self.b, self.m = float(a), float(b), m
        self.crs = getattr(m, "crs", None)

    def __call__(self, xy: np.ndarray) -> np.ndarray:
        if self.m is None:
            return np.full(len(xy), self.a)
        return self.a + self.b * np.asarray(self.m(xy), dtype=float)

    def __repr__(self) -> str:
        return f"{self.a:.4g}" if self.m is None else f"{self.a:.4g} + {self.b:.4g} * {self.m!r}"


def mixture_mean_std(means: np.ndarray, stds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Equal-weight Gaussian mixture moments over axis 0 (law of total variance).

    ``mean = E[mu_k]``, ``std = sqrt(E[sigma_k^2] + Var[mu_k])`` (population variance).
    ``means``, ``stds``: shape (k, ...) in metres; returns two arrays of shape (...).
    """
    means, stds = np.asarray(means, dtype=float), np.asarray(stds, dtype=float)
    mean = means.mean(axis=0)
    return mean, np.sqrt((stds**2).mean(axis=0) + ((means - mean) ** 2).mean(axis=0))


def _thin(samples: ElevationSamples, max_samples: int, bin_size: float | None, rng):
    """Fit subset: optional inverse-variance binning, then a seeded random choice."""
    xy, z, zv = samples.xy, samples.z, np.asarray(samples.z_var, dtype=float)
    if bin_size:
        key = np.floor((xy - xy.min(axis=0)) / float(bin_size)).astype(np.int64)
        _, inv = np.unique(key, axis=0, return_inverse=True)
        inv = inv.ravel()
        w = 1.0 / (zv + 1e-12)  # exact (z_var = 0) samples dominate their bin
        ws = np.bincount(inv, weights=w)
        xy = np.column_stack([np.bincount(inv, weights=w * xy[:, i]) / ws for i in (0, 1)])
        z, zv = np.bincount(inv, weights=w * z) / ws, 1.0 / ws
    if len(z) > max_samples:
        keep = np.sort(rng.choice(len(z), size=max_samples, replace=False))
        xy, z, zv = xy[keep], z[keep], zv[keep]
    return xy, z, zv


class _LogPosterior:
    """Log-posterior of the sampled vector ``[log kernel theta, log nugget, a, (b)]``."""

    def __init__(self, kernel, X, z, zv, mX, mu, sd, bounds) -> None:
        self.kernel, self.X, self.z, self.zv, self.mX = kernel, X, z, zv, mX
        self.mu, self.sd, self.bounds, self.k = mu, sd, bounds, kernel.n_params

    def __call__(self, p: np.ndarray) -> float:
        p = np.asarray(p, dtype=float)
        if not np.all(np.isfinite(p)) or np.any((p < self.bounds[:, 0]) | (p > self.bounds[:, 1])):
            return -np.inf
        lp = -0.5 * np.sum(((p - self.mu) / self.sd) ** 2)
        K = self.kernel.with_theta(p[: self.k])(self.X)
        K[np.diag_indices_from(K)] += self.zv + np.exp(p[self.k])
        b = p[self.k + 2] if self.mX is not None else 0.0
        r = self.z - p[self.k + 1] - (b * self.mX if self.mX is not None else 0.0)
        try:
            c = cho_factor(K, lower=True, overwrite_a=True, check_finite=False)
        except (LinAlgError, ValueError):
            return -np.inf
        # Eq 9 / R&W Alg. 2.1 line 8: -1/2 r^T K^-1 r - sum log L_ii - n/2 log 2 pi
        lml = -0.5 * r @ cho_solve(c, r, check_finite=False) - np.log(np.diag(c[0])).sum()
        return float(lp + lml - 0.5 * r.size * _LOG_2PI)


@dataclass(frozen=True)
class HyperPosterior:
    """Posterior draws of GP hyperparameters (from :func:`sample_hyperparameters`).

    Attributes
    ----------
    chain : ndarray of shape (n_kept_steps, n_walkers, p)
        Kept draws in sampled coordinates (log for variance, length scales and nugget).
    log_prob : ndarray of shape (n_kept_steps, n_walkers)
        Log-posterior of each draw (up to a constant).
    param_names : list of str
        Kernel parameter names, then ``"nugget"``, ``"offset"`` and (with a mean) ``"scale"``.
    log_params : ndarray of bool, shape (p,)
        Which coordinates are logs of the natural value.
    tau, ess : ndarray of shape (p,), float
        Integrated autocorrelation time per parameter (steps); ``n_walkers * n_kept / max tau``.
    acceptance_fraction, seconds, seed : ndarray (n_walkers,), float (s, whole call), int
    kernel, mean_function, priors
        Kernel template (``with_theta``), fitted base mean ``m`` (None: offset only), and the
        priors used, ``name -> (centre, sd)`` in sampled coordinates.
    n_fit_samples, burn : int
        Samples in the likelihood subset; steps discarded as burn-in.
    """

    chain: np.ndarray
    log_prob: np.ndarray
    param_names: list[str]
    log_params: np.ndarray
    tau: np.ndarray
    ess: float
    acceptance_fraction: np.ndarray
    seconds: float
    seed: int
    kernel: Any = field(repr=False)
    mean_function: Any = field(repr=False)
    priors: dict[str, tuple[float, float]]
    n_fit_samples: int
    burn: int

    def natural(self, theta: np.ndarray) -> np.ndarray:
        """Sampled coordinates (..., p) -> natural units (m^2, m, m^2, m, 1)."""
        out = np.array(theta, dtype=float)
        out[..., self.log_params] = np.exp(out[..., self.log_params])
        return out

    def summary(self) -> dict[str, Any]:
        """JSON-ready: per parameter the median and 68 % interval (16th, 84th percentiles)."""
        flat = self.natural(self.chain.reshape(-1, self.chain.shape[-1]))
        q = np.percentile(flat, [16, 50, 84], axis=0)
        params = {
            n: {"median": float(q[1, i]), "p16": float(q[0, i]), "p84": float(q[2, i])}
            for i, n in enumerate(self.param_names)
        }
        return {
            "parameters": params,
            "tau": dict(zip(self.param_names, self.tau.tolist(), strict=True)),
            "ess": float(self.ess),
            "acceptance_fraction": float(np.mean(self.acceptance_fraction)),
            "n_walkers": int(self.chain.shape[1]),
            "n_kept_steps": int(self.chain.shape[0]),
            "burn": self.burn,
            "n_fit_samples": self.n_fit_samples,
            "seconds": float(self.seconds),
            "seed": int(self.seed),
        }

    def draws(self, n: int, seed: int = 0) -> np.ndarray:
        """``n`` draws (n, p), sampled coordinates, stratified over the flattened chain."""
        flat = self.chain.reshape(-1, self.chain.shape[-1])
        if not 1 <= int(n) <= len(flat):
            raise bad_input("n_draws", n, f"1..{len(flat)} draws", "ask for fewer draws")
        u = np.random.default_rng(seed).uniform(size=int(n))
        return flat[((np.arange(int(n)) + u) * len(flat) / int(n)).astype(int)]

    def gp(self, theta: np.ndarray, samples: ElevationSamples, **gp_kwargs: Any):
        """A TerrainGP fitted on ``samples`` with hyperparameters fixed at ``theta`` (p,)."""
        from .gp import TerrainGP

        k = self.kernel.n_params
        b = theta[k + 2] if self.mean_function is not None else 0.0
        gp_kwargs.setdefault("seed", self.seed)
        return TerrainGP(
            kernel=self.kernel.with_theta(theta[:k]),
            mean=_AffineMean(theta[k + 1], b, self.mean_function),
            nugget=float(np.exp(theta[k])),
            nugget_bounds="fixed",
            optimize=False,
            **gp_kwargs,
        ).fit(samples)

    def predict_grid(self, samples: ElevationSamples, grid, n_draws: int = 16, **gp_kwargs: Any):
        """Posterior-averaged map: a GP per draw on all samples, combined as a mixture.

        ``samples``: all of them (not only the likelihood subset); ``grid``: cells to predict;
        ``n_draws``: posterior draws (:meth:`draws`, this posterior's seed); ``gp_kwargs`` go
        to :class:`TerrainGP` (e.g. ``method="exact"``). Returns an ``xarray.Dataset``:
        ``elevation`` (mixture mean) and ``elevation_std`` (law of total variance), metres,
        dims (y, x); ``attrs`` record method, n_draws, seed and the posterior summary.
        """
        import json

        means, stds = [], []
        for theta in self.draws(n_draws, self.seed):
            ds = self.gp(theta, samples, **gp_kwargs).predict_grid(grid)
            means.append(ds["elevation"].values)
            stds.append(ds["elevation_std"].values)
        mean, std = mixture_mean_std(np.stack(means), np.stack(stds))
        ds["elevation"].values, ds["elevation_std"].values = mean, std
        for key in ("log_marginal_likelihood", "jitter"):  # the last draw's, not the mixture's
            ds.attrs.pop(key, None)
        ds.attrs.update(
            method="posterior-averaged GP (emcee)",
            kernel=f"{self.kernel!r} (initial; hyperparameters drawn)",
            mean_function="a" if self.mean_function is None else f"a + b * {self.mean_function!r}",
            n_draws=int(n_draws),
            n_fit_samples=int(self.n_fit_samples),  # the likelihood subset of the posterior
            seed=int(self.seed),
            hyperparameters=json.dumps(self.summary()["parameters"]),
        )
        return ds


def _priors(kernel, X, z, zv, mX, has_b, override) -> dict[str, tuple[float, float]]:
    r = z - (mX if mX is not None else z.mean())
    extent = float(np.ptp(X, axis=0).max()) or 1.0
    out: dict[str, tuple[float, float]] = {}
    parts = getattr(kernel, "parts", None)
    for i, name in enumerate(kernel.param_names):
        if parts is not None:  # SumKernel: centre each part on its initial value
            out[name] = (float(kernel.theta[i]), 2.0 if name.endswith("variance") else 1.5)
        elif name == "variance":
            out[name] = (float(np.log(max(np.var(r), 1e-6))), 2.0)
        else:
            out[name] = (float(np.log(extent / 10.0)), 1.5)
    out["nugget"] = (float(np.log(np.median(zv) + 1e-4)), 3.0)
    m_abs = abs(float(np.mean(mX))) if mX is not None else 0.0
    a0 = float(np.mean(z - mX)) if mX is not None else float(np.mean(z))
    out["offset"] = (a0, m_abs + 10.0 * float(np.std(z)) + 1.0)
    if has_b:
        out["scale"] = (1.0, 0.5)
    for name, spec in (override or {}).items():
        if name not in out:
            raise bad_input("priors", name, f"one of {list(out)}", "check the parameter name")
        mu, sd = (float(v) for v in spec)
        if not (np.isfinite(mu) and np.isfinite(sd) and sd > 0):
            raise bad_input(f"priors[{name!r}]", spec, "(centre, sd > 0), finite", "")
        out[name] = (mu, sd)
    return out


def sample_hyperparameters(
    samples: ElevationSamples,
    kernel,
    mean: Any = None,
    *,
    n_walkers: int = 32,
    n_steps: int = 2000,
    burn: int | None = None,
    max_samples: int = 500,
    bin_size: float | None = None,
    priors: dict[str, tuple[float, float]] | None = None,
    moves: Any = None,
    seed: int = 0,
) -> HyperPosterior:
    """Sample the GP hyperparameter posterior with emcee (affine-invariant ensemble).

    Parameters
    ----------
    samples : ElevationSamples
        Data; the likelihood uses a subset of at most ``max_samples`` of them.
    kernel : Kernel or SumKernel
        Kernel family, bounds and starting values (e.g. ``Matern(10.0, 50.0, nu=2.5)``).
    mean : None, "constant", number, xarray.DataArray or callable
        Base mean ``m``: a DEM DataArray becomes a :class:`TriangulatedMean`; the mean is then
        ``a + b m(x)`` with ``a`` (m) and ``b`` (1) sampled. None, "constant" or a number:
        constant mean ``a`` only.
    n_walkers : int
        Walkers, at least twice the number of parameters ``p``.
    n_steps : int
        Steps per walker, including ``burn``.
    burn : int, optional
        Steps discarded at the start; default ``n_steps // 4``. Walkers start in a small
        seeded ball (0.01 prior sd) around the maximum a posteriori point (Powell search).
    max_samples : int
        Size cap of the likelihood subset (exact Eq 9 costs O(max_samples^3) per step).
    bin_size : float, optional
        If given, samples are first merged per square bin of this side (m): inverse-variance
        weighted mean at the weighted centroid, variance ``1 / sum(1 / z_var)``. Then, if
        still more than ``max_samples``, a seeded random subset without replacement (the
        default thinning: the likelihood of a random subset is exact and unbiased, whereas
        bins comparable to the length scale push within-bin relief into the nugget).
    priors : dict, optional
        ``name -> (centre, sd)`` of a Normal on the sampled coordinate (log for variance,
        length scales and nugget), overriding the module table's defaults.
    moves : emcee move(s), optional
        Passed to ``emcee.EnsembleSampler``. Default: differential evolution (0.8) plus DE
        snooker (0.2); on the benchmark site its autocorrelation time is about half the
        stretch move's (12 vs 21 steps), for the same cost per step.
    seed : int
        Seeds the subset, the starting ball and emcee's moves: same seed, same chain.

    Returns
    -------
    HyperPosterior

    Warns
    -----
    ShortChainWarning
        When the kept chain is shorter than 50 integrated autocorrelation times.
    """
    import warnings

    import emcee

    burn = int(n_steps) // 4 if burn is None else int(burn)
    for field_, value, ok, expected in (
        ("samples", samples, isinstance(samples, ElevationSamples) and samples.n >= 3,
         "ElevationSamples with >= 3 samples"),
        ("max_samples", max_samples, int(max_samples) >= 3, ">= 3, e.g. 500"),
        ("n_steps", n_steps, int(n_steps) >= 1, ">= 1 step per walker, e.g. 2000"),
        ("burn", burn, 0 <= burn < int(n_steps), f"0 <= burn < n_steps ({n_steps})"),
        ("bin_size", bin_size, bin_size is None or (np.isfinite(bin_size) and bin_size > 0),
         "a positive bin side in metres or None"),
    ):  # fmt: skip
        if not ok:
            raise bad_input(field_, value, expected, "see sample_hyperparameters' docstring")
    t0 = time.perf_counter()
    rng = np.random.default_rng(seed)
    samples = samples.by_position()  # the subset's draw is over indices: any row order
    number = isinstance(mean, Real) and not isinstance(mean, bool)
    const = number or mean is None or (isinstance(mean, str) and mean.lower() == "constant")
    base = None if const else as_mean_function(mean)
    if hasattr(base, "fit"):
        base = base.fit(samples.xy, samples.z)
    xy, z, zv = _thin(samples, int(max_samples), bin_size, rng)
    X = xy - xy.mean(axis=0)
    mX = None if base is None else np.asarray(base(xy), dtype=float)
    prior = _priors(kernel, X, z, zv, mX, base is not None, priors)
    if number and "offset" not in (priors or {}):
        prior["offset"] = (float(mean), prior["offset"][1])
    names = list(prior)
    p = len(names)
    if int(n_walkers) < 2 * p:
        raise bad_input("n_walkers", n_walkers, f">= 2 * {p} parameters", f"n_walkers={4 * p}")
    mu, sd = (np.array([prior[n][i] for n in names]) for i in (0, 1))
    bounds = np.vstack(
        [kernel.bounds, np.log(NUGGET_BOUNDS), [[-np.inf, np.inf]] * (p - 1 - kernel.n_params)]
    )
    logpost = _LogPosterior(kernel, X, z, zv, mX, mu, sd, bounds)

    start = np.concatenate([kernel.theta, mu[kernel.n_params :]])
    start = np.clip(start, bounds[:, 0], bounds[:, 1])

    def objective(v: np.ndarray) -> float:
        lp = logpost(v * sd)
        return -lp if np.isfinite(lp) else 1e300

    with one_blas_thread():
        res = minimize(objective, start / sd, method="Powell")
    best = res.x * sd if np.isfinite(logpost(res.x * sd)) else start
    p0 = np.empty((int(n_walkers), p))
    for w in range(int(n_walkers)):
        step = rng.normal(size=p) * 0.01 * sd
        for _ in range(30):
            if np.isfinite(logpost(best + step)):
                break
            step *= 0.5
        p0[w] = best + step
    if moves is None:
        moves = [(emcee.moves.DEMove(), 0.8), (emcee.moves.DESnookerMove(), 0.2)]
    sampler = emcee.EnsembleSampler(int(n_walkers), p, logpost, moves=moves)
    sampler.random_state = np.random.RandomState(seed).get_state()
    with one_blas_thread():
        sampler.run_mcmc(p0, int(n_steps), progress=False)
    chain = sampler.get_chain(discard=burn)
    tau = emcee.autocorr.integrated_time(chain, tol=0, quiet=True)
    n_kept = chain.shape[0]
    ess = float(int(n_walkers) * n_kept / np.max(tau))
    need = MIN_TAU_MULTIPLE * float(np.max(tau))
    if n_kept < need:
        warnings.warn(
            ShortChainWarning(
                f"kept chain of {n_kept} steps is shorter than {MIN_TAU_MULTIPLE} integrated "
                f"autocorrelation times ({need:.0f} steps, tau = {np.max(tau):.1f} for "
                f"{names[int(np.argmax(tau))]}); tau and ESS ({ess:.0f}) are unreliable. Fix: "
                f"run n_steps >= {int(np.ceil(need)) + burn}."
            ),
            stacklevel=2,
        )
    return HyperPosterior(
        chain=chain,
        log_prob=sampler.get_log_prob(discard=burn),
        param_names=names,
        log_params=np.array([i <= kernel.n_params for i in range(p)]),
        tau=np.asarray(tau, dtype=float),
        ess=ess,
        acceptance_fraction=np.asarray(sampler.acceptance_fraction),
        seconds=time.perf_counter() - t0,
        seed=int(seed),
        kernel=kernel,
        mean_function=base,
        priors=prior,
        n_fit_samples=int(z.size),
        burn=burn,
    )
