"""Hyperparameters of a given kernel by Eq 9: the log-parameter vector, L-BFGS-B restarts
and the exact log marginal likelihood (a mixin of :class:`terrain.gp.TerrainGP`).

A kernel *family* search (``kernel="auto"``) lives in :mod:`terrain.kernel_search`; the
geometric anisotropy it runs in, in :mod:`terrain.anisotropy`.
"""

from __future__ import annotations

from functools import partial

import numpy as np
from scipy.optimize import minimize
from threadpoolctl import threadpool_limits

from .anisotropy import select_anisotropy
from .errors import NumericalError, bad_input
from .kernel_search import candidate_names, median_spacing, select_kernel
from .kernels import Kernel, SquaredExponential
from .likelihood import gaussian_lml
from .linalg import one_blas_thread
from .tiled import largest_gap
from .unstated_noise import unstated_noise, window_noise

__all__ = ["HyperparameterMixin"]


class HyperparameterMixin:
    """Eq 9 and its maximization for a :class:`~terrain.gp.TerrainGP` with a given kernel."""

    def _fit_geometry(self, samples, resid, windows, nugget, gaps, rng):
        """Choose the kernel's geometric anisotropy on the fit subset
        (:func:`terrain.anisotropy.select_anisotropy`, ``rng`` its own child stream) and,
        when one is kept, move the samples and the windows into its coordinates. Returns
        ``(X, windows, widest_gap, spacing)`` in the kernel's coordinates, m (``gaps``: the
        isotropic ``(widest_gap, spacing)``, returned as they are when none is kept)."""
        X, idx = self.X_train_, self.fit_index_
        spacing = gaps[1]
        geometry, self.anisotropy_evidence_ = select_anisotropy(
            X[idx],
            resid[idx],
            self.z_var_[idx],
            fit_nugget=self.fit_nugget,
            nugget=nugget,
            nugget_bounds=self.nugget_bounds,
            spacing=spacing,
            rng=rng,
        )
        if geometry.isotropic:
            return X, windows, *gaps
        self.anisotropy_ = geometry
        X = self.X_train_ = self._kernel_xy(samples.xy)
        windows = None if windows is None else windows.transformed(geometry.matrix())
        self.window_plan_ = windows
        return X, windows, largest_gap(X, matrix=geometry.matrix()), median_spacing(X)

    def _search_kernel(self, X, resid, windows, nugget, widest, spacing, rng):
        """The kernel family by evidence on the fit subset (:func:`terrain.kernel_search.
        select_kernel`); where no sample states its noise, the nugget from the windows'
        dense lags and the chosen family refitted with it held (:mod:`terrain.
        unstated_noise`). Returns ``(kernel, nugget)``; sets the search's record."""
        idx = self.fit_index_
        search = partial(
            select_kernel,
            X[idx],
            resid[idx],
            self.z_var_[idx],
            nugget_bounds=self.nugget_bounds,
            spacing=spacing,
            widest_gap=widest,
        )
        names = candidate_names(self.kernel)
        choice = search(names, fit_nugget=self.fit_nugget, nugget=nugget, windows=windows, rng=rng)
        self.kernel_scores_, self.kernel_name_ = choice.scores, choice.name
        self.noise_estimate_ = None
        if unstated_noise(self.z_var_, windows, self.fit_nugget):
            lo, hi = self.nugget_bounds
            hi = max(min(hi, float(np.var(resid[idx]))), 10.0 * lo)  # noise below the signal's
            estimate = window_noise(windows, choice.kernel, (lo, hi))
            first = (repr(choice.kernel), choice.nugget)
            # the family refitted with the noise held: one candidate, nothing to rank
            choice = search((choice.name,), fit_nugget=False, nugget=estimate["nugget"],
                            windows=None, rng=rng.spawn(1)[0])  # fmt: skip
            self.noise_estimate_ = {
                "rule": "no sample states its noise: the nugget from the windows' evidence",
                "subset_kernel": first[0],
                "subset_nugget": first[1],
                **estimate,
            }
        selected = next(r for r in choice.scores if r["selected"])
        self._vecchia_lml = selected.get("refined_lml")
        return choice.kernel, choice.nugget

    # -- hyperparameter vector: log([kernel params..., nugget]) -----------------------------
    def _theta(self, kernel: Kernel, nugget: float) -> np.ndarray:
        theta = kernel.theta
        return np.append(theta, np.log(max(nugget, 1e-300))) if self.fit_nugget else theta

    def _unpack(self, theta: np.ndarray, kernel: Kernel) -> tuple[Kernel, float]:
        theta = np.asarray(theta, dtype=float)
        k = kernel.n_params
        if theta.shape != (k + self.fit_nugget,):
            raise bad_input(
                "theta",
                theta.shape,
                f"shape ({k + self.fit_nugget},): log of "
                f"{kernel.param_names + (['nugget'] if self.fit_nugget else [])}",
                "",
            )
        nugget = float(np.exp(theta[k])) if self.fit_nugget else float(self.nugget)
        return kernel.with_theta(theta[:k]), nugget

    def _bounds(self, kernel: Kernel) -> np.ndarray:
        b = kernel.bounds
        return np.vstack([b, np.log(self.nugget_bounds)]) if self.fit_nugget else b

    @staticmethod
    def _default_kernel(X: np.ndarray, resid: np.ndarray) -> Kernel:
        extent = float(np.ptp(X, axis=0).max()) or 1.0
        variance = float(np.var(resid)) or 1.0
        return SquaredExponential(variance=variance, lengthscale=max(extent / 10.0, 1.0))

    def _optimize(self, kernel, nugget, idx, rng) -> tuple[Kernel, float]:
        X, r, zv = self.X_train_[idx], self.y_resid_[idx], self.z_var_[idx]
        bounds = self._bounds(kernel)

        def objective(theta):
            try:
                lml, grad = self._lml(theta, kernel, X, r, zv, eval_gradient=True, strict=True)
            except NumericalError:
                return np.inf, np.zeros_like(theta)
            return -lml, -grad

        starts = [np.clip(self._theta(kernel, nugget), bounds[:, 0], bounds[:, 1])]
        starts += [rng.uniform(bounds[:, 0], bounds[:, 1]) for _ in range(int(self.n_restarts))]
        best = None
        for theta0 in starts:
            # Single-threaded BLAS for the many small factorizations: on this 2-core machine
            # OpenBLAS's threads made a Cholesky of n = 1000 take 494 ms instead of 23 ms
            # whenever the other core was busy (docs/terrain.md, Performance).
            with threadpool_limits(1):
                res = minimize(objective, theta0, jac=True, method="L-BFGS-B", bounds=bounds)
            self.optimizer_runs_.append(
                {
                    "start": theta0.tolist(),
                    "theta": res.x.tolist(),
                    "lml": float(-res.fun),
                    "success": bool(res.success),
                    "nit": int(res.nit),
                    "nfev": int(res.nfev),
                }
            )
            if np.isfinite(res.fun) and (best is None or res.fun < best.fun):
                best = res
        if best is None:
            raise NumericalError(
                "every optimizer start failed to factor the kernel matrix. Fix: set a larger "
                "nugget or narrower lengthscale_bounds."
            )
        return self._unpack(best.x, kernel)

    # -- Eq 9 -------------------------------------------------------------------------------
    @property
    def log_marginal_likelihood_value_(self) -> float:
        """Eq 9 at the fitted hyperparameters (nats). A tiled fit without a Vecchia value
        reports it on its fit subset, factored when first read: a cross-validation fold
        never reads it, and the 2,000-sample factor was a fifth of a fold's fit."""
        pending = self.__dict__.get("_lml_pending")
        if pending is not None:  # (theta, kernel, subset indices) from fit
            theta, kernel, idx = pending
            X, r, zv = self.X_train_[idx], self.y_resid_[idx], self.z_var_[idx]
            with one_blas_thread():  # as in fit: the same bits whatever the core count
                self._lml_value = self._lml(theta, kernel, X, r, zv, False)
            self._lml_pending = None
        try:
            return self.__dict__["_lml_value"]
        except KeyError:
            raise AttributeError("log_marginal_likelihood_value_ (not fitted)") from None

    @log_marginal_likelihood_value_.setter
    def log_marginal_likelihood_value_(self, value: float) -> None:
        self._lml_value, self._lml_pending = value, None

    def _defer_lml(self, theta: np.ndarray, kernel: Kernel, idx: np.ndarray) -> None:
        """Eq 9 on the samples ``idx`` at ``theta``, computed when first read."""
        self._lml_value, self._lml_pending = None, (theta, kernel, idx)

    def _lml(self, theta, kernel, X, r, z_var, eval_gradient, strict=False):
        k, nugget = self._unpack(theta, kernel)
        return gaussian_lml(
            k, X, r, z_var + nugget, eval_gradient, strict, nugget if self.fit_nugget else None
        )

    def log_marginal_likelihood(
        self, theta: np.ndarray | None = None, eval_gradient: bool = False
    ) -> float | tuple[float, np.ndarray]:
        """Log marginal likelihood (Eq 9) on all fitted samples.

        Parameters
        ----------
        theta : ndarray, optional
            ``log([variance, lengthscale..., nugget])`` (nugget only when it is fitted);
            default: the fitted values.
        eval_gradient : bool
            Also return the analytic gradient with respect to ``theta`` (R&W Eq 5.9).
        """
        self._check_fitted()
        if theta is None:
            theta = self._theta(self.kernel_, self.nugget_)
            if not eval_gradient:
                return self.log_marginal_likelihood_value_
        return self._lml(
            theta, self.kernel_, self.X_train_, self.y_resid_, self.z_var_, eval_gradient
        )
