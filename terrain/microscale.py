"""Ground that varies faster than the fit subset can show: the nugget beyond the samples'
stated noise, kept in the map's 1-sigma as a short kernel part.

A nugget is measurement error plus variation below the data's smallest lag (Cressie 1993,
Statistics for Spatial Data, Section 3.2.1). When the samples state their noise (``z_var``),
a fitted nugget on top of it is the second kind: ground that varies faster than the
2,000-sample fit subset's spacing. As white noise it tells the map to smooth that ground away
and leaves it out of ``elevation_std``: on real DEMs at 50,000 samples with a coarse prior
mean, rough or faceted ground read 47-66 % at 68 and 77-92 % at 95 (docs/terrain.md "Ground
shaped another way"). As a Matérn 3/2 part whose variance is the nugget and whose length is
the fit subset's median nearest-neighbour spacing, the dense data resolve what they can and
the gaps carry the rest.

With ``z_var = 0`` the nugget *is* the noise, and a nugget held fixed (``nugget_bounds=
"fixed"``) is the user's: both stay white.

The fitted nugget is placed by the random order of the refine's Vecchia plan where the
subset's likelihood cannot tell it from none, so where the samples left out of the subset
sit in windows (:mod:`terrain.window_evidence`), the part is averaged over its lengths and
none, weighted by their exact evidence (:func:`windowed_part`).
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from .heldout_weights import sample_spacing
from .kernels import Matern, SumKernel, _fmt

__all__ = [
    "MICROSCALE_MIN_SHARE",
    "PART_LENGTHS",
    "PART_MIN_WEIGHT",
    "Microscale",
    "microscale_part",
    "windowed_part",
    "without_microscale",
]

#: The fitted nugget becomes ground only above this share of the mean stated noise variance
#: (below it the part would change nothing).
MICROSCALE_MIN_SHARE = 1e-3
#: Lengths the part may take, in the fit subset's spacings (``None``: no part), scored by
#: the left-out samples' window evidence (:func:`windowed_part`).
PART_LENGTHS = (1.0, 4.0, None)
#: An option whose evidence weight is at most this share is left out of the averaged part.
PART_MIN_WEIGHT = 1e-3


@dataclass(frozen=True, repr=False)
class Microscale(Matern):
    """Matérn 3/2 part for ground below the fit subset's spacing (see module docstring).

    Tiles are sized without it (:func:`terrain.tiled.shortest_lengthscale`,
    :func:`terrain.tiled.long_scale_part`): it is resolved by the dense data or not at all.
    """

    nu: float = 1.5

    def __repr__(self) -> str:
        return f"Microscale(variance={self.variance:.4g}, lengthscale={_fmt(self)})"


def without_microscale(kernel: Any) -> tuple:
    """The parts of ``kernel`` other than :class:`Microscale` ones."""
    parts = getattr(kernel, "parts", (kernel,))
    return tuple(p for p in parts if not isinstance(p, Microscale)) or parts


def microscale_part(
    kernel: Any, nugget: float, z_var: np.ndarray, X_fit: np.ndarray, fitted: bool
) -> Microscale | None:
    """The :class:`Microscale` part for a fit, or ``None``.

    Parameters
    ----------
    kernel : Kernel or SumKernel
        The fitted kernel (a kernel that already has the part gets no second one).
    nugget : float
        The fitted nugget beyond the stated noise, m^2.
    z_var : ndarray of shape (n,)
        The samples' stated noise variance, m^2.
    X_fit : ndarray of shape (m, 2)
        The fit subset's locations, m: its median nearest-neighbour spacing is the length.
    fitted : bool
        Whether the nugget was fitted (a fixed nugget stays white).
    """
    stated = float(np.mean(z_var)) if np.size(z_var) else 0.0
    parts = getattr(kernel, "parts", (kernel,))
    if not fitted or stated <= 0.0 or any(isinstance(p, Microscale) for p in parts):
        return None
    floor = max(MICROSCALE_MIN_SHARE * stated, Matern.variance_bounds[0])
    if nugget <= floor or len(X_fit) < 3:
        return None
    length = max(sample_spacing(X_fit), Matern.lengthscale_bounds[0])
    return Microscale(variance=float(nugget), lengthscale=length)


def windowed_part(
    kernel: Any, part: Microscale, nugget: float, windows: Any, scores: list | None = None
) -> Microscale | SumKernel | None:
    """The part averaged over its lengths, and none, by the evidence of the left-out samples.

    The fitted nugget is placed by the random order of the refine's Vecchia plan (on real
    DEMs at 50,000 samples ~0 to 2.8e-3 m^2 over four orders), and the part's length is as
    strong a lever on the 1-sigma as its variance. The window evidence
    (:mod:`terrain.window_evidence`: exact, on the dense lags, its windows drawn apart from
    the refine's plan) scores the part at each of :data:`PART_LENGTHS`. The options are
    averaged with their evidence as weights, ``w_i = exp(l_i) / sum_j exp(l_j)`` (Bayesian
    model averaging with equal prior odds; Hoeting et al. 1999, Statist. Sci. 14: 382), and
    the average is moment-matched: one Gaussian process whose covariance is the weighted
    mean of the options', i.e. the part at length ``f_i`` keeps ``w_i`` of the variance.
    Decisive evidence picks one option; where the windows cannot tell the options apart
    (bei at 50k, one refine order: 6e-4 m^2, none ahead by 0.1 nats) no one of them takes
    the map (docs/terrain.md "The part averaged by the window evidence", session 31).

    Parameters
    ----------
    kernel : Kernel or SumKernel
        The fitted kernel, without the part.
    part : Microscale
        The part from :func:`microscale_part`.
    nugget : float
        The white nugget beside the part, m^2.
    windows : terrain.window_evidence.WindowPlan or None
        ``None``, or a plan without windows: the part is kept as it is.
    scores : list of dict, optional
        The kernel search's rows: the selected one records ``microscale_window_lml`` (the
        options' window evidence, nats) and ``microscale_weights``.

    Returns
    -------
    Microscale, SumKernel of Microscale parts, or None
        The options with weight above :data:`PART_MIN_WEIGHT`, each with its share of the
        part's variance; ``None`` when no part keeps any.
    """
    if windows is None or not windows.X:
        return part
    options = [
        None if f is None else replace(part, lengthscale=part.lengthscale * f) for f in PART_LENGTHS
    ]

    def lml(option: Microscale | None) -> float:
        return windows.lml(kernel if option is None else kernel + option, nugget)

    workers = max(1, min(len(options), os.cpu_count() or 1))
    with threadpool_limits(1), ThreadPoolExecutor(max_workers=workers) as pool:
        got = np.array(list(pool.map(lml, options)))
    weights = np.exp(got - got.max())
    weights /= weights.sum()
    kept = tuple(
        replace(option, variance=option.variance * float(w))
        for option, w in zip(options, weights, strict=True)
        if option is not None and w > PART_MIN_WEIGHT
    )
    row = next((r for r in scores or () if r.get("selected")), None)
    if row is not None:
        names = ["none" if f is None else f"x{f:g}" for f in PART_LENGTHS]
        row["microscale_window_lml"] = dict(zip(names, got.tolist(), strict=True))
        row["microscale_weights"] = dict(zip(names, weights.tolist(), strict=True))
    return None if not kept else kept[0] if len(kept) == 1 else SumKernel(kept)
