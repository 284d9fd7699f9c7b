"""One held-out fold's model: the map's fitted GP refitted on the fold's training samples.

:func:`terrain.cross_validate` and :func:`terrain.dem_choice.choose_dem_reading` score a
map on samples it did not see. Each fold's model is a clone of the estimator with the
map's hyperparameters held fixed (:func:`terrain.estimator_clone.fixed_overrides`), on the
same kind of GP as the map:

- a tiled map's folds get tiles whose halo reaches across the fold's own held-out gaps
  (:func:`terrain.tiled.tiles_reaching_gaps`): the map has no such gaps, and tiles that
  cannot reach across them predict the prior mean there (docs/terrain.md "Folds' tiles
  reach across their own gaps");
- a map that is exact only because of a long kernel part (more samples than
  ``exact_max_samples``) gets tiles with that part's halo (:mod:`terrain.long_halo`), and
  an exact fold where those tiles would be capped.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from .estimator_clone import clone, fixed_overrides, is_fitted
from .long_halo import long_halo_tiles
from .samples import ElevationSamples
from .tiled import tiles_reaching_gaps

__all__ = ["fold_predictor"]


def fold_predictor(
    estimator: Any, reference: Any, n_samples: int, fixed: bool = True
) -> Callable[[ElevationSamples], Any]:
    """A function that fits one fold's model and predicts its held-out points.

    Parameters
    ----------
    estimator : TerrainGP or estimator of the same shape
        The unfitted settings; never modified (every fold's model is a clone).
    reference : TerrainGP
        ``estimator`` fitted on all the samples: the hyperparameters held fixed. Unused
        when ``fixed`` is False.
    n_samples : int
        Samples in the whole survey (the map's): decides whether the map was exact only
        because of a long kernel part.
    fixed : bool
        Hold the reference's hyperparameters fixed (the held-out check's fast mode); False
        refits everything per fold.

    Returns
    -------
    callable
        ``fit_predict(train, xy) -> (model, mean, sd)``: the fold's model fitted on
        ``train`` (ElevationSamples) and its mean and latent 1-sigma (m) at ``xy`` (k, 2),
        m. (A capped long-halo tile is only known once predicted: the model is then
        refitted exact.)
    """
    overrides = fixed_overrides(reference) if fixed and is_fitted(reference) else {}
    long_tiles = None
    if overrides and getattr(reference, "method_", None) == "exact":
        if n_samples > getattr(reference, "exact_max_samples", math.inf):
            long_tiles = long_halo_tiles(reference)
    tiled = getattr(reference, "method_", None) == "tiled"

    def fit_predict(train: ElevationSamples, xy: np.ndarray) -> tuple[Any, np.ndarray, np.ndarray]:
        fold_overrides = overrides
        if overrides and tiled and getattr(estimator, "tiles", None) is None:
            geometry = reference.anisotropy_  # the fold's samples in the kernel's space
            fold_xy = geometry.apply(train.xy)
            fold_tiles = tiles_reaching_gaps(reference.kernel_, fold_xy, geometry.kernel_matrix)
            if reference.tiles_.far_share:  # the map's spread halo (terrain/long_halo.py)
                fold_tiles = reference.tiles_
            fold_overrides = {**overrides, "tiles": fold_tiles}
        elif overrides and long_tiles is not None:  # terrain/long_halo.py: no n^3 per fold
            fold_overrides = {**overrides, "method": "tiled", "tiles": long_tiles}
            fold_overrides["local_amplitude"] = False
        model = clone(estimator, **fold_overrides).fit(train)
        m, s = model.predict(xy, return_std=True)
        if (getattr(model, "tile_stats_", None) or {}).get("tiles_capped") and long_tiles:
            model = clone(estimator, **overrides).fit(train)  # exact, then
            m, s = model.predict(xy, return_std=True)
        return model, m, s

    return fit_predict
