"""Geometric anisotropy (terrain.anisotropy): the transform, its choice by evidence, and
every path of the engine in the kernel's coordinates.

References: hand-computed rotations; a GP drawn from a known anisotropic kernel (exact
Cholesky draw); the same isotropic GP fitted on coordinates transformed by hand; dense
posterior covariances for the volume integral.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from terrain import (
    Anisotropy,
    ElevationSamples,
    Grid,
    InputError,
    Matern,
    SquaredExponential,
    TerrainGP,
    cross_validate,
)
from terrain.volume import gp_integral, outline_weights

W0, S0 = 500_000.0, 6_800_000.0


def test_matrix_by_hand():
    # smooth axis to the east (azimuth 90), lengths twice as long along it
    a = Anisotropy(azimuth_deg=90.0, ratio=2.0)
    assert a.apply(np.array([[10.0, 0.0]]))[0] == pytest.approx([5.0, 0.0], abs=1e-12)
    assert np.linalg.norm(a.apply(np.array([[0.0, 10.0]]))) == pytest.approx(10.0)
    # azimuth 45 (north-east): a step along it is halved, across it kept
    b = Anisotropy(45.0, 2.0)
    d = 10.0 / math.sqrt(2.0)
    assert np.linalg.norm(b.apply(np.array([[d, d]]))) == pytest.approx(5.0)
    assert np.linalg.norm(b.apply(np.array([[d, -d]]))) == pytest.approx(10.0)
    # area-preserving form: determinant 1; an axis, not a direction: 225 deg is 45
    assert abs(np.linalg.det(b.matrix(area_preserving=True))) == pytest.approx(1.0)
    assert Anisotropy(225.0, 2.0).azimuth_deg == pytest.approx(45.0)
    iso = Anisotropy()
    xy = np.array([[1.0, 2.0]])
    assert iso.isotropic and iso.apply(xy) is xy
    assert "isotropic" in iso.describe() and "azimuth 45.0" in b.describe()


def test_bad_input_names_the_field():
    with pytest.raises(InputError, match="ratio"):
        Anisotropy(30.0, 0.5)
    with pytest.raises(InputError, match="azimuth_deg"):
        Anisotropy(float("nan"), 2.0)
    xy = np.random.default_rng(0).uniform(0, 100, (50, 2))
    s = ElevationSamples(xy, xy[:, 0] * 0.01, 0.01)
    with pytest.raises(InputError, match="anisotropy"):
        TerrainGP(anisotropy="diagonal").fit(s)


def _draw(aniso: Anisotropy, n: int = 900, seed: int = 3):
    """Samples of a zero-mean GP whose Matern 5/2 kernel has the geometry ``aniso``
    (length 12 m across the grain), by an exact Cholesky draw, plus 0.05 m noise."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform([W0, S0], [W0 + 240, S0 + 240], (n, 2))
    k = Matern(1.0, 12.0, nu=2.5)
    C = k(aniso.apply(xy - xy.mean(axis=0))) + 1e-8 * np.eye(n)
    f = np.linalg.cholesky(C) @ rng.standard_normal(n)
    z = 1000.0 + f + rng.normal(0.0, 0.05, n)
    return ElevationSamples(xy, z, 0.05**2)


def test_auto_recovers_a_known_grain_and_keeps_isotropic_ground_isotropic():
    true = Anisotropy(azimuth_deg=60.0, ratio=3.0)
    gp = TerrainGP(seed=0, anisotropy="auto").fit(_draw(true))
    got = gp.anisotropy_
    assert not got.isotropic
    off = abs((got.azimuth_deg - 60.0 + 90.0) % 180.0 - 90.0)  # axial difference, deg
    assert off <= 10.0 and 2.4 <= got.ratio <= 3.8  # measured: 61.9 deg, 3.07
    ev = gp.anisotropy_evidence_
    assert ev["kept"] and ev["delta_bic"] >= 6.0 and "Matern" in ev["pilot"]
    assert json.loads(gp.provenance()["anisotropy"])["ratio"] == pytest.approx(got.ratio)
    # the same ground without a grain: the evidence keeps the isotropic kernel
    iso = TerrainGP(seed=0, anisotropy="auto").fit(_draw(Anisotropy()))
    assert iso.anisotropy_.isotropic
    assert not iso.anisotropy_evidence_["kept"]
    # the default (None): no profile at all
    none = TerrainGP(seed=0).fit(_draw(true))
    assert none.anisotropy_.isotropic
    assert none.anisotropy_evidence_ is None


