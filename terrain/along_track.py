"""The along-track correlated error of a rover's samples and its quadratic form.

A rover's samples (triangulated landmarks) inherit the trajectory's error. With consumer GPS
that error is dominated by the receiver's slowly wandering bias, a first-order Gauss-Markov
(Ornstein-Uhlenbeck) process with time constant ``tau`` (~60 s for the default sensors): two
landmarks seen within the same minute share most of their vertical error, two seen ten
minutes apart share none of it. A GP that treats each sample's error as independent noise
(``z_var``) averages this error down over neighbours that all carry it.

Model (per survey; the shared map-wide offset is a separate term): each sample's *relative*
vertical error (the shared offset removed) is ``e_i = a(t_i) s_i + b_i`` with

* ``a`` a unit-variance OU process in time: ``cov(a(t), a(t')) = exp(-|t - t'| / tau)``,
* ``s_i = sqrt(fraction) sigma_i``, ``sigma_i`` the sample's relative vertical 1-sigma,
* ``b_i`` independent, variance ``(1 - fraction) sigma_i^2`` (none when ``fraction >= 1``:
  the measured fraction is relative to the *stated* variance and exceeds 1 when the
  realised errors are larger than stated),

so that ``var(e_i) = max(fraction, 1) sigma_i^2`` and, for ``i != j``,
``C_ij = s_i s_j exp(-|t_i - t_j| / tau)``. For a linear estimator ``I_hat = u^T y`` the
along-track part adds ``u^T C u - sum_i u_i^2 s_i^2`` to the variance the independent-noise
model gives (its diagonal is already in ``z_var``).

``u^T C u`` costs O(n) per column through the OU recursion over the samples in time order
(Rybicki & Press 1995: the inverse of an exponential covariance is tridiagonal; the forward
sum is the same Markov property): with ``a_i = u_i s_i`` sorted by time,

    S_1 = 0,  S_i = exp(-(t_i - t_{i-1}) / tau) (S_{i-1} + a_{i-1}),
    u^T C u = sum_i a_i^2 + 2 sum_i a_i S_i.

``fraction`` and ``tau`` are measured from the realised errors of simulated surveys
(:func:`fit_along_track`, docs/change.md "The along-track term").
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .errors import bad_input

__all__ = [
    "ALONG_TRACK_FRACTION",
    "ALONG_TRACK_TAU_S",
    "AlongTrackModel",
    "along_track_quadratic",
    "empirical_time_correlation",
    "fit_along_track",
    "pool_time_correlations",
]

#: Along-track variance over the stated relative variance, and the correlation time (s):
#: measured on the realised landmark errors of 24 simulated surveys of the change Monte
#: Carlo's chain plan with 4 control corners, seeds 1000-1023 (disjoint from the Monte
#: Carlo's), ``python benchmarks/change.py --parts calib --calib-surveys 24`` (JSON:
#: benchmarks/results/change_along_track_calib.json; docs/change.md "The along-track term"):
#: correlation at lag 0+ 1.04 (realised/stated variance 1.15: 91 % of the realised relative
#: variance is along-track), e-folding lag 139 s (integral time scale 116 s; the GPS bias's
#: own tau is 60 s: the smoothed trajectory error decays about twice as slowly).
ALONG_TRACK_FRACTION = 1.04
ALONG_TRACK_TAU_S = 139.0


@dataclass(frozen=True)
class AlongTrackModel:
    """Along-track variance ``fraction * sigma_i^2`` of each sample (``sigma_i`` its stated
    relative vertical 1-sigma), correlated with ``exp(-|dt| / tau_s)``. ``fraction`` is the
    share of the stated variance that is along-track; it exceeds 1 when the realised errors
    are larger than stated (it is measured against the stated 1-sigma)."""

    fraction: float = ALONG_TRACK_FRACTION
    tau_s: float = ALONG_TRACK_TAU_S

    def __post_init__(self) -> None:
        f, tau = float(self.fraction), float(self.tau_s)
        if not (np.isfinite(f) and f >= 0.0):
            raise bad_input(
                "along_track.fraction",
                self.fraction,
                "a finite number >= 0 (along-track over stated variance)",
                f"use the measured default {ALONG_TRACK_FRACTION}",
            )
        if not (tau > 0):
            raise bad_input(
                "along_track.tau_s",
                self.tau_s,
                "a time constant > 0 (s)",
                f"use the measured default {ALONG_TRACK_TAU_S}",
            )

    def to_dict(self) -> dict[str, float]:
        return {"fraction": float(self.fraction), "tau_s": float(self.tau_s)}


def _columns(name: str, value: Any, n: int | None = None) -> np.ndarray:
    a = np.asarray(value, float)
    if a.ndim not in (1, 2) or (n is not None and a.shape[0] != n):
        want = "shape (n,) or (n, m)" if n is None else f"{n} rows (one per sample)"
        raise bad_input(name, getattr(a, "shape", value), want, "one row per sample")
    if not np.isfinite(a).all():
        raise bad_input(name, "non-finite values", "finite numbers", "drop or fix those samples")
    return a


def along_track_quadratic(
    u: np.ndarray,
    t_s: np.ndarray,
    sigma_m: np.ndarray,
    tau_s: float,
    *,
    off_diagonal: bool = False,
) -> float | np.ndarray:
    """``u^T C u`` for ``C_ij = sigma_i sigma_j exp(-|t_i - t_j| / tau_s)``, in O(n) a column.

    Parameters
    ----------
    u : ndarray of shape (n,) or (n, m)
        Weights of the samples (one column per linear functional; e.g. m^2 per m of sample
        error for a volume).
    t_s : ndarray of shape (n,)
        Time of each sample (s; any origin, any order).
    sigma_m : ndarray of shape (n,)
        Along-track 1-sigma of each sample (m), ``>= 0``.
    tau_s : float
        Correlation time (s), ``> 0`` (``inf``: fully correlated).
    off_diagonal : bool
        Return ``u^T C u - sum_i u_i^2 sigma_i^2``: the part a model with independent
        per-sample noise of the same variance misses.

    Returns
    -------
    float or ndarray of shape (m,)
        Units of ``u^2 sigma^2`` (m^6 for volume weights in m^2).

    Raises
    ------
    InputError
        Mismatched lengths, non-finite values, negative ``sigma_m``, ``tau_s <= 0``.
    """
    U = _columns("u", u)
    n = U.shape[0]
    t = _columns("t_s", t_s, n)
    s = _columns("sigma_m", sigma_m, n)
    if t.ndim != 1 or s.ndim != 1:
        raise bad_input("t_s / sigma_m", (t.shape, s.shape), f"shape ({n},)", "one per sample")
    if (s < 0).any():
        raise bad_input("sigma_m", float(s.min()), "1-sigmas >= 0 (m)", "pass standard deviations")
    tau = float(tau_s)
    if not tau > 0:
        raise bad_input("tau_s", tau_s, "a correlation time > 0 (s)", "e.g. 60.0")
    vec = U.ndim == 1
    U = U.reshape(n, -1)
    order = np.argsort(t, kind="stable")
    a = U[order] * s[order, None]
    decay = np.exp(-np.diff(t[order]) / tau)  # (n-1,) in [0, 1]
    diag = np.sum(a**2, axis=0)
    cross = np.zeros(a.shape[1])
    S = np.zeros(a.shape[1])
    for i in range(1, n):  # the OU recursion: S_i = d_i (S_{i-1} + a_{i-1})
        S = decay[i - 1] * (S + a[i - 1])
        cross += a[i] * S
    out = (0.0 if off_diagonal else diag) + 2.0 * cross
    return float(out[0]) if vec else out


def empirical_time_correlation(
    t_s: np.ndarray, error_m: np.ndarray, sigma_m: np.ndarray, edges_s: np.ndarray
) -> dict[str, np.ndarray]:
    """Mean of ``(e_i / sigma_i)(e_j / sigma_j)`` over the pairs ``i < j`` whose time lag
    falls in each bin of ``edges_s`` (s): the realised correlation of normalised errors.

    Returns
    -------
    dict
        ``lag_s`` (bin mean lag), ``corr``, ``pairs`` (count) per bin, and ``nees`` (the
        mean of ``(e / sigma)^2``: 1 when ``sigma`` is right).
    """
    t = np.asarray(t_s, float)
    z = np.asarray(error_m, float) / np.asarray(sigma_m, float)
    edges = np.asarray(edges_s, float)
    nb = edges.size - 1
    prod, lagsum, cnt = np.zeros(nb), np.zeros(nb), np.zeros(nb)
    for i in range(t.size - 1):  # row by row: O(n) memory
        lag = np.abs(t[i + 1 :] - t[i])
        b = np.searchsorted(edges, lag, side="right") - 1
        ok = (b >= 0) & (b < nb)
        prod += np.bincount(b[ok], weights=z[i] * z[i + 1 :][ok], minlength=nb)
        lagsum += np.bincount(b[ok], weights=lag[ok], minlength=nb)
        cnt += np.bincount(b[ok], minlength=nb)
    with np.errstate(invalid="ignore", divide="ignore"):
        return {
            "lag_s": lagsum / cnt,
            "corr": prod / cnt,
            "pairs": cnt,
            "nees": np.array(float(np.mean(z**2))),
        }


def pool_time_correlations(parts: list[dict[str, Any]]) -> dict[str, np.ndarray]:
    """Pool :func:`empirical_time_correlation` results of several surveys: pair-weighted mean
    correlation and lag per bin, ``nees`` weighted by each survey's ``n`` (its sample count,
    a key the caller adds)."""
    pairs = np.sum([np.asarray(p["pairs"], float) for p in parts], axis=0)
    w = np.array([np.asarray(p["pairs"], float) for p in parts])
    corr = np.sum(w * np.nan_to_num(np.array([p["corr"] for p in parts], float)), axis=0)
    lag = np.sum(w * np.nan_to_num(np.array([p["lag_s"] for p in parts], float)), axis=0)
    n = np.array([p["n"] for p in parts], float)
    nees = float(np.sum(n * np.array([float(p["nees"]) for p in parts])) / n.sum())
    with np.errstate(invalid="ignore", divide="ignore"):
        return {"lag_s": lag / pairs, "corr": corr / pairs, "pairs": pairs, "nees": np.array(nees)}


def fit_along_track(
    lag_s: np.ndarray,
    corr: np.ndarray,
    pairs: np.ndarray,
    nees: float,
    short_lag_s: float = 10.0,
) -> dict[str, float]:
    """``fraction`` and ``tau`` of :class:`AlongTrackModel` from pooled binned correlations.

    ``fraction``: the correlation at lag 0+, the first two bins (both below
    ``short_lag_s``) extrapolated linearly to lag 0: the along-track variance over the
    *stated* variance (``corr`` is of errors normalised by the stated 1-sigma; above 1 when
    that 1-sigma is too small). ``tau``: the e-folding lag, where the correlation has
    fallen to ``fraction / e``: exact for the exponential, and unlike a fit or an integral
    not pulled by the noisy long-lag bins. For reference: the integral time scale
    ``int_0^T corr(lag) dlag / fraction`` (``integral_tau_s``; trapezoid from
    ``(0, fraction)`` through the bins, ``T`` the first zero crossing), which is what the
    variance of an integral over many minutes depends on, and the least-squares fit of
    ``fraction exp(-lag / tau) + c`` (``lsq_*``; ``c`` absorbs the negative correlation at
    long lags that removing each survey's mean error leaves), weights = pairs per bin.
    ``nees`` (realised over stated variance) gives ``fraction_of_realised``.
    """
    from scipy.optimize import curve_fit

    ok = np.isfinite(corr) & (pairs > 0)
    lag, c, w = np.asarray(lag_s)[ok], np.asarray(corr)[ok], np.asarray(pairs)[ok]
    if lag.size < 3 or lag[1] >= short_lag_s:
        raise bad_input(
            "lag_s",
            lag[:2].tolist(),
            f"two bins below {short_lag_s} s and one more",
            "use finer lag bins near 0",
        )
    # the correlation at lag 0+: the first two bins extrapolated linearly to 0
    frac = float(c[0] + (c[0] - c[1]) * lag[0] / (lag[1] - lag[0]))
    # tau: the e-folding lag, where the correlation has fallen to fraction / e (linear
    # between bins): exact for the OU model, and insensitive to the noisy long-lag tail
    below = np.flatnonzero(c <= frac / np.e)
    if below.size == 0 or below[0] == 0:
        raise bad_input(
            "corr",
            c.tolist(),
            "a correlation that decays below fraction / e",
            "extend the lag bins (or pool more surveys)",
        )
    j = int(below[0])
    efold = float(lag[j - 1] + (lag[j] - lag[j - 1]) * (c[j - 1] - frac / np.e) / (c[j - 1] - c[j]))
    # the integral time scale to the first zero crossing, for reference
    x, y = [0.0], [frac]
    for lg, cc in zip(lag, c, strict=True):
        if cc <= 0:  # linear to the zero crossing, then stop
            x.append(x[-1] + (lg - x[-1]) * y[-1] / (y[-1] - cc))
            y.append(0.0)
            break
        x.append(float(lg))
        y.append(float(cc))
    integral = float(np.trapezoid(y, x))

    def model(t, f, tau, c0):
        return f * np.exp(-t / tau) + c0

    p, cov = curve_fit(
        model,
        lag,
        c,
        p0=(0.5, 60.0, 0.0),
        sigma=1.0 / np.sqrt(w),
        bounds=([0.0, 1.0, -1.0], [2.0, 1e4, 1.0]),
    )
    return {
        "fraction": frac,
        "tau_s": efold,
        "integral_tau_s": integral / frac if frac > 0 else float("nan"),
        "integral_s": integral,
        "zero_crossing_s": float(x[-1]),
        "nees": float(nees),
        "fraction_of_realised": frac / nees if nees > 0 else float("nan"),
        "lsq_fraction": float(p[0]),
        "lsq_tau_s": float(p[1]),
        "lsq_constant": float(p[2]),
        "lsq_sd": np.sqrt(np.clip(np.diag(cov), 0.0, None)).tolist(),
    }
