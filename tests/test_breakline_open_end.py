"""Breaklines that stop inside the survey (``terrain.BreaklineMean``'s open ends): the step
column is the double layer whose strength tapers off, continuous round the end; a cliff that
dies out is mapped as well as the same ground without it.

References: the double layer by an independent quadrature (the direction from each point
to the line unwrapped over 1 cm pieces, summed with the strength; the closed form is not
used); the height and the taper against the step put into the samples; the map against the
same draw without the step, mapped by the same default estimator.
"""

from __future__ import annotations

import numpy as np
import pytest
import shapely
from scipy.special import expit

from terrain import BreaklineMean, ElevationSamples, InputError, TerrainGP
from terrain.breakline_geometry import REACH_M

BENT = np.array([[-100.0, 0.0], [0.0, 0.0], [40.0, 30.0], [100.0, 30.0]])


def _quadrature(pts: np.ndarray, line: np.ndarray, taper: float) -> np.ndarray:
    """(1 / 2 pi) integral tau dtheta + 1/2 over ``line`` run on before its head (strength
    1) and open at its tail (smoothstep over ``taper`` m), by 1 cm pieces: each piece's
    angle unwrapped to (-pi, pi], times the strength at its middle."""
    geom = shapely.LineString(line)
    s = np.linspace(0.0, geom.length, int(geom.length / 0.01) + 1)
    u = np.clip((geom.length - s) / taper, 0.0, 1.0)
    tau = u * u * (3 - 2 * u)
    head = line[0] - REACH_M * (line[1] - line[0]) / np.hypot(*(line[1] - line[0]))
    path = np.vstack([head, shapely.get_coordinates(geom.interpolate(s))])
    strength = np.concatenate([[1.0], 0.5 * (tau[:-1] + tau[1:])])
    out = np.empty(len(pts))
    for i, p in enumerate(pts):
        theta = np.arctan2(path[:, 1] - p[1], path[:, 0] - p[0])
        dtheta = np.angle(np.exp(1j * np.diff(theta)))  # each piece subtends < pi
        out[i] = strength @ dtheta / (2 * np.pi) + 0.5
    return out


def test_an_open_end_is_the_double_layer_whose_strength_tapers_off():
    m = BreaklineMean([BENT], width=1.0, taper=50.0)
    m.open_ends_ = ((False, True),)  # as a fit on samples round the tail would set it
    rng = np.random.default_rng(0)
    pts = rng.uniform(-150, 200, (300, 2))
    D = m.signed_distances(pts, 1e9)[:, 0]
    far = np.abs(D) > 40.0  # 40 widths: the logistic is a step to double precision
    ref = _quadrature(pts[far], BENT, 50.0)
    # measured 4.4e-5: the taper is linear between 16 nodes in the closed form
    np.testing.assert_allclose(m.steps(pts[far])[:, 0], ref, atol=2e-4)
    # continuous round the end: on rings round it no jump beyond the logistic's
    theta = np.linspace(0.0, 2 * np.pi, 3601)
    for r, most in ((5.0, 1e-3), (20.0, 1e-2)):  # measured 1.6e-4, 3.2e-3
        ring = BENT[-1] + r * np.column_stack([np.cos(theta), np.sin(theta)])
        assert np.abs(np.diff(m.steps(ring)[:, 0])).max() < most
    # the jump across the line is the strength: 1 away from the taper, ~0 at the end
    for s, jump in ((50.0, 1.0), (185.0, 0.5), (209.0, 0.0)):  # smoothstep(1/2), (1/50)
        p = np.asarray(shapely.LineString(BENT).interpolate(s).coords)[0]
        v = m.steps(p + np.array([[0.0, 0.01], [0.0, -0.01]]), widths=(1e-4,))[:, 0]
        assert v[0] - v[1] == pytest.approx(jump, abs=0.02)
    # the hinge column (basis: constant, step, hinge) jumps nowhere: across the line, on
    # rings round the end, across the ray beyond it
    hinge = lambda p: m.basis(p)[:, -1]  # noqa: E731
    for s in (50.0, 185.0, 209.0):
        p = np.asarray(shapely.LineString(BENT).interpolate(s).coords)[0]
        v = hinge(p + np.array([[0.0, 0.01], [0.0, -0.01]]))
        assert abs(v[0] - v[1]) < 2e-3, (s, v)
    for r in (5.0, 50.0):
        ring = BENT[-1] + r * np.column_stack([np.cos(theta), np.sin(theta)])
        assert np.abs(np.diff(hinge(ring))).max() < 5e-3  # measured 2.1e-3 at 50 m: its slope
    # far away: 1 on the left, 0 on the right, going round the open end with the angle
    # (a semi-infinite line's double layer): 3/4 abreast of it, 1/2 beyond it
    far_pts = np.array([[-5e4, 100.0], [-5e4, -100.0], [100.0, 5e4], [5e4, 30.0]])
    np.testing.assert_allclose(m.steps(far_pts)[:, 0], [1.0, 0.0, 0.75, 0.5], atol=0.01)