@pytest.mark.parametrize("method", ["exact", "tiled"])
def test_given_anisotropy_is_the_isotropic_gp_on_transformed_coordinates(method):
    aniso = Anisotropy(30.0, 2.5)
    s = _draw(aniso, n=600)
    k = Matern(1.0, 12.0, nu=2.5)
    fixed = {"kernel": k, "optimize": False, "nugget": 1e-4, "nugget_bounds": "fixed"}
    fixed["method"] = method
    gp = TerrainGP(anisotropy=aniso, **fixed).fit(s)
    # by hand: the centred coordinates mapped by A, an isotropic GP there
    centre = s.xy.mean(axis=0)
    moved = ElevationSamples(aniso.apply(s.xy - centre), s.z, s.z_var)
    ref = TerrainGP(anisotropy=None, **fixed).fit(moved)
    q = np.random.default_rng(1).uniform([W0, S0], [W0 + 240, S0 + 240], (200, 2))
    m, sd = gp.predict(q, return_std=True)
    m_ref, sd_ref = ref.predict(aniso.apply(q - centre), return_std=True)
    assert m == pytest.approx(m_ref, abs=1e-8)
    assert sd == pytest.approx(sd_ref, abs=1e-8)


def test_folds_keep_the_fitted_anisotropy():
    aniso = Anisotropy(120.0, 2.0)
    s = _draw(aniso, n=500)
    k = Matern(1.0, 12.0, nu=2.5)
    kw = {"kernel": k, "optimize": False, "nugget": 1e-4, "nugget_bounds": "fixed"}
    gp = TerrainGP(anisotropy=aniso, **kw).fit(s)
    cv = cross_validate(gp, s, block_size=60.0, n_folds=4, seed=0)
    for f in range(4):
        test = cv.fold == f
        by_hand = TerrainGP(anisotropy=aniso, **kw).fit(s.subset(~test))
        assert cv.prediction[test] == pytest.approx(by_hand.predict(s.xy[test]), abs=1e-8)


def test_volume_integral_in_the_kernels_space():
    """w^T Sigma_post w of an anisotropic GP against dense matrices built from the kernel on
    A x (R&W Eq 2.24 and 2.42)."""
    aniso = Anisotropy(45.0, 3.0)
    rng = np.random.default_rng(1)
    grid = Grid.from_bounds((W0, S0, W0 + 120, S0 + 120), 4.0)
    xy = rng.uniform([W0, S0], [W0 + 120, S0 + 120], (200, 2))
    s = ElevationSamples(xy, 1000 + np.sin(xy[:, 0] / 20.0), 0.01, crs=grid.crs)
    k = SquaredExponential(4.0, 15.0)
    gp = TerrainGP(
        kernel=k, optimize=False, nugget=1e-3, nugget_bounds="fixed", anisotropy=aniso
    ).fit(s)
    from shapely.geometry import box

    w = outline_weights(grid, box(W0 + 20, S0 + 20, W0 + 90, S0 + 100)).ravel()
    c = s.xy.mean(axis=0)
    X, q = aniso.apply(s.xy - c), aniso.apply(grid.xy() - c)
    A = np.linalg.inv(k(X) + np.diag(s.z_var + gp.nugget_))
    v = k(q, X).T @ w
    H, hq = np.ones((len(X), 1)), np.ones((len(q), 1))
    R = hq.T @ w - H.T @ A @ v
    ref = w @ k(q) @ w - v @ A @ v + R @ np.linalg.inv(H.T @ A @ H) @ R
    got = gp_integral(gp, grid, w.reshape(grid.shape))
    assert got["posterior_var_m6"] == pytest.approx(float(ref), rel=1e-5)


def test_gaps_and_density_are_the_surveys_in_the_kernels_space():
    """A rotated survey's bounding box has empty corners: measured in the kernel's space
    without the matrix they read as a 2-3x wider gap and a lower density. With it, a pure
    rotation gives the metric values, and a compression scales them by hand."""
    from terrain.tiled import largest_gap, sample_density

    xy = np.random.default_rng(0).uniform(0.0, 300.0, (3000, 2))
    rot = Anisotropy(30.0, 2.0).matrix()
    rot = rot / np.array([[0.5], [1.0]])  # rows back to unit length: the rotation alone
    moved = xy @ rot.T
    assert largest_gap(moved, matrix=rot) == pytest.approx(largest_gap(xy), rel=1e-9)
    assert largest_gap(moved) > 2.0 * largest_gap(xy)  # the corners
    assert sample_density(moved, rot) == pytest.approx(sample_density(xy), rel=1e-9)
    assert sample_density(moved) < 0.8 * sample_density(xy)
    # compressed along east by 2: area halves, density doubles
    a = Anisotropy(90.0, 2.0)
    assert sample_density(a.apply(xy), a.matrix()) == pytest.approx(2 * sample_density(xy))
