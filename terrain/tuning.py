"""The paper's own hyperparameter tuning (Section II-D): grid search against ground truth.

The paper gave the GP "a small segment of the terrain", varied alpha and gamma over a large
range and kept the pair with the lowest reconstruction error (alpha = 10, gamma = 315). We
reproduce that procedure; maximizing Eq 9 (``TerrainGP(optimize=True)``) needs no truth and
is the default everywhere else.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .errors import bad_input
from .gp import TerrainGP
from .grid import Grid, north_up
from .kernels import PaperReading, SquaredExponential
from .metrics import rmse
from .samples import ElevationSamples

__all__ = ["PaperTuning", "tune_paper_grid"]


@dataclass(frozen=True)
class PaperTuning:
    """Result of :func:`tune_paper_grid`.

    Attributes
    ----------
    alpha, gamma : float
        The pair with the lowest RMSE on the truth patch.
    reading : str
        Which reading of gamma the numbers use (see ``SquaredExponential.from_paper``).
    rmse_table : ndarray of shape (len(alphas), len(gammas))
        RMSE (m) of every pair on the truth patch.
    kernel : SquaredExponential
        The kernel of the best pair.
    """

    alpha: float
    gamma: float
    reading: str
    rmse_table: np.ndarray
    alphas: np.ndarray
    gammas: np.ndarray
    kernel: SquaredExponential


def tune_paper_grid(
    samples: ElevationSamples,
    truth_patch: Any,
    alphas: np.ndarray,
    gammas: np.ndarray,
    *,
    reading: PaperReading,
    mean: Any = "constant",
    nugget: float = 0.0,
) -> PaperTuning:
    """Grid-search the paper's (alpha, gamma) by RMSE against a patch of ground truth.

    Parameters
    ----------
    samples : ElevationSamples
        Training samples (typically those inside or near the patch).
    truth_patch : xarray.DataArray
        True elevations on a small grid (dims y, x, with CRS attrs), m.
    alphas, gammas : array-like
        Candidate kernel variances (m^2) and gammas (m^2 or m, by ``reading``).
    reading : {"squared_lengthscale", "lengthscale"}
        How to read gamma (Eq 1 literally, or the prose); required so every number is labelled.
    mean, nugget
        As in :class:`TerrainGP`; the nugget stays fixed.
    """
    alphas = np.atleast_1d(np.asarray(alphas, dtype=float))
    gammas = np.atleast_1d(np.asarray(gammas, dtype=float))
    if alphas.size < 1 or gammas.size < 1:
        raise bad_input("alphas/gammas", (alphas.size, gammas.size), "non-empty", "")
    truth_patch = north_up(truth_patch)  # values in the order of grid.xy()
    grid = Grid.from_dataarray(truth_patch)
    truth = np.asarray(truth_patch.values, dtype=float).ravel()
    query = grid.xy()
    table = np.empty((alphas.size, gammas.size))
    for i, a in enumerate(alphas):
        for j, g in enumerate(gammas):
            kernel = SquaredExponential.from_paper(a, g, reading=reading)
            gp = TerrainGP(
                kernel=kernel, mean=mean, nugget=nugget, nugget_bounds="fixed", optimize=False
            ).fit(samples)
            table[i, j] = rmse(gp.predict(query), truth)
    i, j = np.unravel_index(np.nanargmin(table), table.shape)
    return PaperTuning(
        alpha=float(alphas[i]),
        gamma=float(gammas[j]),
        reading=reading,
        rmse_table=table,
        alphas=alphas,
        gammas=gammas,
        kernel=SquaredExponential.from_paper(alphas[i], gammas[j], reading=reading),
    )
