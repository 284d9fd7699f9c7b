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
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .heldout_weights import sample_spacing
from .kernels import Matern, _fmt

__all__ = ["MICROSCALE_MIN_SHARE", "Microscale", "microscale_part", "without_microscale"]

#: The fitted nugget becomes ground only above this share of the mean stated noise variance
#: (below it the part would change nothing).
MICROSCALE_MIN_SHARE = 1e-3


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
