"""Spatially correlated error of a sum over cells: stationary covariance integration and the
variogram of dh on stable ground (Rolstad et al. 2009; Hugonnet et al. 2022).

The variance of ``I = sum_q w_q e_q`` for errors ``e`` with a stationary covariance ``C(h)``
is the double sum ``w^T C w``. :func:`covariance_sum` evaluates it exactly on a raster of
weights by one FFT convolution of the weights with ``C`` on the lag lattice (cost
``O(N log N)`` for ``N`` cells instead of ``N^2``); :func:`convolved_covariance` returns the
convolution itself, ``c(p) = sum_q C(p - q) w_q``, which the GP route also needs at the
samples.

The variogram route (the xDEM approach, the fallback for DEMs without a known error model):
an empirical variogram of dh on stable cells (random pairs, seeded), a fitted nugget plus two
spherical models, and ``Var(I) = w^T C w`` with ``C = sill - gamma``, integrated over the
actual outline (not the disk of equal area that Rolstad's closed form assumes;
:func:`rolstad_disk_variance` gives that closed form for comparison).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .errors import bad_input

__all__ = [
    "SphericalVariogram",
    "binned_semivariance",
    "convolved_covariance",
    "covariance_sum",
    "empirical_variogram",
    "fit_variogram",
    "rolstad_disk_variance",
]

#: Fewest stable cells the variogram route accepts.
MIN_VARIOGRAM_CELLS = 100


def _lag_kernel(shape: tuple[int, int], res: tuple[float, float], cov: Callable) -> np.ndarray:
    """``C`` on the lag lattice ``(2 ny - 1, 2 nx - 1)``, centre = lag 0."""
    ny, nx = shape
    lx = np.arange(-(nx - 1), nx) * res[0]
    ly = np.arange(-(ny - 1), ny) * res[1]
    xx, yy = np.meshgrid(lx, ly)
    lags = np.column_stack([xx.ravel(), yy.ravel()])
    return np.asarray(cov(lags), float).reshape(xx.shape)


def convolved_covariance(
    weights: np.ndarray, res: tuple[float, float], cov: Callable[[np.ndarray], np.ndarray]
) -> np.ndarray:
    """``c(p) = sum_q C(p - q) w_q`` at every cell ``p`` of the weight raster.

    Parameters
    ----------
    weights : ndarray of shape (ny, nx)
        Weight of each cell (e.g. its area inside the outline, m^2; 0 outside).
    res : (dx, dy)
        Cell size, m.
    cov : callable
        ``cov(lags)`` -> covariance (m^2) for lag vectors ``lags`` of shape (k, 2), metres
        (east, north). Stationary.

    Returns
    -------
    ndarray of shape (ny, nx)
    """
    from scipy.signal import fftconvolve

    w = np.asarray(weights, float)
    k = _lag_kernel(w.shape, res, cov)[::-1, :]  # rows run south: flip the north lag axis
    return fftconvolve(w, k, mode="same")


def covariance_sum(
    weights: np.ndarray, res: tuple[float, float], cov: Callable[[np.ndarray], np.ndarray]
) -> float:
    """``w^T C w`` over a weight raster: the variance of ``sum_q w_q e_q`` (m^2 * weight^2)."""
    w = np.asarray(weights, float)
    return float(np.sum(w * convolved_covariance(w, res, cov)))


@dataclass(frozen=True)
class SphericalVariogram:
    """``gamma(h) = nugget + sum_k s_k sph(h / a_k)``; ``sph(r) = 1.5 r - 0.5 r^3`` (r < 1).

    Attributes
    ----------
    nugget : float
        Uncorrelated variance, m^2.
    sills, ranges : tuple of float
        Partial sills (m^2) and ranges (m) of the spherical parts.
    lags, gamma, counts : ndarray
        The empirical variogram it was fitted to (bin centres m, semivariance m^2, pairs).
    """

    nugget: float
    sills: tuple[float, ...]
    ranges: tuple[float, ...]
    lags: np.ndarray | None = None
    gamma: np.ndarray | None = None
    counts: np.ndarray | None = None

    def __call__(self, h: np.ndarray) -> np.ndarray:
        h = np.asarray(h, float)
        out = np.where(h > 0, self.nugget, 0.0)
        for s, a in zip(self.sills, self.ranges, strict=True):
            r = np.minimum(h / a, 1.0)
            out = out + s * (1.5 * r - 0.5 * r**3)
        return out

    def correlated_covariance(self, lags: np.ndarray) -> np.ndarray:
        """``C(h) = sum_k s_k (1 - sph(h / a_k))`` for lag vectors (k, 2): the nugget left out
        (it is added per cell by the caller)."""
        h = np.hypot(lags[:, 0], lags[:, 1])
        out = np.zeros_like(h)
        for s, a in zip(self.sills, self.ranges, strict=True):
            r = np.minimum(h / a, 1.0)
            out += s * (1.0 - (1.5 * r - 0.5 * r**3))
        return out

    def to_dict(self) -> dict:
        return {
            "nugget_m2": self.nugget,
            "sills_m2": list(self.sills),
            "ranges_m": list(self.ranges),
        }


def binned_semivariance(
    xy: np.ndarray,
    values: np.ndarray,
    n_bins: int = 25,
    min_lag: float | None = None,
    max_lag: float | None = None,
    min_pairs: int = 10,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Binned semivariance of ``values`` (n,) at ``xy`` (n, 2) over all pairs.

    Bins are log-spaced from ``min_lag`` (default: the smallest non-zero distance) to
    ``max_lag`` (default: half the extent's diagonal); bins with fewer than ``min_pairs``
    pairs are dropped. Returns bin centres (m), semivariance (units^2) and pair counts.
    """
    from scipy.spatial.distance import pdist

    d = pdist(xy)
    g = 0.5 * pdist(np.asarray(values, float)[:, None], "sqeuclidean")
    if max_lag is None:
        max_lag = 0.5 * float(np.hypot(*np.ptp(xy, axis=0)))
    lo = max(float(np.min(d[d > 0])), 1e-3) if min_lag is None else float(min_lag)
    edges = np.geomspace(lo, max_lag, n_bins + 1)
    b = np.digitize(d, edges) - 1
    keep = (b >= 0) & (b < n_bins)
    counts = np.bincount(b[keep], minlength=n_bins)
    sums = np.bincount(b[keep], weights=g[keep], minlength=n_bins)
    good = counts >= min_pairs
    centres = np.sqrt(edges[:-1] * edges[1:])
    return centres[good], sums[good] / counts[good], counts[good]


