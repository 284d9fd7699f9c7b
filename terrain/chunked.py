"""Maps bigger than memory: ``TerrainGP.predict_grid(grid, chunks=...)`` through Dask.

Each block of the grid is predicted independently from the fitted GP (exact or tiled) when
it is computed, so peak memory is one block's worth of work, whatever the grid size. The
blocks run on the active ``dask.distributed`` client when there is one (a cluster spreads
them), otherwise on Dask's local threaded scheduler.
"""

from __future__ import annotations

import numpy as np

from .errors import bad_input
from .grid import Grid
from .product import terrain_dataset

__all__ = ["predict_grid_dask"]


def _block(_template, gp, grid: Grid, include_nugget: bool, block_info=None) -> np.ndarray:
    (r0, r1), (c0, c1) = block_info[None]["array-location"][1:]
    sub = Grid(
        grid.west + c0 * grid.resolution[0],
        grid.north - r0 * grid.resolution[1],
        grid.resolution,
        (r1 - r0, c1 - c0),
        grid.crs,
    )
    mean, std = gp.predict(sub.xy(), return_std=True, include_nugget=include_nugget)
    return np.stack([mean.reshape(sub.shape), std.reshape(sub.shape)]).astype(np.float64)


def predict_grid_dask(gp, grid: Grid, chunks, include_nugget: bool = False):
    """Dask-backed ``xarray.Dataset`` (``elevation``, ``elevation_std``) of ``gp`` on ``grid``.

    Parameters
    ----------
    gp : TerrainGP
        A fitted GP.
    grid : Grid
        Cells to predict.
    chunks : int or (int, int)
        Rows and columns per block.
    """
    import dask.array as da

    rows, cols = (int(c) for c in np.broadcast_to(np.asarray(chunks), (2,)))
    if rows < 1 or cols < 1:
        raise bad_input("chunks", chunks, "positive block sizes (rows, columns)", "e.g. 1024")
    template = da.zeros((2, *grid.shape), chunks=(2, rows, cols), dtype=np.float64)
    both = da.map_blocks(
        _block,
        template,
        gp=gp,
        grid=grid,
        include_nugget=include_nugget,
        dtype=np.float64,
        chunks=template.chunks,
        name="glacimap-gp-block",
    )
    return terrain_dataset(grid, both[0], both[1], {**gp.provenance(), "chunks": [rows, cols]})
