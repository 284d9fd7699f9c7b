"""terrain.block_reduce: a dense cloud as one sample per block, unbiased on curved ground,
its variance measured from the points' scatter or carried from their stated noise."""

import numpy as np
import pytest

from terrain.block_samples import MIN_QUADRATIC, auto_block_size, block_reduce
from terrain.errors import InputError


def _surface(xy):
    """A curved surface: 0.2 slope, a 40 m wave (Laplacian up to 0.03 / m)."""
    x, y = xy[:, 0], xy[:, 1]
    return 100 + 0.2 * x + 0.1 * y + 1.2 * np.sin(x / 40.0) * np.cos(y / 40.0)


def test_a_quadratic_surface_is_recovered_exactly_at_each_centroid():
    # Hand value: a quadratic through 12+ points in general position is fitted exactly, so
    # each block's sample equals the quadratic at the block's centroid (to rounding).
    rng = np.random.default_rng(1)
    xy = rng.uniform(0, 60, (20_000, 2))
    z = 5 + 0.3 * xy[:, 0] - 0.2 * xy[:, 1] + 0.01 * xy[:, 0] ** 2 - 0.004 * xy[:, 0] * xy[:, 1]
    red = block_reduce(xy, z, 5.0)
    truth = 5 + 0.3 * red.xy[:, 0] - 0.2 * red.xy[:, 1] + 0.01 * red.xy[:, 0] ** 2
    truth -= 0.004 * red.xy[:, 0] * red.xy[:, 1]
    assert red.count.sum() == 20_000 and red.n == 144  # 12 x 12 blocks, nothing dropped
    np.testing.assert_allclose(red.z, truth, atol=1e-9)
    assert red.scatter_var < 1e-12  # m^2: rounding of sum dz^2 - beta.r


def test_block_means_would_be_biased_by_curvature_the_quadratic_is_not():
    # The mean of points spread evenly over a b-metre block sits b^2 / 24 * Laplacian above
    # the surface at the centroid (E[d_x^2] = b^2 / 12 per axis): 0.0375 m for b = 3,
    # Laplacian 0.1 / m. The quadratic's intercept has no such term.
    rng = np.random.default_rng(2)
    xy = rng.uniform(0, 30, (60_000, 2))
    z = 0.05 * (xy[:, 0] ** 2 + xy[:, 1] ** 2)  # Laplacian 0.2 / m everywhere
    red = block_reduce(xy, z, 3.0)
    truth = 0.05 * (red.xy[:, 0] ** 2 + red.xy[:, 1] ** 2)
    np.testing.assert_allclose(red.z, truth, atol=1e-9)
    means = np.bincount(
        np.floor(xy[:, 0] / 3).astype(int) * 10 + np.floor(xy[:, 1] / 3).astype(int), weights=z
    )
    assert means.size == 100  # the hand value the fix removes: mean - surface ~ 9 / 24 * 0.2
    assert 0.06 < np.median(np.abs(np.sort(means / red.count) - np.sort(red.z))) < 0.09


def test_the_noise_is_measured_from_the_scatter_and_calibrated():
    # Points with 0.1 m noise on a curved surface: the pooled scatter reads 0.1 m, and the
    # blocks' errors against the surface at their centroids have unit standardized spread.
    rng = np.random.default_rng(3)
    xy = rng.uniform(0, 300, (400_000, 2))
    z = _surface(xy) + rng.normal(0, 0.1, xy.shape[0])
    red = block_reduce(xy, z, 4.0)
    assert red.noise_source == "scatter"
    assert np.sqrt(red.scatter_var) == pytest.approx(0.1, rel=0.02)
    zs = (red.z - _surface(red.xy)) / np.sqrt(red.z_var)
    assert abs(zs.mean()) < 0.05 and zs.std() == pytest.approx(1.0, abs=0.05)
    assert "400,000 points reduced to" in red.note() and "0.0999 m" in red.note()


