"""The note that the paper's coarse 8 x 8 prior throws a finer DEM's resolution away."""

from __future__ import annotations

import numpy as np
import pytest

from terrain import Grid, RasterMean
from toolkit.stages import PRIOR_COARSENING_NOTE, prior_coarsening_note


def _dem(cell_m: float, side_m: float = 4000.0):
    g = Grid.from_bounds((500_000.0, 6_800_000.0, 500_000.0 + side_m, 6_800_000.0 + side_m), cell_m)
    x, y = g.xy().T
    return g.data_array(
        (1000.0 + 0.01 * (x - x.min()) + 0.02 * (y - y.min())).reshape(g.shape), "elevation"
    )


@pytest.mark.parametrize(
    ("cell_m", "map_m", "cells", "noted"),
    [
        (30.0, 3600.0, (8, 8), True),  # 450 m coarse cells from a 30 m DEM: 15 x
        (75.0, 600.0, (8, 8), False),  # the default site: 75 m into 8 x 8 of 75 m
        (30.0, 3600.0, None, False),  # the DEM's own cells: nothing thrown away
    ],
)
def test_prior_coarsening_note(cell_m, map_m, cells, noted):
    mean = RasterMean(_dem(cell_m), offset="none", cells=cells)
    grid = Grid.from_bounds((500_100.0, 6_800_100.0, 500_100.0 + map_m, 6_800_100.0 + map_m), 20.0)
    assert prior_coarsening_note(mean) is None  # not bound yet: nothing to say
    mean.for_grid(grid)
    note = prior_coarsening_note(mean)
    assert (note is not None) == noted
    if noted:
        assert f"{cell_m:.0f} m cells" in note and "[prior] cells = []" in note
        coarse = map_m / 8
        assert f"{coarse:.0f} m" in note and coarse >= PRIOR_COARSENING_NOTE * cell_m
    assert prior_coarsening_note("constant") is None
    np.testing.assert_equal(mean.cells, cells)
