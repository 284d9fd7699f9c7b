"""TerrainGP: Gaussian-process terrain reconstruction with per-point noise and a prior mean.

Model (paper Section II): ``z_i = m(x_i) + f(x_i) + e_i`` with ``f ~ GP(0, k)`` (Eq 1 or a
Matérn kernel), ``e_i ~ N(0, sigma_i^2 + nugget)`` (Eq 6: each sample's own elevation variance,
plus an optional fitted nugget for noise the samples do not state), and ``m`` a prior mean: a
constant, a triangulated satellite DEM (Section II-C), or any callable.

The posterior follows Rasmussen & Williams, Algorithm 2.1 — not the paper's Eq 4-5, whose
subscripts are swapped (docs/architecture.md §5). The estimator has scikit-learn's shape: the
constructor stores settings, ``fit`` validates and factors ``K`` once, every ``predict`` reuses
the factor, no explicit inverse is formed for prediction, and the variance diagonal is computed
chunk by chunk without the (m, m) posterior covariance.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
from scipy.linalg import cho_solve, solve_triangular

from .anisotropy import Anisotropy
from .breakline_evidence import gls_mean
from .coarse_variance import predict_checked_lattice, variance_step
from .errors import NotFittedError, bad_input
from .exact_predict import predict_exact
from .gp_hyper import HyperparameterMixin
from .gp_mean import bind_mean, gls_subset, n_coef
from .gp_settings import check_samples, check_settings
from .grid import Grid, check_same_crs
from .kernel_search import median_spacing, warn_if_degenerate
from .kernels import Kernel
from .linalg import cholesky_jitter, single_blas_thread
from .long_halo import predict_long_halo
from .microscale import microscale_part, windowed_part
from .prior import as_mean_function
from .product import gp_provenance, terrain_dataset
from .samples import ElevationSamples
from .tiled import (
    TileSpec,
    default_tiles,
    largest_gap,
    long_scale_part,
    predict_tiled,
    warn_long_scale,
)
from .window_evidence import WindowPlan

__all__ = ["TerrainGP"]

_LOG_2PI = np.log(2.0 * np.pi)
#: Above n^2 * m multiply-adds (~2 s here) "auto" predicts the variance on a lattice or tiled.
EXACT_PREDICT_FLOPS = 4e10
#: From this many samples ``local_amplitude="auto"`` turns per-tile amplitudes on (and
#: ``method="auto"`` tiles): measured on nine real DEMs at 3,000 samples (docs/terrain.md
#: "Local amplitude from 1,000 samples").
AMPLITUDE_MIN_SAMPLES = 1000


class TerrainGP(HyperparameterMixin):
    """Exact GP regression of elevation on (easting, northing).

    Parameters
    ----------
    kernel : "auto", family name(s), Kernel or None
        Covariance of the terrain deviation from the mean. ``"auto"`` (default) fits the
        family SE (Eq 1), Matérn 3/2, 5/2, 7/2 and their two-scale sums on the fit subset
        and keeps the best penalised evidence (BIC of Eq 9, :mod:`terrain.kernel_search`)
        with the evidence of the samples the subset left out, in windows
        (:mod:`terrain.window_evidence`);
        a family name or a list of names restricts the search; a Kernel object is fitted
        from its initial hyperparameters and bounds; ``None``: ``SquaredExponential``
        started at the residual variance and a tenth of the data extent.
    mean : "constant", float, xarray.DataArray or callable
        Prior mean: ``"constant"`` is the mean of the observations (the paper's landmark-only
        GP); a coarse DEM ``DataArray`` becomes a :class:`TriangulatedMean` (the paper's
        satellite prior); a callable maps xy (n, 2) to z (n,).
    nugget : float
        Extra noise variance in m^2 added to every sample's own ``z_var`` (Eq 6).
    nugget_bounds : tuple of float or "fixed"
        Search bounds for the nugget; ``"fixed"`` keeps ``nugget`` as given (may be 0).
    optimize : bool
        Fit hyperparameters by maximizing the log marginal likelihood (Eq 9) with L-BFGS-B
        on log-parameters.
    n_restarts : int
        Extra optimizer starts drawn uniformly in the log-bounds from the seeded generator.
    max_fit_samples : int or None
        Hyperparameters are fitted on at most this many samples, drawn at random (seeded,
        without replacement); the posterior always uses every sample.
    chunk_size : int or None
        Query points per prediction chunk; default keeps each (chunk, n) block near 128 MB.
    seed : int
        Seed of the one ``numpy.random.Generator`` (restarts, fit subset); in every product.
    method : {"auto", "exact", "tiled"}
        ``"auto"``: exact up to ``exact_max_samples`` samples (3x with a long-scale kernel
        part), tiled above (:mod:`terrain.tiled`), and tiled from 1,000 samples when
        ``local_amplitude="auto"`` turns amplitudes on; a big grid gets the exact mean and the
        variance on a lattice (:mod:`terrain.coarse_variance`), from tiles (tileable), or
        from tiles sized by the kernel's long part (:mod:`terrain.long_halo`).
    tiles : TileSpec, optional
        Tile geometry of the tiled GP; default scaled to the shortest length scale.
    local_amplitude : bool or "auto"
        Each tile scales the kernel by its own MAP amplitude (Eq 9 on its samples,
        :func:`terrain.tiled.local_amplitude`) for terrain whose roughness varies; length
        scales and noise stay global. ``"auto"`` (default): on from
        :data:`AMPLITUDE_MIN_SAMPLES` (1,000) samples with ``method="auto"``, which then
        tiles, provided the tiles hold any long-scale kernel part (the survey's widest gap,
        :func:`terrain.tiled.largest_gap`, within the halo); also on whenever the fit tiles
        anyway. Below 1,000 samples, or asked for ``method="exact"``, the exact stationary GP
        (the reference). Measured on nine real DEMs at 1,000, 3,000 and 50,000 samples and
        the synthetic site (docs/terrain.md "Local amplitude from 1,000 samples").
        ``True``: always (``method="auto"`` then always tiles, ``"exact"`` is rejected);
        ``False``: never.
    amplitude_prior_sd : float
        Prior sd of a tile's log amplitude around the global fit (1.0: a factor e).
    anisotropy : None, Anisotropy or "auto"
        Ground smoother along one azimuth (:mod:`terrain.anisotropy`): ``None`` (default)
        isotropic; an :class:`Anisotropy` (e.g. a glacier's flow) used in every fit;
        ``"auto"`` chosen with a kernel search by BIC. Not the default: on real DEMs surveyed
        along tracks it made 4 of 22 maps 3-5 % worse (docs/terrain.md "Anisotropic ground").

    Attributes
    ----------
    kernel_ : Kernel
        Kernel with the fitted hyperparameters.
    anisotropy_ : Anisotropy
        The geometry of the kernel: length scales of ``kernel_`` are across the grain,
        ``ratio`` times longer along ``azimuth_deg`` (isotropic: ratio 1).
    nugget_ : float
        Fitted (or fixed) nugget, m^2; the lower bound of ``nugget_bounds`` when the fitted
        one became ``microscale_`` (or the window evidence gave it no weight).
    window_plan_ : terrain.window_evidence.WindowPlan or None
        The left-out samples' windows that scored the candidates; ``None`` without any.
    microscale_ : terrain.microscale.Microscale, SumKernel of them, or None
        A nugget fitted on top of stated noise, kept in the 1-sigma as ground below the fit
        subset's spacing (parts of ``kernel_``; averaged over its lengths and none by the
        left-out samples' window evidence: :func:`terrain.microscale.windowed_part`);
        ``None`` without one.
    noise_estimate_ : dict or None
        Where no sample states its noise: the nugget the dense windows measured, beside the
        subset's (:mod:`terrain.unstated_noise`); ``None`` otherwise.
    samples_ : ElevationSamples
        The samples fitted, in order of position (easting, then northing); every per-sample
        array of the fit (``alpha_``, :func:`terrain.gp_integral`'s weights) is in this order.
    sample_order_ : ndarray of int, shape (n,)
        The caller's row of each row of ``samples_`` (``samples.subset(sample_order_)``).
    mean_ : callable
        The fitted prior mean function.
    L_ : ndarray of shape (n, n)
        Lower Cholesky factor of ``K + diag(z_var + nugget)``.
    alpha_ : ndarray of shape (n,)
        ``(K + Sigma)^{-1} (z - m(X))`` (R&W Alg. 2.1 line 3).
    log_marginal_likelihood_value_ : float
        Eq 9 at the fitted hyperparameters, on all samples.
    jitter_ : float
        Diagonal jitter that the final factorization needed (0 when none).
    method_ : {"exact", "tiled"}
        The GP the fit chose.
    local_amplitude_ : bool
        Whether the tiles scale the kernel by their own amplitude.
    """

    def __init__(
        self,
        kernel: Kernel | str | list[str] | None = "auto",
        mean: Any = "constant",
        nugget: float = 1e-2,
        nugget_bounds: tuple[float, float] | str = (1e-6, 1e2),
        optimize: bool = True,
        n_restarts: int = 2,
        max_fit_samples: int | None = 2000,
        chunk_size: int | None = None,
        seed: int = 0,
        method: str = "auto",
        tiles: TileSpec | None = None,
        exact_max_samples: int = 4000,
        local_amplitude: bool | str = "auto",
        amplitude_prior_sd: float = 1.0,
        anisotropy: Anisotropy | str | None = None,
    ) -> None:
        self.kernel = kernel
        self.mean = mean
        self.nugget = nugget
        self.nugget_bounds = nugget_bounds
        self.optimize = optimize
        self.n_restarts = n_restarts
        self.max_fit_samples = max_fit_samples
        self.chunk_size = chunk_size
        self.seed = seed
        self.method = method
        self.tiles = tiles
        self.exact_max_samples = exact_max_samples
        self.local_amplitude = local_amplitude
        self.amplitude_prior_sd = amplitude_prior_sd
        self.anisotropy = anisotropy

    # -- settings ---------------------------------------------------------------------------
    def _check_settings(self) -> None:
        check_settings(self)  # terrain/gp_settings.py

    @property
    def _amplitude_always(self) -> bool:
        """``local_amplitude=True``: per-tile amplitudes whatever the sample count."""
        return not isinstance(self.local_amplitude, str) and bool(self.local_amplitude)

    @property
    def _searches_kernel(self) -> bool:
        """A kernel search: ``"auto"`` or family names (``"auto"`` without ``optimize``
        keeps the unfitted default SE instead)."""
        if self.kernel == "auto" and not self.optimize:
            return False
        return isinstance(self.kernel, str | list | tuple)

    @property
    def fit_nugget(self) -> bool:
        return not isinstance(self.nugget_bounds, str)

    # -- fit ------------------------------------------------------------------------------
    @single_blas_thread
    def fit(self, samples: ElevationSamples) -> TerrainGP:
        """Fit hyperparameters (optional) and factor the kernel matrix once.

        Parameters
        ----------
        samples : ElevationSamples
            At least 3 samples; their CRS must match the prior mean's, if both have one.
        """
        self._check_settings()
        check_samples(samples)  # terrain/gp_settings.py
        t0 = time.perf_counter()
        # Every draw below is over the samples' indices: in order of position, the same
        # survey in any row order gives the same map (docs/terrain.md, session 46).
        self.sample_order_ = samples.position_order()
        samples = samples.by_position()
        rng = np.random.default_rng(self.seed)
        mean = bind_mean(as_mean_function(self.mean), samples.crs, samples.xy)
        check_same_crs(getattr(mean, "crs", None), samples.crs, "mean", "samples")
        if hasattr(mean, "fit"):  # a linear mean starts from least squares, then GLS below
            mean = mean.fit(samples.xy, samples.z)
        self.mean_ = mean
        self.crs_ = samples.crs
        self.samples_ = samples
        self.X_offset_ = samples.xy.mean(axis=0)  # centred coordinates: exact cdist digits
        given = self.anisotropy if isinstance(self.anisotropy, Anisotropy) else Anisotropy()
        self.anisotropy_ = given  # the kernel's coordinates: X = A (xy - offset)
        X = self._kernel_xy(samples.xy)
        resid = samples.z - np.asarray(mean(samples.xy), dtype=float)
        self.X_train_, self.y_resid_, self.z_var_ = X, resid, np.asarray(samples.z_var)

        nugget = float(self.nugget)
        self.fit_index_ = np.arange(samples.n)
        self.optimizer_runs_ = []
        self.kernel_scores_ = []
        self.noise_estimate_ = None  # set where no sample states its noise (gp_hyper.py)
        self.window_plan_ = None
        self.anisotropy_evidence_ = None
        if self.optimize and self.max_fit_samples is not None and samples.n > self.max_fit_samples:
            self.fit_index_ = np.sort(
                rng.choice(samples.n, size=int(self.max_fit_samples), replace=False)
            )
        widest = largest_gap(X, matrix=self.anisotropy_.kernel_matrix)  # widest gap, m
        spacing = median_spacing(X) if samples.n < 200_000 else None
        if self._searches_kernel:
            idx = self.fit_index_
            # The samples the subset leaves out score each candidate in windows (their own
            # generator, spawned: the main stream and every other draw stay as they were).
            windows = WindowPlan.build(X, resid, self.z_var_, idx, rng.spawn(1)[0])
            self.window_plan_ = windows
            spacing = median_spacing(X) if spacing is None else spacing
            if self.anisotropy == "auto":  # the search then runs in the kernel's coordinates
                X, windows, widest, spacing = self._fit_geometry(
                    samples, resid, windows, nugget, (widest, spacing), rng.spawn(1)[0]
                )
            kernel, nugget = self._search_kernel(X, resid, windows, nugget, widest, spacing, rng)
        else:
            given = self.kernel not in (None, "auto")
            kernel = self.kernel if given else self._default_kernel(X, resid)
            self.kernel_name_ = "given"
            if self.optimize:
                kernel, nugget = self._optimize(kernel, nugget, self.fit_index_, rng)
        self.degenerate_ = warn_if_degenerate(kernel, None if spacing is None else X, spacing)
        self.tiling_note_ = None  # set where the tiles cannot hold a long part (below)
        # Nugget beyond the stated noise: a short part of the 1-sigma (terrain/microscale.py)
        fitted = self.optimize and self.fit_nugget
        part = microscale_part(kernel, nugget, self.z_var_, X[self.fit_index_], fitted)
        if part is not None:  # averaged over lengths by the left-out samples' evidence
            nugget = float(self.nugget_bounds[0])
            part = windowed_part(kernel, part, nugget, self.window_plan_, self.kernel_scores_)
            kernel = kernel if part is None else kernel + part
        self.microscale_ = part
        self.kernel_, self.nugget_ = kernel, nugget
        self.tiles_ = tiles = self.tiles or default_tiles(
            kernel, X, widest, self.anisotropy_.kernel_matrix
        )
        long_part = long_scale_part(kernel, tiles.halo)
        # A long-scale part is held by the tiles where data lie within a halo of everywhere.
        held = long_part is None or widest <= tiles.halo
        amplitude_auto = self.local_amplitude == "auto" and self.method == "auto" and held
        amplitude_auto = amplitude_auto and samples.n >= AMPLITUDE_MIN_SAMPLES
        exact = self.method == "exact" or (
            self.method == "auto"
            and not (self._amplitude_always or amplitude_auto)
            and (
                samples.n <= self.exact_max_samples
                or (long_part is not None and samples.n <= 3 * self.exact_max_samples)
            )
        )
        self.method_ = "exact" if exact else "tiled"
        self.local_amplitude_ = self._amplitude_always or (
            self.local_amplitude == "auto" and not exact
        )
        if not exact:
            if not held:
                self.tiling_note_ = warn_long_scale(long_part, tiles.halo)
            # Tiled: no global factor. GLS coefficients of a linear mean on every k-th sample:
            # the samples' alone, so a rebuild at these hyperparameters gives the same mean.
            if n_coef(self.mean_):
                self._set_coefficients(samples, idx=gls_subset(samples.n))
            self.jitter_ = 0.0
            self.fit_seconds_ = time.perf_counter() - t0
            if getattr(self, "_vecchia_lml", None) is not None:
                self.log_marginal_likelihood_value_ = self._vecchia_lml  # Vecchia Eq 9
                return self
            # Eq 9 reported on the fit subset (exact there).
            idx = self.fit_index_
            if idx.size == samples.n:
                idx = np.sort(rng.choice(samples.n, size=min(samples.n, 2000), replace=False))
            self._defer_lml(self._theta(kernel, nugget), kernel, idx)
            return self

        # R&W Alg. 2.1 lines 2-3: L = chol(K + Sigma), alpha = L^T \ (L \ y)
        K = kernel(X)
        K[np.diag_indices_from(K)] += self.z_var_ + nugget
        self.L_, self.jitter_ = cholesky_jitter(K, what="TerrainGP kernel matrix")
        del K
        if n_coef(self.mean_):
            resid = self._set_coefficients(samples, L=self.L_)
        self.alpha_ = cho_solve((self.L_, True), resid, check_finite=False)
        # Eq 9 / R&W Alg. 2.1 line 8
        self.log_marginal_likelihood_value_ = float(
            -0.5 * resid @ self.alpha_
            - np.log(np.diag(self.L_)).sum()
            - 0.5 * X.shape[0] * _LOG_2PI
        )
        self.fit_seconds_ = time.perf_counter() - t0
        return self

    def _set_coefficients(self, samples, L=None, idx=None) -> np.ndarray:
        """GLS coefficients of a linear mean at the fitted kernel (R&W Eq 2.42); updates the
        mean and the residuals, returns the residuals (n,)."""
        idx = slice(None) if idx is None else idx
        nv = self.z_var_[idx] + self.nugget_
        args = (self.kernel_, self.X_train_[idx], samples.xy[idx], samples.z[idx], nv, L)
        self.mean_, beta, cov = gls_mean(self.mean_, *args)  # terrain.breakline_evidence
        H = np.asarray(self.mean_.basis(samples.xy), dtype=float)
        self.mean_, self.coef_cov_ = self.mean_.with_coefficients(beta, cov), cov
        self.H_ = H
        if L is not None:
            self.W_ = solve_triangular(L, H, lower=True, check_finite=False)
        self.y_resid_ = samples.z - H @ beta
        return self.y_resid_

    def _basis_pair(self, xy: np.ndarray, cov: np.ndarray):
        """(H at the samples, H at ``xy``, coefficient covariance) for the tiled GP."""
        if getattr(self, "H_", None) is None:
            self.H_ = np.asarray(self.mean_.basis(self.samples_.xy), dtype=float)
        return self.H_, np.asarray(self.mean_.basis(xy), dtype=float), cov

    # -- predict ----------------------------------------------------------------------------
    def _kernel_xy(self, xy: np.ndarray) -> np.ndarray:
        """Map coordinates (n, 2), m, in the kernel's space: centred, then the fitted
        geometric anisotropy (:mod:`terrain.anisotropy`; none: centred only)."""
        return self.anisotropy_.apply(np.asarray(xy, dtype=float) - self.X_offset_)

    def _check_fitted(self) -> None:
        if not hasattr(self, "method_"):
            raise NotFittedError("This TerrainGP is not fitted yet. Call fit(samples) first.")

    def _chunk_rows(self) -> int:
        if self.chunk_size is not None:
            return int(self.chunk_size)
        return int(np.clip(2**24 // max(self.alpha_.size, 1), 256, 65536))

    @single_blas_thread
    def predict(
        self, xy: np.ndarray, return_std: bool = False, include_nugget: bool = False
    ) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
        """Posterior mean (and 1-sigma) of the terrain at query points.

        Parameters
        ----------
        xy : ndarray of shape (m, 2)
            Easting, northing in metres, in the samples' CRS.
        return_std : bool
            Also return the posterior standard deviation of the terrain, metres.
        include_nugget : bool
            Add the nugget to the variance (predicting a new nugget-noisy observation rather
            than the surface itself).

        Returns
        -------
        mean : ndarray of shape (m,)
        std : ndarray of shape (m,), only when ``return_std``
        """
        self._check_fitted()
        xy = np.asarray(xy, dtype=float)
        if xy.ndim != 2 or xy.shape[1] != 2 or not np.all(np.isfinite(xy)):
            raise bad_input("xy", xy.shape, "finite query points of shape (m, 2)", "")
        m = xy.shape[0]
        cov = getattr(self, "coef_cov_", None)
        # The exact variance costs n^2 per query (R&W Alg. 2.1 line 5): "auto" tiles big grids;
        # a long-scale part: the default tiles revert to the mean in gaps (docs/terrain.md).
        big = return_std and self.samples_.n**2 * m > EXACT_PREDICT_FLOPS
        tileable = long_scale_part(self.kernel_, self.tiles_.halo) is None
        tiled = self.method_ == "tiled" or (big and tileable and self.method == "auto")
        self.predict_route_ = "tiled" if tiled else "exact"
        long = big and not tileable and self.method == "auto"  # exact mean, tiled 1-sigma:
        if long and (done := predict_long_halo(self, xy, include_nugget)) is not None:
            return done  # terrain/long_halo.py (sets predict_route_ and tile_stats_)
        if self.predict_route_ == "tiled":
            resid_mean, std, stats = predict_tiled(
                self._kernel_xy(xy),
                self.X_train_,
                self.y_resid_,
                self.z_var_ + self.nugget_,
                self.kernel_,
                self.tiles_,
                return_std,
                amplitude_prior_sd=self.amplitude_prior_sd if self.local_amplitude_ else None,
                basis=None if cov is None or not return_std else self._basis_pair(xy, cov),
            )
            self.tile_stats_ = stats
            mean = np.asarray(self.mean_(xy), dtype=float) + resid_mean
            if return_std and include_nugget:
                std = np.sqrt(std**2 + self.nugget_)
            return (mean, std) if return_std else mean
        Xq = self._kernel_xy(xy)
        mean, std = predict_exact(
            Xq,
            self.X_train_,
            self.L_,
            self.alpha_,
            self.kernel_,
            self._chunk_rows(),
            np.asarray(self.mean_(xy), dtype=float),
            return_std,
            extra_var=self.nugget_ if include_nugget else 0.0,
            basis=None if cov is None else (lambda sl: self.mean_.basis(xy[sl]), cov, self.W_),
        )
        return (mean, std) if return_std else mean

    @single_blas_thread
    def predict_grid(
        self, grid: Grid, include_nugget: bool = False, chunks: int | tuple[int, int] | None = None
    ):
        """Posterior mean and 1-sigma on every cell centre of ``grid``, in bounded memory.

        Parameters
        ----------
        grid : Grid
            Cells to predict; same CRS as the samples.
        include_nugget : bool
            As in :meth:`predict`.
        chunks : int or (int, int), optional
            Return a Dask-backed Dataset computed block by block (rows, columns per block),
            on the active ``dask.distributed`` client if there is one, else local threads.

        Returns
        -------
        xarray.Dataset
            ``elevation`` and ``elevation_std`` (metres) on dims ``(y, x)``, with CRS and
            provenance (method, kernel, hyperparameters, seed) in ``attrs``.
        """
        self._check_fitted()
        check_same_crs(self.crs_, grid.crs, "samples", "grid")
        if chunks is not None:
            from .chunked import predict_grid_dask

            return predict_grid_dask(self, grid, chunks, include_nugget)
        step = variance_step(self, grid, EXACT_PREDICT_FLOPS)
        if step > 1:  # exact mean, variance on a checked lattice (terrain/coarse_variance.py)
            mean, std = predict_checked_lattice(self, grid, step, include_nugget)
        else:
            mean, std = self.predict(grid.xy(), return_std=True, include_nugget=include_nugget)
        return terrain_dataset(
            grid, mean.reshape(grid.shape), std.reshape(grid.shape), self.provenance()
        )

    def provenance(self) -> dict[str, Any]:
        """Flat, netCDF-safe description of how this map was made
        (:func:`terrain.product.gp_provenance`)."""
        self._check_fitted()
        return gp_provenance(self)
