"""The linear-mean protocol: GP prior means with linear coefficients (R&W Section 2.7).

A mean whose ``n_coef`` is > 0 is ``m(x) = h(x)^T beta`` with explicit basis functions:

``n_coef`` : int
    Number of coefficients; 0 means a fixed mean (evaluate it, do not ask for a basis).
``basis(xy)`` : (n, 2) -> (n, n_coef)
    The design matrix ``H``.
``coef_names`` : tuple of str
    Column names, with units (``("offset_m", "scale")``).
``with_coefficients(beta, cov)``
    A copy evaluating ``H @ beta``; ``coef_`` and ``coef_cov_`` keep ``beta`` (n_coef,) and
    its covariance (n_coef, n_coef). The GP estimates them by generalised least squares.
``fit(xy, z)``
    Ordinary least squares fallback, so the mean also works outside the GP.

:class:`~terrain.prior.ConstantMean`, :class:`~terrain.prior.TriangulatedMean` and
:class:`~terrain.raster_mean.RasterMean` implement it; this module holds the shared parts.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from numbers import Real
from typing import Any

import numpy as np

from .errors import NotFittedError, bad_input

__all__ = ["ols_coefficients"]


def check_xy(xy: Any) -> np.ndarray:
    """``xy`` as a finite float array of shape (n, 2), or an :class:`InputError`."""
    xy = np.asarray(xy, dtype=float)
    if xy.ndim != 2 or xy.shape[1] != 2 or not np.all(np.isfinite(xy)):
        shape = getattr(xy, "shape", None)
        raise bad_input("xy", shape, "finite easting/northing, shape (n, 2)", "stack x and y")
    return xy


def check_z(xy: Any, z: Any) -> tuple[np.ndarray, np.ndarray]:
    z = np.asarray(z, dtype=float)
    if z.ndim != 1 or z.size == 0 or not np.all(np.isfinite(z)):
        raise bad_input(
            "z", getattr(z, "shape", z), "a non-empty finite (n,) array", "drop NaN samples first"
        )
    xy = check_xy(xy)
    if len(xy) != z.size:
        raise bad_input("xy", len(xy), f"{z.size} points, one per z", "align xy and z")
    return xy, z


def ols_coefficients(h: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ordinary least squares of ``z`` (n,) on the design matrix ``h`` (n, p).

    Returns
    -------
    beta : ndarray, shape (p,)
        ``argmin |z - h beta|``.
    cov : ndarray, shape (p, p)
        ``s^2 (h^T h)^-1`` with ``s^2 = RSS / (n - p)``; NaN when ``n <= p`` (no residual
        degrees of freedom); 0 on noise-free data.
    """
    h, z = np.asarray(h, float), np.asarray(z, float)
    n, p = h.shape
    beta, _, rank, sv = np.linalg.lstsq(h, z, rcond=None)
    if rank < p:
        raise bad_input(
            "mean basis",
            f"rank {rank} of {p} columns at {n} samples",
            "linearly independent basis columns (e.g. a DEM that varies over the samples)",
            'fix the coefficients instead: offset="none" or a number of metres',
        )
    if n <= p:
        return beta, np.full((p, p), np.nan)
    resid = z - h @ beta
    s2 = float(resid @ resid) / (n - p)
    return beta, s2 * np.linalg.inv(h.T @ h)


def coefficient_table(names: tuple[str, ...], beta: Any, cov: Any) -> dict[str, Any]:
    """``{name: {"value": b, "sd": 1-sigma or None}}``, JSON-safe."""
    if beta is None:
        return {}
    sd = np.sqrt(np.clip(np.diag(cov), 0.0, None)) if cov is not None else [np.nan] * len(beta)
    return {
        n: {"value": float(b), "sd": float(e) if np.isfinite(e) else None}
        for n, b, e in zip(names, beta, sd, strict=True)
    }


def format_coefficients(names: tuple[str, ...], beta: Any, cov: Any) -> str:
    parts = []
    for name, c in coefficient_table(names, beta, cov).items():
        sd = "" if c["sd"] is None else f" +- {c['sd']:.4g}"
        parts.append(f"{name}={c['value']:.6g}{sd}")
    return ", ".join(parts)


def parse_offset(offset: Any) -> str | float:
    if isinstance(offset, str) and offset in ("fit", "none"):
        return offset
    if isinstance(offset, Real) and not isinstance(offset, bool) and np.isfinite(offset):
        return float(offset)
    raise bad_input(
        "offset",
        offset,
        '"fit" (a + b * DEM, estimated), "none" (the DEM as is) or a number of metres',
        'use offset="fit" unless the vertical datum offset is known',
    )


