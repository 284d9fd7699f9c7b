"""An isotropic kernel tabulated along the distance: one lookup per matrix entry.

A tiled prediction of 50,000 samples onto 600 x 600 cells at 1 m evaluates ~1e9
cross-covariances; with two squared-exponential parts and a Matérn micro-scale part that is
three exponentials (and a square root) per entry. NumPy's float64 ``exp`` is not vectorised
on AVX2 machines (~10 ns a value here), so kernel evaluation was 56 % of the prediction's
CPU time (docs/terrain.md "Kernel matrices from a distance table").

Every kernel part here is stationary and, unless given per-axis length scales, isotropic:
the whole sum is one function ``k(r)`` of the distance ``r``. :class:`RadialTable` samples
``k`` and its slope ``dk/dr`` (closed forms: R&W Eq 4.17 and its derivative) at a step
``h = l_min / STEPS_PER_LENGTH`` (``l_min`` the shortest length scale) on ``[0, r_max]`` and
evaluates the cubic Hermite interpolant between nodes: two 16-byte gathers and a Horner
step per entry, whatever the number of parts. The interpolation error is at most
``h^4 / 384`` times the largest fourth derivative of ``k``: about 1e-11 of the variance at
256 steps per length scale (tests/test_radial_table.py), far below the rounding of a
Cholesky factor of these matrices.

Evaluated with NumPy, that lookup is a dozen passes over the matrix (distance, floor,
fraction, two gathers, six Horner steps): ~15 ns an entry here, and still 42 % of a 50k
prediction's CPU time. With Numba (a dependency; the NumPy form stays for a platform it
does not build on) the same operations in the same order run as one loop that releases the
GIL: the same bits, 8-10x faster (docs/terrain.md "Performance notes").
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.spatial.distance import cdist

from .compiled import compiled

__all__ = [
    "MAX_STEPS",
    "STEPS_PER_LENGTH",
    "RadialTable",
    "radial_profile",
    "tabulate",
]

#: Table steps per shortest length scale (cubic Hermite error ~1e-11 of the variance).
STEPS_PER_LENGTH = 256
#: Most steps in a table (32 bytes each); beyond it the kernel is evaluated directly.
MAX_STEPS = 1 << 18


def _build_fill(numba):
    """The table lookup as one compiled loop (terrain.compiled)."""

    @numba.njit(nogil=True, cache=True, boundscheck=False)
    def fill(X, Y, inv_step, coef, scale, symmetric, out):  # pragma: no cover - compiled
        # The operations of RadialTable._numpy_matrix, entry by entry and in its order,
        # so the two give the same bits: distance (as cdist: sqrt of dx^2 + dy^2), times
        # 1/h, floor, fraction, Horner, times scale. False where a distance is past the table.
        size = coef.shape[0]
        for a in range(X.shape[0]):
            xa = X[a, 0]
            ya = X[a, 1]
            for b in range(a + 1 if symmetric else Y.shape[0]):
                dx = xa - Y[b, 0]
                dy = ya - Y[b, 1]
                t = np.sqrt(dx * dx + dy * dy) * inv_step
                i = int(t)
                if i >= size:
                    return False
                t -= i
                k = ((coef[i, 3] * t + coef[i, 2]) * t + coef[i, 1]) * t + coef[i, 0]
                out[a, b] = k * scale
                if symmetric:
                    out[b, a] = out[a, b]
        return True

    return fill


def _parts(kernel: Any) -> tuple:
    return tuple(getattr(kernel, "parts", (kernel,)))


def radial_profile(kernel: Any, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``k(r)`` and ``dk/dr`` of an isotropic kernel at distances ``r`` (m), each of r's shape.

    With ``q = (r / l)^2`` a part's ``_rho_and_dlog(q)`` gives ``rho`` and
    ``(d rho / d log l) / q``; since ``d rho / d log l = -r d rho / dr``,
    ``d rho / dr = -[(d rho / d log l) / q] * r / l^2``.
    """
    r = np.asarray(r, dtype=float)
    value = np.zeros_like(r)
    slope = np.zeros_like(r)
    for part in _parts(kernel):
        length = float(part.lengths[0])
        rho, dlog = part._rho_and_dlog((r / length) ** 2)
        value += part.variance * rho
        slope -= part.variance * dlog * r / length**2
    return value, slope