def empirical_variogram(
    xy: np.ndarray,
    values: np.ndarray,
    n_points: int = 3000,
    n_bins: int = 25,
    max_lag: float | None = None,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Binned semivariance of ``values`` at ``xy`` from all pairs of a seeded subsample.

    Returns bin centres (m), semivariance (m^2) and pair counts; bins are log-spaced from the
    smallest spacing to ``max_lag`` (default half the extent's diagonal).
    """
    xy, v = np.asarray(xy, float), np.asarray(values, float)
    ok = np.isfinite(v)
    xy, v = xy[ok], v[ok]
    if v.size < MIN_VARIOGRAM_CELLS:
        raise bad_input(
            "stable cells",
            v.size,
            f"at least {MIN_VARIOGRAM_CELLS} stable cells with dh for a variogram",
            "give stable ground (a mask or an outline that leaves ground outside)",
        )
    rng = np.random.default_rng(seed)
    if v.size > n_points:
        idx = rng.choice(v.size, n_points, replace=False)
        xy, v = xy[idx], v[idx]
    return binned_semivariance(xy, v, n_bins, max_lag=max_lag)


def fit_variogram(lags: np.ndarray, gamma: np.ndarray, counts: np.ndarray) -> SphericalVariogram:
    """Nugget + two spherical models by weighted least squares (``scipy.optimize.curve_fit``,
    weights ~ sqrt(pair counts)); ranges bounded to (first lag, 4 x last lag). Semivariances
    that are all 0 (two DEMs that differ by a constant there) give the zero variogram."""
    from scipy.optimize import curve_fit

    top = float(np.max(gamma))
    hmin, hmax = float(lags[0]), float(lags[-1])
    if not top > 0.0:  # stable ground without any variation (DEMs equal but for a constant)
        return SphericalVariogram(0.0, (0.0, 0.0), (hmin, max(hmax, hmin)), lags, gamma, counts)

    def model(h, n, s1, a1, s2, a2):
        return SphericalVariogram(n, (s1, s2), (a1, a2))(h)

    p0 = [0.1 * top, 0.5 * top, max(hmin * 3, hmax / 10), 0.4 * top, hmax / 2]
    lo = [0.0, 0.0, hmin, 0.0, hmin]
    hi = [top * 2, top * 4, 4 * hmax, top * 4, 4 * hmax]
    p, _ = curve_fit(
        model, lags, gamma, p0=p0, bounds=(lo, hi), sigma=1 / np.sqrt(counts), maxfev=20000
    )
    return SphericalVariogram(
        float(p[0]), (float(p[1]), float(p[3])), (float(p[2]), float(p[4])), lags, gamma, counts
    )


def rolstad_disk_variance(vario: SphericalVariogram, area: float) -> float:
    """Variance of the mean over a disk of ``area`` m^2 by Rolstad et al. (2009)'s closed form
    for spherical models (as in xDEM's ``neff_circular_approx_theoretical``), nugget excluded:
    ``s (1 - L/a + (L/a)^3 / 5)`` for ``L <= a`` and ``s (a/L)^2 / 5`` beyond, ``L = sqrt(A/pi)``.
    """
    L = np.sqrt(area / np.pi)
    out = 0.0
    for s, a in zip(vario.sills, vario.ranges, strict=True):
        out += s * (1 - L / a + (L / a) ** 3 / 5) if L <= a else s * (a / L) ** 2 / 5
    return float(out)
