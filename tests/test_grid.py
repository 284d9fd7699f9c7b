import numpy as np
import pytest
from rasterio.transform import from_origin
from rasterio.transform import xy as rio_xy

from terrain import CRSMismatchError, Grid, InputError
from terrain.grid import check_same_crs


def test_from_bounds_matches_rasterio_conventions():
    g = Grid.from_bounds((526000, 6475000, 526600, 6475600), 2.0)
    assert g.shape == (300, 300)
    assert g.bounds == (526000, 6475000, 526600, 6475600)
    # Reference: rasterio's own transform for the same origin and cell size.
    assert g.transform == from_origin(526000, 6475600, 2.0, 2.0)
    xs, ys = rio_xy(g.transform, [0, 299], [0, 299])  # rows, cols -> cell centres
    assert (g.x[0], g.y[0]) == (xs[0], ys[0])
    assert (g.x[-1], g.y[-1]) == (xs[1], ys[1])
    assert g.crs.to_epsg() == 32608


def test_xy_is_row_major_and_coords_roundtrip():
    g = Grid.from_bounds((0, 0, 30, 20), (10, 5))
    pts = g.xy()
    assert pts.shape == (12, 2)
    np.testing.assert_array_equal(pts[:3, 0], [5, 15, 25])
    assert pts[0, 1] == 17.5 and pts[-1, 1] == 2.5
    da = g.data_array(np.arange(12.0).reshape(4, 3), "elevation")
    assert Grid.from_dataarray(da) == g
    assert g.coarsen((2, 3)).resolution == (10.0, 10.0)


@pytest.mark.parametrize(
    "bounds, res",
    [
        ((0, 0, 0, 10), 1.0),
        ((0, 10, 10, 0), 1.0),
        ((0, 0, 10, 10), 0.0),
        ((0, 0, 10, 10), 50.0),
        ((0, 0, np.nan, 10), 1.0),
    ],
)
def test_empty_or_inverted_grid_rejected(bounds, res):
    with pytest.raises(InputError):
        Grid.from_bounds(bounds, res)


def test_crs_checks():
    with pytest.raises(InputError, match="projected"):
        Grid.from_bounds((0, 0, 10, 10), 1.0, crs="EPSG:4326")
    with pytest.raises(InputError, match="crs"):
        Grid.from_bounds((0, 0, 10, 10), 1.0, crs="not a crs")
    with pytest.raises(CRSMismatchError, match="32608"):
        check_same_crs(
            Grid.from_bounds((0, 0, 1, 1), 1).crs,
            Grid.from_bounds((0, 0, 1, 1), 1, crs=32607).crs,
            "samples",
            "grid",
        )