class RadialTable:
    """``k(r)`` of an isotropic kernel on ``[0, r_max]``, cubic Hermite between nodes.

    Parameters
    ----------
    kernel : Kernel or SumKernel
        An isotropic kernel (every part with one length scale).
    r_max : float
        Largest distance the table must cover, m. A matrix with a longer distance is
        evaluated by ``kernel`` itself, so a short table is never wrong, only slower.

    Attributes
    ----------
    step : float
        Table step ``h``, m.
    variance : float
        ``k(0)``, m^2.
    """

    def __init__(self, kernel: Any, r_max: float) -> None:
        self.kernel = kernel
        shortest = min(float(np.min(p.lengths)) for p in _parts(kernel))
        self.step = shortest / STEPS_PER_LENGTH
        n = int(np.ceil(float(r_max) / self.step)) + 1
        value, slope = radial_profile(kernel, np.arange(n + 1) * self.step)
        # On each step, t in [0, 1): k = c0 + c1 t + c2 t^2 + c3 t^3 (cubic Hermite).
        v0, v1 = value[:-1], value[1:]
        d0, d1 = slope[:-1] * self.step, slope[1:] * self.step
        self._c01 = v0 + 1j * d0
        self._c23 = (3.0 * (v1 - v0) - 2.0 * d0 - d1) + 1j * (2.0 * (v0 - v1) + d0 + d1)
        # The same coefficients as rows (c0, c1, c2, c3) for the compiled loop.
        self._coef = np.column_stack([v0, d0, self._c23.real, self._c23.imag])
        self.variance = float(value[0])
        self._fill = compiled("radial_table.fill", _build_fill)

    @property
    def r_max(self) -> float:
        """Largest distance the table interpolates, m."""
        return self._c01.size * self.step

    def __call__(
        self, X: np.ndarray, Y: np.ndarray | None = None, scale: float | None = None
    ) -> np.ndarray:
        """Covariance matrix, shape (n, m), m^2. ``X`` (n, 2), ``Y`` (m, 2) in metres;
        ``scale``: a factor on every entry (a tile's amplitude), the same bits as
        multiplying after, without a second pass."""
        if self._fill is None:
            return self._numpy_matrix(X, Y, scale)
        X = np.ascontiguousarray(X, dtype=float)
        Z = X if Y is None else np.ascontiguousarray(Y, dtype=float)
        K = np.empty((X.shape[0], Z.shape[0]))
        s = 1.0 if scale is None else float(scale)  # x * 1.0 is x: the same bits
        if self._fill(X, Z, 1.0 / self.step, self._coef, s, Y is None, K):
            return K
        return self._closed_form(X, Y, scale)

    def _closed_form(self, X, Y, scale):
        K = self.kernel(X, Y)
        if scale is not None:
            K *= scale
        return K

    def _numpy_matrix(
        self, X: np.ndarray, Y: np.ndarray | None = None, scale: float | None = None
    ) -> np.ndarray:
        """:meth:`__call__` in NumPy alone: the same operations, pass by pass."""
        t = cdist(X, X if Y is None else Y)
        t *= 1.0 / self.step
        i = t.astype(np.intp)  # t >= 0: truncation is the floor
        if i.size and int(i.max()) >= self._c01.size:
            return self._closed_form(X, Y, scale)
        t -= i  # fraction of a step
        c23 = np.take(self._c23, i)
        K = c23.imag * t  # Horner: ((c3 t + c2) t + c1) t + c0
        K += c23.real
        del c23
        c01 = np.take(self._c01, i)
        K *= t
        K += c01.imag
        K *= t
        K += c01.real
        if scale is not None:
            K *= scale
        return K

    def diag(self, X: np.ndarray) -> np.ndarray:
        """Prior variance at each point, shape (n,), m^2."""
        return np.full(np.asarray(X).shape[0], self.variance)


def tabulate(kernel: Any, r_max: float) -> RadialTable | None:
    """A :class:`RadialTable` of ``kernel`` up to ``r_max`` m, or ``None`` where one does not
    apply: a part with per-axis length scales (not a function of the distance alone), or a
    table of more than :data:`MAX_STEPS` steps (short length scales over long distances)."""
    parts = _parts(kernel)
    if any(np.size(getattr(p, "lengths", ())) != 1 for p in parts):
        return None
    shortest = min(float(np.min(p.lengths)) for p in parts)
    if not np.isfinite(r_max) or r_max / shortest * STEPS_PER_LENGTH + 1 > MAX_STEPS:
        return None
    return RadialTable(kernel, r_max)
