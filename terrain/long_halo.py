"""Exact mean, tiled 1-sigma with a halo sized by the kernel's long part: big exact-GP grids.

An exact GP's mean costs ``n`` per cell (``k_*^T alpha``), its variance ``n^2`` (R&W Alg.
2.1 line 5): 5,920 GNSS fixes on 300 m lines and a 20 m grid of 20,000 cells took 68 s,
beyond the variance lattice's reach (:mod:`terrain.coarse_variance`: its spacing follows
the shortest length scale, 3.6 m, finer than the grid). The tiled GP's default halo (three
shortest length scales) cannot carry a kernel part whose length scale is longer
(:func:`terrain.tiled.long_scale_part`), so such kernels kept the exact route.

Here the mean stays exact and the 1-sigma comes from tiles whose halo is three length
scales of the *long* part (:data:`LONG_HALO_SCALES`): each tile conditions on the samples
within that distance, where the long part's correlation has fallen below 1.2 % (SE; a
Matérn's more slowly). A tile with more samples there than its budget
(``TileSpec.max_points``) keeps half nearest and spreads half over the halo
(:data:`FAR_SHARE`, ``TileSpec.far_share``). Conditioning on a subset of the data never
lowers a GP's posterior variance, so the tiles' GP term can only err on the wide side (a
fitted mean's coefficient term, R&W Eq 2.42, computed per tile, moves it by up to 0.1 %
either way). Measured against the exact 1-sigma (at random cells): the GNSS walk, tiles
not capped, within 1e-4; the same lines without a prior (a 221 m Matérn part, every tile
capped) median +0.14 %, at most +0.6 %; a real glacier's contours (a 2.1 km part, 8,338
samples) median 0, at most +1.2 %; tests/test_long_halo.py's small site at most +2.7 %
mid-gap. The route is taken only where it costs less than the exact variance (tiles x
budget^3 against n^2 per cell): not for scattered queries (each its own tile).
Measured on the walk: the map in 1 min 3 s instead of 2 min 36 s (docs/terrain.md
"Prediction route").
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from .exact_predict import predict_exact
from .tiled import long_scale_part, predict_tiled

__all__ = ["FAR_SHARE", "LONG_HALO_SCALES", "long_halo_tiles", "predict_long_halo"]

#: The halo, in length scales of the kernel's long part.
LONG_HALO_SCALES = 3.0
#: Share of a capped tile's budget spread over its halo for the 1-sigma (the rest nearest).
FAR_SHARE = 0.5


def long_halo_tiles(gp: Any) -> Any:
    """The fitted ``gp``'s tiles with the halo of its kernel's long part (three of that
    part's length scales), or None when the default tiles already hold every part."""
    long_part = long_scale_part(gp.kernel_, gp.tiles_.halo)
    if long_part is None:
        return None
    return replace(gp.tiles_, halo=LONG_HALO_SCALES * float(np.min(long_part.lengths)))


def predict_long_halo(
    gp: Any, xy: np.ndarray, include_nugget: bool
) -> tuple[np.ndarray, np.ndarray] | None:
    """Exact mean and long-halo tiled 1-sigma of a fitted exact ``gp`` at ``xy`` (m, 2), m.

    Returns
    -------
    (mean, std) or None
        Metres. ``gp.predict_route_`` says the route and halo, ``gp.tile_stats_`` holds
        :func:`terrain.tiled.predict_tiled`'s counts. None when the kernel has no long part,
        or the tiles would cost more than the exact variance (the caller predicts exactly).
    """
    spec = long_halo_tiles(gp) if gp.method_ == "exact" else None  # a tiled fit has no L
    if spec is None:
        return None
    Xq = gp._kernel_xy(xy)
    n = gp.X_train_.shape[0]
    area = float(np.prod(np.ptp(gp.X_train_, axis=0)) + 1.0)
    # tiles of 4 x 4 queries or more (one factor for 16 cells of a lattice), their own
    # region holding at most a quarter of the budget at the samples' mean density
    spacing = float(np.sqrt((np.prod(np.ptp(Xq, axis=0)) + 1.0) / Xq.shape[0]))
    roomy = np.sqrt(0.25 * spec.max_points * area / n) / 1.25
    tile = max(spec.tile, min(4.0 * spacing, roomy))
    spec = replace(spec, tile=tile, blend=tile / 8.0, far_share=FAR_SHARE)
    # cost: each tile factors the samples in its reach (at the samples' mean density, at
    # most its budget) and solves them per cell, against n^2 per cell exactly
    reach = (spec.tile + 2.0 * (spec.blend + spec.halo)) ** 2
    k = min(float(spec.max_points), n * min(1.0, reach / area))
    tiles = np.unique(np.floor(Xq / spec.tile).astype(np.int64), axis=0).shape[0]
    if tiles * (k**3 / 3.0 + 2.0 * k * k) + Xq.shape[0] * k * k >= float(n) ** 2 * Xq.shape[0]:
        return None  # scattered queries: a tile each, dearer than n^2 per query
    cov = getattr(gp, "coef_cov_", None)
    _, std, stats = predict_tiled(
        Xq,
        gp.X_train_,
        gp.y_resid_,
        gp.z_var_ + gp.nugget_,
        gp.kernel_,
        spec,
        True,
        amplitude_prior_sd=None,
        basis=None if cov is None else gp._basis_pair(xy, cov),
    )
    mean, _ = predict_exact(
        Xq,
        gp.X_train_,
        gp.L_,
        gp.alpha_,
        gp.kernel_,
        gp._chunk_rows(),
        np.asarray(gp.mean_(xy), dtype=float),
        False,
    )
    if include_nugget:
        std = np.sqrt(std**2 + gp.nugget_)
    capped = (
        f", {stats['tiles_capped']} of {stats['tiles']} tiles spread"
        if stats["tiles_capped"]
        else ""
    )
    gp.predict_route_ = f"exact mean, tiled 1-sigma (halo {spec.halo:.0f} m{capped})"
    gp.tile_stats_ = {**stats, "halo": spec.halo}
    return mean, std
