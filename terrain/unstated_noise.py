"""Noise the samples do not state, estimated where the survey is dense.

With ``z_var = 0`` the fitted nugget *is* the samples' noise (:mod:`terrain.microscale`
keeps it white). The kernel search fits it on a fit subset of at most 2,000 samples, about
13 m apart on a 600 m site, where 0.05 m of noise cannot be told from ground that varies at
that spacing: mapped from a DSM (a real DEM's 80-node site at 2 m, 0.05 m of noise, voids;
``benchmarks/dsm_voids.py``), the fitted nugget ranged 3.6e-6 to 2.4e-2 m² over the
subset's draws for the true 2.5e-3 m², and the truth fell inside the cells' 68 % band on
3-98 % of them (docs/terrain.md "Noise the samples do not state, from the dense windows").

The samples the subset leaves out are scored in windows given the subset near them
(:mod:`terrain.window_evidence`), at the lags the subset lacks. Their evidence, maximized
over the nugget alone at the chosen kernel, put the noise at 1.3-3.9e-3 m² on all 16 draws
of four real sites (the cells then 59-79 % in their 68 % band). :func:`window_noise` is that
estimate; :class:`terrain.TerrainGP` then refits the chosen family on the subset with the
nugget held there, so the kernel's short part no longer trades against it.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
from scipy.optimize import minimize_scalar

from .window_evidence import WindowPlan

__all__ = ["NOISE_SAMPLES", "NOISE_XATOL", "unstated_noise", "window_noise"]

#: Tolerance of the search in log nugget: 2 % of the variance.
NOISE_XATOL = 0.02
#: Left-out samples the estimate scores (every k-th window, spread over the site as the
#: plan orders them): one number needs fewer than the candidates' ranking.
NOISE_SAMPLES = 6_000


def unstated_noise(z_var: np.ndarray, windows: WindowPlan | None, fit_nugget: bool) -> bool:
    """Whether the nugget is the samples' whole noise and windows can measure it: no sample
    states a variance, the nugget is fitted, and left-out samples sit in windows."""
    return bool(fit_nugget and windows is not None and not np.any(z_var))


def window_noise(windows: WindowPlan, kernel: Any, bounds: tuple[float, float]) -> dict:
    """The nugget that maximizes the windows' evidence at ``kernel``.

    Parameters
    ----------
    windows : WindowPlan
        The left-out samples' windows, in the kernel's coordinates; every k-th is scored,
        about :data:`NOISE_SAMPLES` samples in all.
    kernel : Kernel
        The kernel the search chose (held).
    bounds : (float, float)
        The nugget's bounds, m^2.

    Returns
    -------
    dict
        ``nugget`` (m^2), ``window_lml`` (nats, at it), ``evaluations``, and the
        ``windows`` and ``samples_scored``.
    """
    lo, hi = np.log(float(bounds[0])), np.log(float(bounds[1]))
    step = max(1, int(np.ceil(windows.n_samples / NOISE_SAMPLES)))
    windows = _every(windows, step)
    # bounded Brent on log(nugget): the windows' evidence is smooth and one-peaked in it
    res = minimize_scalar(
        lambda u: -windows.lml(kernel, float(np.exp(u))),
        bounds=(lo, hi),
        method="bounded",
        options={"xatol": NOISE_XATOL},
    )
    return {
        "nugget": float(np.exp(res.x)),
        "window_lml": float(-res.fun),
        "evaluations": int(res.nfev),
        "windows": len(windows.X),
        "samples_scored": windows.n_samples,
    }


def _every(windows: WindowPlan, step: int) -> WindowPlan:
    """Every ``step``-th window of the plan (its counts left as the whole plan's)."""
    if step == 1:
        return windows

    def take(xs: list | None) -> list | None:
        return None if xs is None else xs[::step]

    fields = ("X", "r", "z_var", "X_near", "r_near", "z_var_near")
    return replace(windows, **{name: take(getattr(windows, name)) for name in fields})
