"""terrain.coregister: Nuth & Kääb co-registration on stable ground.

Reference values: the displacement is put in by construction -- the second DEM samples the
same continuous surface (a 1 m truth) on a lattice moved by a known vector, so nothing is
resampled with glacimap's own interpolator to make it. Peer: xDEM's NuthKaab on the same pair
(when xdem is installed).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from shapely.geometry import box

from terrain import Grid, InputError, coregister, random_terrain
from terrain.coregister import MIN_STABLE_CELLS, warp_to

ROOT = Path(__file__).resolve().parents[1]
W0, S0 = 500_000.0, 6_800_000.0  # UTM 8N


def rel_box(w, s, e, n):
    return box(W0 + w, S0 + s, W0 + e, S0 + n)


def _pair(fine, shift_cells=(3, 2), dz=1.0, noise=0.0, seed=0):
    """ref on even 1 m cells, dem = truth seen ``shift_cells`` (east, north) m away, +dz."""
    g = Grid.from_dataarray(fine)
    z = np.asarray(fine.values)
    se, sn = shift_cells
    rng = np.random.default_rng(seed)
    ref_v = z[10:-10:2, 10:-10:2]
    dem_v = z[10 + sn : z.shape[0] - 10 + sn : 2, 10 - se : z.shape[1] - 10 - se : 2] + dz
    gr = Grid(g.west + 10, g.north - 10, (2.0, 2.0), ref_v.shape, g.crs)
    ref = gr.data_array(ref_v + rng.normal(0, noise, ref_v.shape), "elevation")
    dem = gr.data_array(dem_v + rng.normal(0, noise, dem_v.shape), "elevation")
    return ref, dem


@pytest.fixture(scope="module")
def olinda_site():
    sys.path.insert(0, str(ROOT / "scripts"))
    import real_dems

    try:
        return real_dems.glacier_site("olinda", size_m=640.0, resolution=1.0)
    except real_dems.RealDataUnavailable as exc:
        pytest.skip(f"real DEM 'olinda' unavailable: {exc}")


@pytest.fixture(scope="module")
def synthetic_site():
    grid = Grid.from_bounds((W0, S0, W0 + 400, S0 + 400), 1.0)
    return random_terrain(grid, relief=30.0, seed=3, features=True)


@pytest.mark.parametrize("noise", [0.0, 0.1])
def test_recovers_known_shift_on_real_dem(olinda_site, noise):
    ref, dem = _pair(olinda_site, noise=noise)
    r = coregister(ref, dem)
    # issue 19: <= 0.2 m horizontally, <= 0.05 m vertically
    assert np.hypot(r.shift_east_m - 3.0, r.shift_north_m - 2.0) <= 0.2
    assert abs(r.vertical_bias_m - 1.0) <= 0.05
    assert r.converged and r.n_stable >= MIN_STABLE_CELLS
    assert r.nmad_after_m < 0.5 * r.nmad_before_m
    if noise:
        assert r.shift_east_std_m > 0 and r.vertical_bias_std_m > 0


def test_agrees_with_xdem(olinda_site):
    xdem = pytest.importorskip("xdem")
    import rasterio.crs

    ref, dem = _pair(olinda_site, noise=0.1)
    r = coregister(ref, dem)
    g = Grid.from_dataarray(ref)
    crs = rasterio.crs.CRS.from_wkt(g.crs.to_wkt())
    nk = xdem.coreg.NuthKaab().fit(ref.values, dem.values, transform=g.transform, crs=crs)
    a = nk.meta["outputs"]["affine"]  # xDEM gives the correction (minus the shift)
    assert r.shift_east_m == pytest.approx(-a["shift_x"], abs=0.05)
    assert r.shift_north_m == pytest.approx(-a["shift_y"], abs=0.05)
    assert r.vertical_bias_m == pytest.approx(-a["shift_z"], abs=0.02)


def test_tilt_and_apply_round_trip(synthetic_site):
    ref, dem = _pair(synthetic_site, shift_cells=(-2, 3), dz=-0.5)
    g = Grid.from_dataarray(dem)
    xy = g.xy()
    ramp = (2e-3 * (xy[:, 0] - W0 - 200) - 1e-3 * (xy[:, 1] - S0 - 200)).reshape(g.shape)
    dem = dem + ramp
    r = coregister(ref, dem, tilt=True)
    assert r.shift_east_m == pytest.approx(-2.0, abs=0.05)
    assert r.shift_north_m == pytest.approx(3.0, abs=0.05)
    assert r.tilt_east == pytest.approx(2e-3, abs=1e-4)
    assert r.tilt_north == pytest.approx(-1e-3, abs=1e-4)
    aligned = r.apply(dem)
    inner = (slice(5, -5), slice(5, -5))
    err = np.asarray(aligned.values)[inner] - np.asarray(ref.values)[inner]
    # cubic resampling of 30 m-relief terrain with crevasses, 2 m cells: measured max 0.050 m
    assert np.nanpercentile(np.abs(err), 99) < 0.02 and np.nanmax(np.abs(err)) < 0.1
    assert "coregistration" in aligned.attrs


def test_stable_polygons_and_outline_agree(synthetic_site):
    ref, dem = _pair(synthetic_site)
    glacier = rel_box(100, 100, 300, 300)
    # the glacier changes: thinning of 2 m inside the outline must not bias the fit
    g = Grid.from_dataarray(dem)
    xy = g.xy().reshape(*g.shape, 2) - [W0, S0]
    inside = (xy[..., 0] > 100) & (xy[..., 0] < 300) & (xy[..., 1] > 100) & (xy[..., 1] < 300)
    dem = dem - 2.0 * inside
    r1 = coregister(ref, dem, outline=glacier)
    r2 = coregister(ref, dem, stable=rel_box(0, 0, 400, 400).difference(glacier))
    assert r1.vertical_bias_m == pytest.approx(1.0, abs=0.02)
    assert r1.shift_east_m == pytest.approx(r2.shift_east_m, abs=1e-3)
    assert r1.stable_source == "cells outside the glacier outline"


def test_other_crs_is_reprojected(synthetic_site):
    from pyproj import Transformer

    ref, dem = _pair(synthetic_site)
    g = Grid.from_dataarray(dem)
    # the displaced DEM delivered in the next UTM zone (rotated by the grid convergence)
    t = Transformer.from_crs(g.crs, "EPSG:32609", always_xy=True)
    w, s = t.transform(g.west, g.north - g.resolution[1] * g.ny)
    target = Grid(round(w) - 40, round(s) + 440, (2.0, 2.0), (240, 240), "EPSG:32609")
    dem_other = target.data_array(warp_to(dem, target, "cubic"), "elevation")
    r = coregister(ref, dem_other)
    assert "reprojected from EPSG:32609" in r.method
    assert np.hypot(r.shift_east_m - 3.0, r.shift_north_m - 2.0) < 0.2
    assert r.vertical_bias_m == pytest.approx(1.0, abs=0.05)


def test_too_few_stable_cells_names_the_minimum(synthetic_site):
    ref, dem = _pair(synthetic_site)
    with pytest.raises(InputError, match=f"MIN_STABLE_CELLS = {MIN_STABLE_CELLS}"):
        coregister(ref, dem, stable=rel_box(0, 0, 20, 20))  # < 100 cells of 2 m


def test_bad_method():
    grid = Grid.from_bounds((W0, S0, W0 + 100, S0 + 100), 2.0)
    da = grid.data_array(np.zeros(grid.shape), "elevation")
    with pytest.raises(InputError, match="nuth_kaab"):
        coregister(da, da, method="icp")
