"""Kernel matrices from a distance table (terrain/radial_table.py).

Reference values: each kernel's own closed form (R&W Eq 4.17, Eq 1) evaluated directly, and
for the slope a central finite difference of that closed form (hand computation of
d/dr, independent of the table's analytic derivative).
"""

from __future__ import annotations

import numpy as np
import pytest

import terrain.tiled as tiled
from terrain.kernels import Matern, SquaredExponential
from terrain.microscale import Microscale
from terrain.radial_table import MAX_STEPS, RadialTable, radial_profile, tabulate
from terrain.tiled import TileSpec, predict_tiled

KERNELS = {
    "se": SquaredExponential(4.0, 12.0),
    "matern32": Matern(30.0, 5.0, nu=1.5),
    "matern52": Matern(2.0, 20.0, nu=2.5),
    "matern72": Matern(3.0, 8.0, nu=3.5),
    "se+se+micro": SquaredExponential(6.8, 13.6)
    + SquaredExponential(29.5, 41.3)
    + Microscale(0.0026, 4.3),
    "long+short": Matern(77.0, 483.6, nu=2.5) + Matern(0.96, 80.4, nu=2.5),
}


@pytest.mark.parametrize("name", sorted(KERNELS))
def test_table_matches_closed_form(name):
    kernel = KERNELS[name]
    rng = np.random.default_rng(0)
    X = rng.uniform(-40, 40, (300, 2))
    Y = rng.uniform(-40, 40, (200, 2))
    table = tabulate(kernel, 80.0 * np.sqrt(2.0))
    assert table is not None
    exact = kernel(X, Y)
    # cubic Hermite at 256 steps per length scale: ~1e-11 of the variance (module docs)
    assert np.max(np.abs(table(X, Y) - exact)) <= 1e-10 * kernel.variance
    K = table(X)
    assert np.array_equal(K, K.T)  # the same distance gives the same bits
    assert np.all(np.diag(K) == table.variance)
    assert table.variance == pytest.approx(kernel.variance, rel=1e-15)
    assert np.all(table.diag(X) == table.variance)


@pytest.mark.parametrize("name", sorted(KERNELS))
def test_slope_against_finite_difference(name):
    kernel = KERNELS[name]
    r = np.linspace(0.3, 60.0, 50)
    h = 1e-5
    value, slope = radial_profile(kernel, r)
    plus, _ = radial_profile(kernel, r + h)
    minus, _ = radial_profile(kernel, r - h)
    fd = (plus - minus) / (2 * h)
    assert np.allclose(slope, fd, rtol=1e-6, atol=1e-9 * kernel.variance)
    direct = kernel(np.column_stack([r, np.zeros_like(r)]), np.zeros((1, 2)))[:, 0]
    assert np.allclose(value, direct, rtol=1e-14, atol=0.0)
    assert radial_profile(kernel, np.zeros(1))[1][0] == 0.0  # flat at the origin


def test_beyond_the_table_the_kernel_itself():
    kernel = KERNELS["matern52"]
    table = RadialTable(kernel, 10.0)
    X = np.array([[0.0, 0.0], [3.0, 0.0], [50.0, 0.0]])
    assert table.r_max >= 10.0
    # a distance of 50 m is past the table: every entry comes from the closed form
    assert np.array_equal(table(X), kernel(X))


def test_no_table_where_it_does_not_apply():
    assert tabulate(SquaredExponential(1.0, (10.0, 20.0)), 100.0) is None  # per-axis lengths
    assert tabulate(SquaredExponential(1.0, 10.0) + Matern(1.0, (5.0, 9.0)), 100.0) is None
    # 0.5 m length over 1 km: more than MAX_STEPS steps
    assert 1000.0 / 0.5 * 256 > MAX_STEPS
    assert tabulate(SquaredExponential(1.0, 0.5), 1000.0) is None
    assert tabulate(SquaredExponential(1.0, 0.5), np.inf) is None
    assert tabulate(SquaredExponential(1.0, 0.5), 100.0) is not None


def test_tiled_prediction_with_and_without_the_table(monkeypatch):
    rng = np.random.default_rng(3)
    X = rng.uniform(0, 120, (1500, 2))
    kernel = KERNELS["se+se+micro"]
    resid = np.sin(X[:, 0] / 9.0) * 2.0 + np.cos(X[:, 1] / 17.0) + rng.normal(0, 0.05, 1500)
    noise = np.full(1500, 0.05**2)
    g = np.arange(0.5, 120, 1.5)
    xq = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    spec = TileSpec(tile=24.0, blend=3.0, halo=36.0, max_points=400)
    mean, std, _ = predict_tiled(xq, X, resid, noise, kernel, spec, workers=2)
    monkeypatch.setattr(tiled, "tabulate", lambda *a: None)
    mean0, std0, _ = predict_tiled(xq, X, resid, noise, kernel, spec, workers=2)
    assert np.max(np.abs(mean - mean0)) < 1e-8  # m
    assert np.max(np.abs(std / std0 - 1.0)) < 1e-7


@pytest.mark.parametrize("name", sorted(KERNELS))
def test_compiled_lookup_gives_the_numpy_bits(name):
    # Reference: RadialTable._numpy_matrix, the lookup pass by pass in NumPy. The compiled
    # loop does the same operations in the same order, so every entry must be the same bits
    # (a reordered Horner step or a fused multiply-add would differ in the last digit).
    table = tabulate(KERNELS[name], 80.0 * np.sqrt(2.0))
    assert table._fill is not None, "Numba is a dependency: the compiled lookup must build"
    rng = np.random.default_rng(1)
    X = rng.uniform(-40, 40, (257, 2))
    Y = rng.uniform(-40, 40, (3, 130))[:2].T  # a strided view: copied to C order first
    assert np.array_equal(table(X, Y), table._numpy_matrix(X, Y))
    assert np.array_equal(table(X), table._numpy_matrix(X))
    assert table(X[:0], Y).shape == (0, 130)


def test_compiled_lookup_past_the_table_falls_back_to_the_kernel():
    kernel = KERNELS["matern52"]
    table = RadialTable(kernel, 10.0)
    X = np.array([[0.0, 0.0], [3.0, 0.0], [50.0, 0.0]])
    assert np.array_equal(table(X, X[::-1]), kernel(X, X[::-1]))


def test_a_scale_gives_the_bits_of_multiplying_after():
    # A tile's amplitude is applied inside the lookup (one pass fewer): the same IEEE
    # products as scaling the matrix after, in the compiled loop, its NumPy twin and past
    # the table (the closed form).
    kernel = KERNELS["se+se+micro"]
    table = tabulate(kernel, 80.0 * np.sqrt(2.0))
    rng = np.random.default_rng(2)
    X, Y = rng.uniform(-40, 40, (50, 2)), rng.uniform(-40, 40, (70, 2))
    for s in (0.37, 1.0, 2.9):
        assert np.array_equal(table(X, Y, s), table(X, Y) * s)
        assert np.array_equal(table(X, None, s), table(X) * s)
        assert np.array_equal(table._numpy_matrix(X, Y, s), table._numpy_matrix(X, Y) * s)
    short = RadialTable(KERNELS["matern52"], 10.0)
    far = np.array([[0.0, 0.0], [50.0, 0.0]])
    assert np.array_equal(short(far, None, 1.7), KERNELS["matern52"](far) * 1.7)