def test_a_line_that_curls_back_has_its_open_ends_run_on_off_it():
    # A 270-degree arc with both ends inside the survey: run on straight, each end's ray
    # would cross the arc; an open end's ray only splits the plane (its layer is
    # subtracted again), so it turns off the arc. Reference: the same quadrature of the
    # tapered layer over the arc alone (no ray: both ends open).
    t = np.linspace(0.0, 1.5 * np.pi, 271)
    arc = 100.0 * np.column_stack([np.cos(t), np.sin(t)])
    m = BreaklineMean([arc], width=1.0, taper=40.0)
    m.open_ends_ = ((True, True),)
    rng = np.random.default_rng(2)
    pts = rng.uniform(-200, 200, (200, 2))
    far = np.abs(m.signed_distances(pts, 1e9)[:, 0]) > 40.0
    geom = shapely.LineString(arc)
    s = np.linspace(0.0, geom.length, int(geom.length / 0.01) + 1)
    path = shapely.get_coordinates(geom.interpolate(s))
    # the strength: a smoothstep of the distance to each end (the chord) over 40 m
    u = [np.clip(np.hypot(*(path - end).T) / 40.0, 0.0, 1.0) for end in (arc[0], arc[-1])]
    w = np.prod([v * v * (3 - 2 * v) for v in u], axis=0)
    ref = []
    for p in pts[far]:
        theta = np.arctan2(path[:, 1] - p[1], path[:, 0] - p[0])
        ref.append(0.5 * (w[:-1] + w[1:]) @ np.angle(np.exp(1j * np.diff(theta))) / (2 * np.pi))
    # equal up to a constant (the half-plane of a line whose rays are not opposite is the
    # layer plus a constant other than 1/2; the base's intercept takes it)
    diff = m.steps(pts[far])[:, 0] - np.asarray(ref)
    assert np.ptp(diff) < 2e-4  # measured 3.3e-6
    theta = np.linspace(0.0, 2 * np.pi, 3601)
    for end in (arc[0], arc[-1]):
        ring = end + 10.0 * np.column_stack([np.cos(theta), np.sin(theta)])
        assert np.abs(np.diff(m.steps(ring)[:, 0])).max() < 5e-3


def test_a_line_across_the_survey_is_unchanged_by_the_fit():
    # Both ends outside the samples' box: run on, the step is expit(d / w) as before 0.37.0.
    rng = np.random.default_rng(1)
    xy = rng.uniform(-90, 90, (400, 2))
    line = np.array([[-100.0, 0.0], [100.0, 0.0]])
    z = 2.0 * expit(xy[:, 1] / 1.0) + rng.normal(0, 0.05, len(xy))
    m = BreaklineMean([line], width=1.0).fit(xy, z)
    assert m.open_ends_ == ((False, False),) and m.tapers_ == (None,)
    np.testing.assert_allclose(m.steps(xy)[:, 0], expit(xy[:, 1] / 1.0), rtol=0, atol=1e-15)
    assert "taper" not in repr(m)


@pytest.fixture(scope="module")
def dying_cliff():
    """An SE draw (variance 4, 25 m) on a 300 m site, 1,500 samples with 0.05 m noise, and
    the same with a 3 m step, 1 m wide, up to the north of a sinuous east-west line, its
    height falling by half a cosine of the easting over the 80 m before it stops at x = 230
    m (a hinge: not the estimator's smoothstep of arc length)."""
    from terrain import SquaredExponential

    rng = np.random.default_rng(11)
    xy = rng.uniform(0, 300, (1500, 2))
    k = SquaredExponential(4.0, 25.0)
    K = k(xy) + 1e-8 * np.eye(len(xy))
    f = np.linalg.cholesky(K) @ rng.normal(size=len(xy))
    noise = rng.normal(0, 0.05, len(xy))
    q = rng.uniform(5, 295, (3000, 2))
    fq = k(q, xy) @ np.linalg.solve(K, f)  # the draw at q (smooth: exact far below 5 cm)

    def step(p):
        fade = np.clip((230.0 - p[:, 0]) / 80.0, 0, 1)
        across = p[:, 1] - (150 + 30 * np.sin(p[:, 0] / 60))
        return 3.0 * expit(across / 1.0) * (0.5 - 0.5 * np.cos(np.pi * fade))

    def line(x0, x1):
        u = np.arange(x0, x1 + 1e-9, 1.0)
        return np.column_stack([u, 150 + 30 * np.sin(u / 60)])

    return xy, f, noise, q, fq, step, line


