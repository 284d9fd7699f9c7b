"""The survey's gaps and sample density, measured in metres or in a kernel's space.

A tiled GP sizes its tiles by the samples' density and grows a tile's halo to reach across
the survey's widest gap (:mod:`terrain.tiled`). Under a geometric anisotropy
(:mod:`terrain.anisotropy`) the samples are given in the kernel's space ``x @ A.T``; there
the survey's bounding box is rotated, and its empty corners would read as gaps and as lost
density. So the box is always the survey's in metres, mapped into that space.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .heldout_design import default_targets

__all__ = ["largest_gap", "sample_density"]


def _metric(xy: np.ndarray, matrix: np.ndarray | None) -> np.ndarray:
    """Coordinates in metres of samples given in a kernel's space ``xy = x @ matrix.T``
    (:mod:`terrain.anisotropy`); ``xy`` itself without a matrix."""
    xy = np.asarray(xy, dtype=float)
    return xy if matrix is None else xy @ np.linalg.inv(matrix).T


def sample_density(xy: np.ndarray, matrix: np.ndarray | None = None) -> float:
    """Samples per m^2 over the bounding box of ``xy`` (n, 2), m; ``nan`` when the box has
    no area (one sample, or all on a line along x or y). ``matrix``: ``xy`` are in a
    kernel's space (an anisotropy's ``A``): the box is the survey's in metres, its area
    mapped by ``|det A|`` (a rotated box would count its empty corners)."""
    m = _metric(xy, matrix)
    area = float(np.ptp(m[:, 0]) * np.ptp(m[:, 1])) if len(m) else 0.0
    if matrix is not None:
        area *= abs(float(np.linalg.det(matrix)))
    return len(m) / area if area > 0 else float("nan")


def largest_gap(xy: np.ndarray, n_side: int = 100, matrix: np.ndarray | None = None) -> float:
    """Largest distance from a point of the samples' bounding box to its nearest sample, m:
    the widest gap in the survey, measured on an ``n_side`` x ``n_side`` lattice of the box
    (:func:`terrain.heldout_design.default_targets`). A tile sees data within its halo, so a
    long-scale kernel part is held by the data (no reversion to the prior mean inside the
    survey) when this is at most the halo. ``matrix``: ``xy`` are in an anisotropy's kernel
    space; the lattice is the survey's box in metres, mapped there, and the distance is the
    kernel's (a rotated box's empty corners read as gaps)."""
    targets = default_targets(_metric(xy, matrix), n_side)
    if matrix is not None:
        targets = targets @ matrix.T
    return float(cKDTree(xy).query(targets)[0].max())
