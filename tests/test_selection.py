import numpy as np
import pytest

from terrain import ElevationSamples, InputError, Matern, SquaredExponential
from terrain.selection import compare_kernels


def _gp_draw(kernel, n=300, noise=0.05, seed=0):
    # Data drawn from a known GP: the evidence must prefer the family that generated it.
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, 200, (n, 2))
    K = kernel(xy) + 1e-8 * np.eye(n)
    z = np.linalg.cholesky(K) @ rng.normal(size=n) + rng.normal(0, noise, n)
    return ElevationSamples(xy, z, noise**2)


CANDIDATES = {
    "se": SquaredExponential(1.0, 20.0),
    "matern15": Matern(1.0, 20.0, nu=1.5),
    "matern25": Matern(1.0, 20.0, nu=2.5),
}


@pytest.mark.parametrize(
    "truth, expected",
    [(Matern(4.0, 25.0, nu=1.5), "matern15"), (SquaredExponential(4.0, 25.0), "se")],
)
def test_evidence_prefers_the_generating_family(truth, expected):
    rows = compare_kernels(
        _gp_draw(truth),
        CANDIDATES,
        mean=0.0,
        nugget=0.0,
        nugget_bounds="fixed",
        n_restarts=1,
        seed=0,
    )
    assert rows[0]["name"] == expected
    assert rows[0]["delta_lml"] == 0.0 and all(r["delta_lml"] <= 0 for r in rows)


def test_no_candidates_rejected():
    with pytest.raises(InputError, match="kernels"):
        compare_kernels(_gp_draw(SquaredExponential(1.0, 10.0), n=10), {})
