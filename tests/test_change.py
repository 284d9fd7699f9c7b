"""terrain.difference (dh on the finer common grid) and the simulated second epoch.

References: analytic surfaces evaluated at every cell centre (a plane, so bilinear
reprojection is exact up to rounding), hand-made shifts, and the change function's own stated
range (0.5-3 m of thinning).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from pyproj import Transformer
from shapely.geometry import box

from terrain import (
    Grid,
    InputError,
    default_outline,
    default_site,
    difference,
    random_terrain,
    second_epoch,
    surface_change,
)
from terrain.product import terrain_dataset
from terrain.synthetic import DEFAULT_SITE_BOUNDS

W0, S0 = 500_000.0, 6_800_000.0


def plane(x, y):
    return 1000.0 + 0.03 * (x - W0) - 0.02 * (y - S0)


def product(grid, f, std, **attrs):
    xx, yy = np.meshgrid(grid.x, grid.y)
    return terrain_dataset(grid, f(xx, yy), np.full(grid.shape, std), attrs)


def test_same_grid_difference_and_provenance():
    g = Grid.from_bounds((W0, S0, W0 + 100, S0 + 80), 2.0)
    b = product(g, plane, 0.3, seed=1, shared_vertical_offset_std_m=0.1, method="exact GP")
    a = product(g, lambda x, y: plane(x, y) - 1.5, 0.4, seed=2)
    d = difference(b, a, coregister=False)
    np.testing.assert_allclose(d["dh"].values, -1.5, atol=1e-12)
    np.testing.assert_allclose(d["dh_std"].values, 0.5, atol=1e-12)  # 3-4-5
    assert d.attrs["before_seed"] == 1 and d.attrs["after_seed"] == 2
    assert d.attrs["before_shared_vertical_offset_std_m"] == 0.1
    assert d.attrs["coregistration"] == "none" and d.attrs["reprojection"] == "same CRS"
    assert Grid.from_dataarray(d) == g


def test_finer_grid_wins_and_overlap_is_cut():
    fine = Grid.from_bounds((W0 + 20, S0, W0 + 120, S0 + 100), 1.0)
    coarse = Grid.from_bounds((W0, S0 + 10, W0 + 100, S0 + 110), 4.0)
    d = difference(product(coarse, plane, 0.2), product(fine, plane, 0.2), coregister=False)
    g = Grid.from_dataarray(d)
    assert g.resolution == (1.0, 1.0)
    assert g.bounds == (W0 + 20, S0 + 10, W0 + 100, S0 + 100)
    assert d.attrs["grid_source"].startswith("after")
    inner = d["dh"].values[3:-3, 3:-3]  # bilinear of a plane is the plane
    np.testing.assert_allclose(inner, 0.0, atol=1e-9)


def test_other_crs_is_reprojected_and_stated():
    g = Grid.from_bounds((W0, S0, W0 + 200, S0 + 200), 2.0)
    t = Transformer.from_crs(g.crs, "EPSG:32609", always_xy=True)
    w, s = t.transform(W0, S0)
    g9 = Grid.from_bounds((w - 50, s - 50, w + 260, s + 260), 4.0, "EPSG:32609")
    inv = Transformer.from_crs("EPSG:32609", g.crs, always_xy=True)

    def plane9(x, y):
        return plane(*inv.transform(x, y)) + 2.0

    d = difference(product(g, plane, 0.2), product(g9, plane9, 0.2), coregister=False)
    assert "reprojected from EPSG:32609 to EPSG:32608" in d.attrs["reprojection"]
    dh = d["dh"].values
    assert np.nanmedian(dh) == pytest.approx(2.0, abs=1e-3)


def test_non_overlapping_is_an_error():
    a = Grid.from_bounds((W0, S0, W0 + 100, S0 + 100), 2.0)
    b = Grid.from_bounds((W0 + 500, S0, W0 + 600, S0 + 100), 2.0)
    with pytest.raises(InputError, match="overlap"):
        difference(product(a, plane, 0.1), product(b, plane, 0.1), outline=box(0, 0, 1, 1))
    with pytest.raises(InputError, match="stable ground"):  # co-registration needs it
        difference(product(a, plane, 0.1), product(a, plane, 0.1))


def test_coregistered_difference_removes_shift():
    fine = random_terrain(Grid.from_bounds((W0, S0, W0 + 400, S0 + 400), 1.0), 30.0, seed=4)
    z = fine.values
    g = Grid.from_dataarray(fine)
    gr = Grid(g.west + 10, g.north - 10, (2.0, 2.0), (190, 190), g.crs)
    before = gr.data_array(z[10:390:2, 10:390:2], "elevation")
    after = gr.data_array(z[12:392:2, 7:387:2] + 0.7, "elevation")  # 3 m E, 2 m N, +0.7 m
    glacier = box(W0 + 150, S0 + 150, W0 + 250, S0 + 250)
    xy = gr.xy().reshape(*gr.shape, 2)
    on_ice = (abs(xy[..., 0] - W0 - 200) < 50) & (abs(xy[..., 1] - S0 - 200) < 50)
    after = after - 2.0 * on_ice
    d = difference(before, after, coregister=True, outline=glacier)
    co = json.loads(d.attrs["coregistration"])
    assert co["shift_east_m"] == pytest.approx(3.0, abs=0.05)
    assert co["vertical_bias_m"] == pytest.approx(0.7, abs=0.02)
    dh = d["dh"].values
    assert np.nanmedian(np.abs(dh[~on_ice])) < 0.02  # stable ground flat after alignment
    assert np.nanmedian(dh[on_ice]) == pytest.approx(-2.0, abs=0.05)
    assert np.isnan(d["dh_std"]).all() and "none" in d.attrs["dh_std_source"]


def test_surface_change_range_seed_and_stable_ground():
    truth = default_site(resolution=4.0)
    outline = default_outline(DEFAULT_SITE_BOUNDS)
    a = surface_change(truth, outline, seed=3, n_features=0, taper_m=0.0)
    dh, z = a.values, truth.values
    inside = dh != 0
    assert inside.mean() == pytest.approx(outline.area / 600.0**2, rel=0.02)
    # thinning 0.5-3 m, strongest at the lowest glacier cell
    assert dh[inside].min() == pytest.approx(-3.0, abs=1e-9)
    assert dh[inside].max() == pytest.approx(-0.5, abs=1e-9)
    assert np.corrcoef(dh[inside], z[inside])[0, 1] > 0.99
    b1 = surface_change(truth, outline, seed=3)
    np.testing.assert_array_equal(b1.values, surface_change(truth, outline, seed=3).values)
    assert not np.array_equal(b1.values, surface_change(truth, outline, seed=4).values)
    assert np.all(b1.values[~inside] == 0.0)  # stable ground unchanged
    after = second_epoch(truth, outline, seed=3)
    np.testing.assert_allclose(after.values - truth.values, b1.values)
    assert after.attrs["change_seed"] == 3
    with pytest.raises(InputError, match="min_thinning"):
        surface_change(truth, outline, min_thinning_m=2.0, max_thinning_m=1.0)