def test_stated_variances_are_carried_through_the_fit():
    # Every point states its variance: each block's variance is sum w_i^2 var_i with w the
    # intercept's weights -- for equal variances s^2 (M^-1)_00, checked against the stated
    # noise's own draw: standardized spread 1.
    rng = np.random.default_rng(4)
    xy = rng.uniform(0, 200, (200_000, 2))
    sd = np.where(xy[:, 0] < 100, 0.05, 0.2)
    z = _surface(xy) + rng.normal(0, 1, xy.shape[0]) * sd
    red = block_reduce(xy, z, 5.0, z_var=sd**2)
    assert red.noise_source == "stated"
    zs = (red.z - _surface(red.xy)) / np.sqrt(red.z_var)
    assert zs.std() == pytest.approx(1.0, abs=0.06)
    west = red.xy[:, 0] < 95
    assert np.median(red.z_var[~west]) / np.median(red.z_var[west]) == pytest.approx(16, rel=0.1)


def test_sparse_blocks_keep_their_mean_and_every_point_is_counted():
    # Blocks of fewer than MIN_QUADRATIC points (or points on one line) are their mean.
    xy = np.array([[0.5, 0.5], [1.5, 1.5], [2.5, 0.5], [10.5, 10.5]])
    z = np.array([1.0, 2.0, 3.0, 7.0])
    red = block_reduce(xy, z, 5.0)
    assert MIN_QUADRATIC > 3 and red.n == 2 and red.count.tolist() == [3, 1]
    np.testing.assert_allclose(red.z, [2.0, 7.0])
    np.testing.assert_allclose(red.xy, [[1.5, 2.5 / 3], [10.5, 10.5]])
    assert red.noise_source == "none" and np.all(red.z_var == 0)  # too few to measure


def test_same_points_same_bytes_and_the_lattice_can_be_shared():
    rng = np.random.default_rng(5)
    xy = rng.uniform(3, 97, (5_000, 2))
    z = _surface(xy) + rng.normal(0, 0.1, 5_000)
    a, b = block_reduce(xy, z, 10.0), block_reduce(xy, z, 10.0)
    assert a.z.tobytes() == b.z.tobytes() and a.z_var.tobytes() == b.z_var.tobytes()
    assert a.origin == (0.0, 0.0)
    c = block_reduce(xy, z, 10.0, origin=(-5.0, -5.0))  # another lattice: other blocks
    assert c.origin == (-5.0, -5.0) and c.n != a.n


def test_auto_size_keeps_at_most_the_samples_asked_for():
    rng = np.random.default_rng(6)
    xy = rng.uniform(0, 600, (300_000, 2))
    size = auto_block_size(xy, 50_000)
    assert size == 3.0  # 600^2 / 2.5^2 = 57,600 occupied blocks > 50,000; 3 m: 40,000
    strip = np.column_stack([rng.uniform(0, 6000, 300_000), rng.uniform(0, 20, 300_000)])
    assert auto_block_size(strip, 50_000) < 3.0  # a strip fills few blocks of its box


@pytest.mark.parametrize(
    "xy, z, size",
    [
        (np.zeros((3, 2)), np.zeros(2), 1.0),
        (np.zeros((0, 2)), np.zeros(0), 1.0),
        (np.array([[0.0, np.nan]]), np.zeros(1), 1.0),
        (np.zeros((1, 2)), np.zeros(1), -2.0),
    ],
)
def test_bad_points_are_refused_by_name(xy, z, size):
    with pytest.raises(InputError, match="points|block size"):
        block_reduce(xy, z, size)


def test_chunks_give_the_blocks_one_pass_gives(monkeypatch):
    # The accumulator's sums are the same whether the points come in one chunk or in many
    # (a cloud larger than memory), up to the order of summation.
    import terrain.block_samples as blocks

    rng = np.random.default_rng(7)
    xy = rng.uniform(0, 100, (30_000, 2))
    z = _surface(xy) + rng.normal(0, 0.1, 30_000)
    whole = block_reduce(xy, z, 5.0)
    monkeypatch.setattr(blocks, "CHUNK", 997)
    parts = block_reduce(xy, z, 5.0)
    assert parts.n == whole.n and np.array_equal(parts.count, whole.count)
    np.testing.assert_allclose(parts.xy, whole.xy, rtol=0, atol=1e-9)
    np.testing.assert_allclose(parts.z, whole.z, rtol=0, atol=1e-9)
    np.testing.assert_allclose(parts.z_var, whole.z_var, rtol=1e-9)
