"""Stationary covariance functions for terrain: squared exponential (Eq 1) and Matérn.

Each kernel carries its hyperparameters in natural units (variance in m^2, length scale in m)
and exposes them to optimizers as ``theta``: the natural log of ``[variance, lengthscale...]``,
with bounds in the same log space (scikit-learn's convention). ``gradients(X)`` yields
``dK / dtheta_j`` one matrix at a time so the marginal-likelihood gradient never holds a
(n, n, p) tensor.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
from scipy.spatial.distance import cdist

from .errors import bad_input

__all__ = ["Kernel", "Matern", "SquaredExponential", "SumKernel"]

PaperReading = Literal["squared_lengthscale", "lengthscale"]


def _positive_lengths(lengthscale) -> tuple[float, ...]:
    ls = np.atleast_1d(np.asarray(lengthscale, dtype=float))
    if ls.ndim != 1 or ls.size not in (1, 2) or not np.all(np.isfinite(ls)) or np.any(ls <= 0):
        raise bad_input(
            "lengthscale",
            lengthscale,
            "one positive length in metres (isotropic) or one per axis (x, y)",
            "e.g. lengthscale=20.0 or lengthscale=(30.0, 15.0)",
        )
    return tuple(float(v) for v in ls)


def _check_bounds(name: str, bounds: tuple[float, float]) -> tuple[float, float]:
    lo, hi = (float(b) for b in bounds)
    if not (0 < lo <= hi < np.inf):
        raise bad_input(name, bounds, "0 < low <= high < inf", "e.g. (1.0, 1e4)")
    return lo, hi


@dataclass(frozen=True)
class Kernel:
    """Base of the stationary kernels: k(x, x') = variance * rho(scaled distance)."""

    variance: float = 1.0
    lengthscale: float | tuple[float, ...] = 1.0
    variance_bounds: tuple[float, float] = (1e-4, 1e6)
    lengthscale_bounds: tuple[float, float] = (0.5, 1e5)

    def __post_init__(self) -> None:
        v = float(self.variance)
        if not (np.isfinite(v) and v > 0):
            raise bad_input("variance", self.variance, "a positive variance in m^2", "e.g. 10.0")
        object.__setattr__(self, "variance", v)
        ls = _positive_lengths(self.lengthscale)
        object.__setattr__(self, "lengthscale", ls[0] if len(ls) == 1 else ls)
        object.__setattr__(
            self, "variance_bounds", _check_bounds("variance_bounds", self.variance_bounds)
        )
        object.__setattr__(
            self, "lengthscale_bounds", _check_bounds("lengthscale_bounds", self.lengthscale_bounds)
        )

    # -- hyperparameters in log space ------------------------------------------------------
    @property
    def lengths(self) -> np.ndarray:
        """Length scales as an array of shape (1,) or (2,), metres."""
        return np.atleast_1d(np.asarray(self.lengthscale, dtype=float))

    @property
    def n_params(self) -> int:
        return 1 + self.lengths.size

    @property
    def theta(self) -> np.ndarray:
        """``log([variance, lengthscale...])``, shape (n_params,)."""
        return np.log(np.concatenate([[self.variance], self.lengths]))

    @property
    def bounds(self) -> np.ndarray:
        """Log-space bounds, shape (n_params, 2)."""
        rows = [self.variance_bounds] + [self.lengthscale_bounds] * self.lengths.size
        return np.log(np.asarray(rows, dtype=float))

    @property
    def param_names(self) -> list[str]:
        if self.lengths.size == 1:
            return ["variance", "lengthscale"]
        return ["variance", "lengthscale_x", "lengthscale_y"]

    def with_theta(self, theta: np.ndarray) -> Kernel:
        """A copy with hyperparameters ``exp(theta)``."""
        p = np.exp(np.asarray(theta, dtype=float))
        ls = p[1:]
        return replace(self, variance=p[0], lengthscale=ls[0] if ls.size == 1 else tuple(ls))

    # -- evaluation ------------------------------------------------------------------------
    def _scaled_sqdist(self, X: np.ndarray, Y: np.ndarray | None) -> np.ndarray:
        ls = self.lengths
        Xs = np.asarray(X, dtype=float) / ls
        Ys = Xs if Y is None else np.asarray(Y, dtype=float) / ls
        return cdist(Xs, Ys, metric="sqeuclidean")

    def _rho(self, d2: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def _drho_dlog_ls(self, d2: np.ndarray) -> np.ndarray:
        """``d rho / d log(l)`` divided by the squared scaled distance along that axis."""
        raise NotImplementedError

    def _rho_overwrite(self, d2: np.ndarray) -> np.ndarray:
        """``_rho`` allowed to reuse ``d2``'s memory (a fresh array nobody else holds)."""
        return self._rho(d2)

    def _rho_and_dlog(self, d2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(_rho(d2), _drho_dlog_ls(d2))`` in one pass; kernels override it to share the
        square root and exponential (the bulk of a likelihood gradient's cost)."""
        return self._rho(d2), self._drho_dlog_ls(d2)

    def __call__(self, X: np.ndarray, Y: np.ndarray | None = None) -> np.ndarray:
        """Covariance matrix, shape (n, m), m^2. ``X`` (n, 2), ``Y`` (m, 2) in metres."""
        # In place: a fresh (chunk, n) array per operation costs more in page faults than
        # the arithmetic (measured: exp of 7.5e7 values 2.3 s fresh, 0.5 s in place).
        K = self._rho_overwrite(self._scaled_sqdist(X, Y))
        K *= self.variance
        return K

    def diag(self, X: np.ndarray) -> np.ndarray:
        """Prior variance at each point, shape (n,): the kernel is stationary."""
        return np.full(np.asarray(X).shape[0], self.variance)

    def __add__(self, other: Kernel) -> SumKernel:
        return SumKernel((self, other))

    def gradients(self, X: np.ndarray) -> Iterator[np.ndarray]:
        """Yield ``dK(X, X) / dtheta_j`` for each log-hyperparameter, each of shape (n, n)."""
        d2 = self._scaled_sqdist(X, None)
        rho, drho = self._rho_and_dlog(d2)
        # d/dlog(variance) of variance * rho is K itself.
        yield self.variance * rho
        g = self.variance * drho
        if self.lengths.size == 1:
            yield g * d2
        else:
            Xs = np.asarray(X, dtype=float) / self.lengths
            for axis in range(self.lengths.size):
                col = Xs[:, axis : axis + 1]
                yield g * cdist(col, col, metric="sqeuclidean")


@dataclass(frozen=True)
class SquaredExponential(Kernel):
    """Squared exponential kernel, Eq 1: ``k = variance * exp(-0.5 * sum_d (dx_d / l_d)^2)``.

    Parameters
    ----------
    variance : float
        Signal variance in m^2 (the paper's alpha).
    lengthscale : float or tuple of 2 floats
        Length scale(s) in metres; one value is isotropic, two are (x, y).
    variance_bounds, lengthscale_bounds : tuple of float
        Search bounds in natural units for the optimizer.
    """

    @classmethod
    def from_paper(
        cls, alpha: float, gamma: float, *, reading: PaperReading, **kwargs
    ) -> SquaredExponential:
        """Build from the paper's (alpha, gamma), choosing explicitly how to read gamma.

        Eq 1 writes ``Gamma = diag(1/gamma)`` inside ``(x - x')^T Gamma (x - x')``, which makes
        gamma a *squared* length scale (``reading="squared_lengthscale"``: l = sqrt(gamma),
        so the paper's gamma = 315 gives l = 17.7 m). Section II-D's prose calls gamma "the
        length scale" (``reading="lengthscale"``: l = gamma = 315 m). docs/architecture.md §5.
        """
        if reading == "squared_lengthscale":
            lengthscale = np.sqrt(np.asarray(gamma, dtype=float))
        elif reading == "lengthscale":
            lengthscale = np.asarray(gamma, dtype=float)
        else:
            raise bad_input(
                "reading",
                reading,
                '"squared_lengthscale" (Eq 1 literally) or "lengthscale" (the paper\'s prose)',
                "say which reading of gamma the number uses",
            )
        ls = lengthscale.tolist()
        return cls(variance=alpha, lengthscale=ls if isinstance(ls, float) else tuple(ls), **kwargs)

    def _rho(self, d2: np.ndarray) -> np.ndarray:
        return np.exp(-0.5 * d2)

    def _rho_overwrite(self, d2: np.ndarray) -> np.ndarray:
        d2 *= -0.5
        return np.exp(d2, out=d2)

    def _drho_dlog_ls(self, d2: np.ndarray) -> np.ndarray:
        # d/dlog l of exp(-0.5 r^2/l^2) = exp(-0.5 r^2/l^2) * (r/l)^2
        return np.exp(-0.5 * d2)

    def _rho_and_dlog(self, d2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        rho = self._rho(d2)
        return rho, rho  # the derivative's factor is rho itself (above)

    def __repr__(self) -> str:
        return f"SquaredExponential(variance={self.variance:.4g}, lengthscale={_fmt(self)})"


#: 2 nu for the half-integer Matérn kernels: a = sqrt(2 nu) r / l (R&W Eq 4.17).
_MATERN_SCALE = {1.5: 3.0, 2.5: 5.0, 3.5: 7.0}


@dataclass(frozen=True)
class Matern(Kernel):
    """Matérn kernel with smoothness ``nu`` in {1.5, 2.5, 3.5} (Rasmussen & Williams Eq 4.16
    with the half-integer closed forms of Eq 4.17).

    Rougher than the squared exponential: nu = 1.5 gives once-differentiable surfaces, 2.5
    twice, 3.5 three times. Which family fits a glacier better is decided by the marginal
    likelihood.
    """

    nu: float = 1.5

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.nu not in _MATERN_SCALE:
            raise bad_input("nu", self.nu, "1.5, 2.5 or 3.5", "use SquaredExponential for nu = inf")

    def _rho(self, d2: np.ndarray) -> np.ndarray:
        return self._rho_overwrite(d2.copy())

    def _rho_overwrite(self, d2: np.ndarray) -> np.ndarray:
        # In place: these matrices are the bulk of the work of a tiled prediction.
        d2 *= _MATERN_SCALE[self.nu]
        a = np.sqrt(d2, out=d2)
        e = np.negative(a)
        np.exp(e, out=e)
        if self.nu == 1.5:
            a += 1.0
            a *= e
            return a
        if self.nu == 3.5:  # 1 + a + 2a^2/5 + a^3/15
            poly = a / 15.0
            poly += 0.4
            poly *= a
            poly += 1.0
            poly *= a
            poly += 1.0
            poly *= e
            return poly
        poly = a * a
        poly *= 1.0 / 3.0
        poly += a
        poly += 1.0
        poly *= e
        return poly

    def _drho_dlog_ls(self, d2: np.ndarray) -> np.ndarray:
        # With a = sqrt(2 nu) r / l: d rho / d log l = c(a) * (r/l)^2, no 1/r singularity:
        # nu = 1.5: 3 exp(-a);  nu = 2.5: (5/3) (1 + a) exp(-a);
        # nu = 3.5: (7/15) (3 + 3a + a^2) exp(-a).
        return self._rho_and_dlog(d2)[1]

    def _rho_and_dlog(self, d2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        # One square root and one exponential for both (R&W Eq 4.17 and its derivative
        # above): a = sqrt(2 nu) r / l, e = exp(-a).
        a = np.sqrt(d2 * _MATERN_SCALE[self.nu])
        e = np.exp(-a)
        if self.nu == 1.5:
            rho = (1.0 + a) * e
            e *= 3.0
            return rho, e
        if self.nu == 3.5:
            a2 = a * a
            rho = (1.0 + a + 0.4 * a2 + a2 * a / 15.0) * e
            return rho, (7.0 / 15.0) * (3.0 + 3.0 * a + a2) * e
        a1 = 1.0 + a
        rho = a * a
        rho *= 1.0 / 3.0
        rho += a1
        rho *= e
        a1 *= e
        a1 *= 5.0 / 3.0
        return rho, a1

    def __repr__(self) -> str:
        return f"Matern(variance={self.variance:.4g}, lengthscale={_fmt(self)}, nu={self.nu})"


def _fmt(kernel: Kernel) -> str:
    return (
        ", ".join(f"{v:.4g}" for v in kernel.lengths)
        if kernel.lengths.size > 1
        else (f"{kernel.lengths[0]:.4g}")
    )


@dataclass(frozen=True)
class SumKernel:
    """Sum of kernels, e.g. a long-scale trend plus short-scale rover-scale relief.

    ``k = k_1 + k_2 + ...``; its ``theta`` is the concatenation of the parts' log-parameters
    and parameter names are prefixed ``k1.``, ``k2.``... Build with ``+``:
    ``Matern(16.0, 150.0, nu=2.5) + Matern(0.5, 15.0, nu=2.5)``.
    """

    parts: tuple[Kernel, ...]

    def __post_init__(self) -> None:
        flat: list[Kernel] = []
        for p in self.parts:
            if isinstance(p, SumKernel):
                flat.extend(p.parts)
            elif isinstance(p, Kernel):
                flat.append(p)
            else:
                raise bad_input("kernel", type(p).__name__, "glacimap kernels", "")
        object.__setattr__(self, "parts", tuple(flat))

    def __add__(self, other: Kernel | SumKernel) -> SumKernel:
        return SumKernel((self, other))

    @property
    def variance(self) -> float:
        return float(sum(p.variance for p in self.parts))

    @property
    def n_params(self) -> int:
        return sum(p.n_params for p in self.parts)

    @property
    def theta(self) -> np.ndarray:
        return np.concatenate([p.theta for p in self.parts])

    @property
    def bounds(self) -> np.ndarray:
        return np.vstack([p.bounds for p in self.parts])

    @property
    def param_names(self) -> list[str]:
        return [f"k{i + 1}.{n}" for i, p in enumerate(self.parts) for n in p.param_names]

    def with_theta(self, theta: np.ndarray) -> SumKernel:
        out, start = [], 0
        for p in self.parts:
            out.append(p.with_theta(theta[start : start + p.n_params]))
            start += p.n_params
        return SumKernel(tuple(out))

    def __call__(self, X: np.ndarray, Y: np.ndarray | None = None) -> np.ndarray:
        K = self.parts[0](X, Y)
        for p in self.parts[1:]:
            Kp = p(X, Y)
            K += Kp
            del Kp
        return K

    def diag(self, X: np.ndarray) -> np.ndarray:
        return np.full(np.asarray(X).shape[0], self.variance)

    def gradients(self, X: np.ndarray) -> Iterator[np.ndarray]:
        for p in self.parts:
            yield from p.gradients(X)

    def __repr__(self) -> str:
        return " + ".join(repr(p) for p in self.parts)
