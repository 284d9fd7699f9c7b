"""The simulated satellite DEM (``toolkit.field_survey.simulated_prior``) covers more than the
site, as a real one does: a landmark estimated just outside the site still has a prior.
Reference values: a plane, whose block averages are its values at the coarse cell centres
(hand computation), continued linearly into the margin by the odd reflection."""

from __future__ import annotations

import numpy as np

from terrain import Grid
from toolkit.field_survey import simulated_prior


def test_prior_extends_one_cell_past_the_site_and_continues_a_plane():
    g = Grid.from_bounds((526_000.0, 6_475_000.0, 526_600.0, 6_475_600.0), 2.0, "EPSG:32608")
    x, y = g.xy().T
    truth = g.data_array(
        (100.0 + 0.01 * (x - 526_000.0) + 0.02 * (y - 6_475_000.0)).reshape(g.shape), "elevation"
    )
    prior = simulated_prior(truth, 75.0, 1.5, 0.0, np.random.default_rng(0))
    pg = Grid.from_dataarray(prior)
    assert pg.resolution == (75.0, 75.0) and pg.shape == (10, 10)
    assert pg.bounds == (525_925.0, 6_474_925.0, 526_675.0, 6_475_675.0)
    px, py = pg.xy().T
    plane = 100.0 + 0.01 * (px - 526_000.0) + 0.02 * (py - 6_475_000.0) + 1.5
    # 2 m cells do not divide 75 m: a block holds 37 or 38 columns, its mean shifts by
    # up to 1 m x 0.02 m/m; the margin continues that
    assert np.allclose(prior.values.ravel(), plane, atol=0.02)  # margin included
    noisy = simulated_prior(truth, 75.0, 1.5, 0.3, np.random.default_rng(0))
    assert 0.2 < float(np.std(noisy.values - prior.values)) < 0.4