class OffsetScaleMean:
    """Mixin: ``a + b * dem(xy)`` (``offset="fit"``), ``dem(xy)`` (``"none"``) or
    ``dem(xy) + c`` (a number). Subclasses define ``dem(xy)`` and set ``offset``."""

    coef_names: tuple[str, ...] = ("offset_m", "scale")
    offset: str | float = "none"
    coef_: np.ndarray | None = None
    coef_cov_: np.ndarray | None = None

    def dem(self, xy: np.ndarray) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def __call__(self, xy: np.ndarray) -> np.ndarray:
        """Mean elevation (m) at ``xy`` (n, 2) -> (n,); never NaN. With ``offset="fit"``
        this is ``a + b * dem(xy)`` and needs the coefficients (:meth:`fit`)."""
        return self._value(xy)

    @property
    def fit(self) -> Callable[[np.ndarray, np.ndarray], Any]:
        """``fit(xy, z)``: least squares of ``z`` on ``[1, dem(xy)]`` (``offset="fit"``
        only; a fixed DEM has no ``fit``, so the GP uses it as it is)."""
        if self.n_coef == 0:
            name = type(self).__name__
            raise AttributeError(f"{name}(offset={self.offset!r}) has nothing to fit")
        return self.fit_ols

    @property
    def n_coef(self) -> int:
        """Number of linear coefficients: 2 with ``offset="fit"``, else 0 (a fixed mean)."""
        return 2 if self.offset == "fit" else 0

    def basis(self, xy: np.ndarray) -> np.ndarray:
        """Design matrix ``[1, dem(xy)]``, shape (n, 2), for ``offset="fit"``."""
        if self.n_coef == 0:
            raise bad_input(
                "mean.offset",
                self.offset,
                '"fit" for a mean with linear coefficients (n_coef > 0)',
                "check mean.n_coef first; a fixed mean is evaluated as mean(xy)",
            )
        d = np.asarray(self.dem(xy), dtype=float)
        return np.column_stack([np.ones_like(d), d])

    def with_coefficients(self, beta: Any, cov: Any) -> Any:
        """A copy whose value is ``basis(xy) @ beta``; ``beta`` (p,), its covariance ``cov``
        (p, p) are kept as ``coef_`` and ``coef_cov_``."""
        beta, cov = check_coefficients(self, beta, cov)
        out = copy.copy(self)
        out.coef_, out.coef_cov_ = beta, cov
        return out

    def fit_ols(self, xy: np.ndarray, z: np.ndarray) -> Any:
        """Ordinary least squares of ``z`` (n,) on :meth:`basis` at ``xy`` (n, 2): a copy with
        ``coef_`` and ``coef_cov_`` set. A fixed mean (``n_coef == 0``) returns itself."""
        if self.n_coef == 0:
            return self
        xy, z = check_z(xy, z)
        return self.with_coefficients(*ols_coefficients(self.basis(xy), z))

    def _value(self, xy: np.ndarray) -> np.ndarray:
        if self.offset == "none":
            return self.dem(xy)
        if self.offset != "fit":
            return self.dem(xy) + float(self.offset)
        if self.coef_ is None:
            raise NotFittedError(
                f"{type(self).__name__}(offset='fit') is a + b * DEM with a and b not yet "
                "estimated. Fix: let TerrainGP fit it, call mean.fit(xy, z) (least squares), "
                "set them with mean.with_coefficients(beta, cov), or pass offset='none'."
            )
        return self.basis(xy) @ self.coef_

    def _coef_text(self) -> str:
        if self.offset != "fit":
            return f"offset={self.offset!r}"
        if self.coef_ is None:
            return "offset='fit' (not fitted)"
        text = format_coefficients(self.coef_names, self.coef_, self.coef_cov_)
        check = getattr(self, "scale_check_", None) or {}
        if check.get("used") == "ols":  # terrain.prior_scale: the GLS scale was rejected
            text += (
                f", scale by least squares (GLS {check['b_gls']:.3g}; Hausman z {check['z']:.1f})"
            )
        return text


def check_coefficients(mean: Any, beta: Any, cov: Any) -> tuple[np.ndarray, np.ndarray]:
    p = mean.n_coef
    fix = f"pass beta of shape ({p},) and its covariance of shape ({p}, {p})"
    if p == 0:
        raise bad_input("mean.n_coef", 0, "a mean with linear coefficients", "nothing to set")
    beta = np.array(beta, dtype=float).reshape(-1)
    cov = np.array(cov, dtype=float)
    if beta.shape != (p,) or not np.all(np.isfinite(beta)):
        raise bad_input("beta", beta, f"{p} finite coefficients {mean.coef_names}", fix)
    if cov.shape != (p, p) or np.any(np.diag(cov) < 0):
        raise bad_input("cov", cov.shape, f"a ({p}, {p}) covariance, NaN if unknown", fix)
    return beta, cov