def test_a_cliff_that_dies_out_is_mapped_as_the_ground_without_it(dying_cliff):
    xy, f, noise, q, fq, step, line = dying_cliff
    plain = TerrainGP(seed=0).fit(ElevationSamples(xy, f + noise, 0.05**2))
    rmse_plain = np.sqrt(np.mean((plain.predict(q) - fq) ** 2))
    samples = ElevationSamples(xy, f + step(xy) + noise, 0.05**2)
    truth = fq + step(q)

    def rmse(mean):
        gp = TerrainGP(mean=mean, seed=0).fit(samples)
        mu, sd = gp.predict(q, return_std=True)
        return gp, np.sqrt(np.mean((mu - truth) ** 2)), np.mean(np.abs(mu - truth) < 1.96 * sd)

    gp, rmse_open, cover = rmse(BreaklineMean([line(-100, 230)]))  # drawn to where it stops
    m = gp.mean_
    assert m.open_ends_ == ((False, True),) and m.tapers_[0] in (56.0, 80.0, 113.0)  # 80
    k = m.coef_names.index("step1_m")
    height, sd = m.coef_[k], np.sqrt(gp.coef_cov_[k, k])
    assert abs(height - 3.0) < 3 * sd and sd < 0.05  # measured 3.033 +- 0.033
    assert rmse_open < 1.15 * rmse_plain  # measured 1.03 x
    assert 0.9 < cover <= 1.0  # measured 93.0 %
    # Run on across the survey (what 0.36.0 asked for) it puts a step where there is none,
    # and without the line the kernel takes the step as rough ground.
    assert rmse(BreaklineMean([line(-100, 400)]))[1] > 2.0 * rmse_open  # measured 2.5 x
    assert rmse("constant")[1] > 3.0 * rmse_open  # measured 4.0 x


def test_tapers_given_back_rebuild_the_same_mean_and_bad_ones_are_refused(dying_cliff):
    xy, f, noise, q, fq, step, line = dying_cliff
    z = f + step(xy) + noise
    lines = [line(-100, 230), np.array([[60.0, -50.0], [60.0, 350.0]])]  # open; across
    fitted = BreaklineMean(lines).fit(xy, z)
    rec = fitted.geojson()["properties"]
    assert rec["open_ends"] == [[False, True], [False, False]]
    assert rec["tapers_m"][1] is None and rec["tapers_m"][0] > 0
    rebuilt = BreaklineMean(lines, width=rec["widths_m"], taper=rec["tapers_m"]).fit(xy, z)
    np.testing.assert_allclose(rebuilt.basis(q), fitted.basis(q), rtol=0, atol=1e-12)
    assert "taper='auto' (" in repr(fitted)
    for bad in (0.0, -5.0, "long", (40.0,), (40.0, float("inf"))):
        with pytest.raises(InputError, match="taper"):
            BreaklineMean(lines, taper=bad)


def test_glacimap_change_rebuilds_the_tapers_a_product_records(dying_cliff):
    # The product's `breaklines` record (BreaklineMean.geojson) read back by `glacimap
    # change` (toolkit.change_inputs): the same lines, widths and tapers, so the refit on the
    # same samples gives the same columns.
    import json

    from toolkit.change_inputs import _mean_from_provenance

    xy, f, noise, q, fq, step, line = dying_cliff
    z = f + step(xy) + noise
    fitted = BreaklineMean([line(-100, 230), line(-100, 400) + [0.0, 60.0]]).fit(xy, z)
    record = json.dumps(fitted.geojson())
    rebuilt = _mean_from_provenance(repr(fitted), None, None, record)
    assert rebuilt.width == fitted.widths_ and rebuilt.taper == fitted.tapers_
    assert rebuilt.ends == fitted.open_ends_ == ((False, True), (False, False))
    np.testing.assert_allclose(rebuilt.fit(xy, z).basis(q), fitted.basis(q), atol=1e-12)


def test_ends_given_and_held_by_the_heldout_folds(dying_cliff):
    # ends="open": a cliff that stops between the survey and the map's edge (both ends
    # outside the samples' box, yet no step runs on beyond them).
    from terrain.estimator_clone import fixed_overrides

    xy, f, noise, q, fq, step, line = dying_cliff
    z = f + step(xy) + noise
    across = line(-100, 400)
    m = BreaklineMean([across], width=1.0, taper=40.0, ends="open").fit(xy, z)
    assert m.open_ends_ == ((True, True),)
    t = (across[-1] - across[-2]) / np.hypot(*(across[-1] - across[-2]))  # run on along t
    beyond = across[-1] + 50.0 * t + np.outer([2.0, -2.0], [-t[1], t[0]])  # left, right
    S = m.steps(beyond)[:, 0]
    assert abs(S[0] - S[1]) < 0.05  # no step past the end (run on: 1.0)
    assert BreaklineMean([across], width=1.0).fit(xy, z).steps(beyond)[:, 0] @ [1, -1] > 0.99
    # the held-out check's folds refit the mean with the map's open ends, whatever box
    # their samples leave (a block cut off the survey's edge may put an end inside it)
    gp = TerrainGP(mean=BreaklineMean([line(-100, 230)]), seed=0)
    gp.fit(ElevationSamples(xy, z, 0.05**2))
    held = fixed_overrides(gp)["mean"]
    assert held.ends == gp.mean_.open_ends_ == ((False, True),) and held.coef_ is None
    assert held.width == "auto" and held.taper == "auto"  # the rest re-chosen per fold
    for bad in ("closed", [(True,)], [(True, "no")], [(True, True), (False, False)]):
        with pytest.raises(InputError, match="ends"):
            BreaklineMean([across], ends=bad)
