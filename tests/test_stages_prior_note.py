"""The note that the paper's coarse 8 x 8 prior throws a finer DEM's resolution away."""

from __future__ import annotations

import numpy as np
import pytest

from terrain import Grid, RasterMean
from terrain.raster_mean import AUTO_OWN_FACTOR
from toolkit.stages import prior_coarsening_note


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
        assert f"{coarse:.0f} m" in note and coarse >= AUTO_OWN_FACTOR * cell_m
    assert prior_coarsening_note("constant") is None
    np.testing.assert_equal(mean.cells, cells)


@pytest.mark.parametrize(
    ("cell_m", "map_m", "resolved"),
    [
        (30.0, 3600.0, None),  # 450 m paper cells from a 30 m DEM: its own cells
        (30.0, 600.0, None),  # a 30 m SRTM-like DEM over the 600 m site: 75 / 30 = 2.5 x
        (75.0, 600.0, (8, 8)),  # the default site's 75 m prior: the paper's 8 x 8
        (100.0, 600.0, (8, 8)),  # a DEM coarser than the paper's cells
    ],
)
def test_auto_cells_take_the_dem_when_it_is_finer(cell_m, map_m, resolved):
    """``cells="auto"`` (the pipeline's default ``[prior] cells``) resolves at the first
    bind: the paper's 8 x 8 unless the DEM's own cells are >= 2 x finer."""
    mean = RasterMean(_dem(cell_m), offset="none", cells="auto")
    assert mean.cells is None and mean.cells_auto
    grid = Grid.from_bounds((500_100.0, 6_800_100.0, 500_100.0 + map_m, 6_800_100.0 + map_m), 20.0)
    mean.for_grid(grid)
    assert mean.cells == resolved
    assert mean.describe()["cells_rule"] == "auto"
    assert prior_coarsening_note(mean) is None  # auto never throws the DEM away


def test_prior_cells_setting():
    from terrain import InputError
    from toolkit.config import load_scenario
    from toolkit.processing import prior_mean

    assert load_scenario()["prior"]["cells"] == "auto"
    dem = _dem(75.0)
    assert prior_mean(dem, load_scenario()).cells_auto
    paper = prior_mean(dem, load_scenario(overrides={"prior": {"cells": [8, 8]}}))
    assert paper.cells == (8, 8) and not paper.cells_auto
    own = prior_mean(dem, load_scenario(overrides={"prior": {"cells": []}}))
    assert own.cells is None and not own.cells_auto
    with pytest.raises(InputError, match="prior.cells"):
        load_scenario(overrides={"prior": {"cells": "paper"}})


def test_prior_coarse_setting():
    from terrain import InputError
    from toolkit.config import load_scenario
    from toolkit.processing import prior_mean

    dem = _dem(75.0)
    assert load_scenario()["prior"]["coarse"] == "mesh"
    assert prior_mean(dem, load_scenario()).coarse == "mesh"
    area = {"prior": {"cells": [8, 8], "coarse": "area-means"}}
    assert prior_mean(dem, load_scenario(overrides=area)).coarse == "area-means"
    with pytest.raises(InputError, match=r"prior\.coarse"):
        load_scenario(overrides={"prior": {"coarse": "triangles"}})


def test_printed_warnings_keep_bracketed_table_names():
    """Rich markup used to eat "[prior]" from printed warnings (" cells = []")."""
    from rich.console import Console

    from toolkit.cli._progress import print_warnings

    console = Console(width=200)
    cert = {
        "warnings": ["set [prior] cells = [] to use the DEM's own resolution"],
        "heldout_calibration": {"verdict": ["see [certify] heldout_folds"]},
    }
    with console.capture() as cap:
        print_warnings(console, cert)
    out = cap.get()
    assert "set [prior] cells = []" in out and "see [certify] heldout_folds" in out
