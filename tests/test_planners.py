"""Survey planners: lawnmower and piecewise continuous (paper Section III-A, Eq 10)."""

import json

import numpy as np
import pytest
import shapely
from shapely.affinity import rotate
from shapely.geometry import Polygon, box

from survey.lawnmower import default_heading, lawnmower
from survey.piecewise import piecewise_continuous
from survey.plan import SurveyPlan
from survey.region import as_region
from terrain import Grid, InputError, random_terrain

HOLES = [[(100, 100), (200, 100), (200, 200), (100, 200)], [(300, 300), (400, 320), (350, 450)]]
REGION = Polygon([(0, 0), (600, 0), (600, 600), (0, 600)], HOLES)


def _inside(region, xy, tol=1e-6):
    return shapely.covered_by(shapely.points(xy), region.buffer(tol))


@pytest.fixture(scope="module")
def prior():
    return random_terrain(Grid.from_bounds((0, 0, 600, 600), 10.0), relief=25.0, seed=7)


@pytest.fixture(scope="module")
def planar():
    """z = 0.1 * northing: ascent points north, descent south."""
    grid = Grid.from_bounds((0, 0, 600, 600), 10.0)
    yy = np.broadcast_to(grid.y[:, None], grid.shape)
    return grid.data_array(0.1 * yy, "elevation")


# -- region ------------------------------------------------------------------------------
def test_region_accepts_bounds_and_rejects_bow_tie():
    assert as_region((0, 0, 10, 5)).area == pytest.approx(50.0)
    bow_tie = Polygon([(0, 0), (10, 10), (10, 0), (0, 10)])
    with pytest.raises(InputError, match=r"region.*Self-intersection.*make_valid"):
        as_region(bow_tie)
    with pytest.raises(InputError, match="region"):
        lawnmower(bow_tie, 2)
    with pytest.raises(InputError, match="region"):
        as_region(Polygon())
    with pytest.raises(InputError, match="crs"):
        as_region((0, 0, 10, 5), crs="EPSG:4326")  # geographic: degrees, not metres


# -- lawnmower ---------------------------------------------------------------------------
def test_lawnmower_rectangle_by_hand():
    plan = lawnmower(box(0, 0, 100, 50), 2, heading=90)
    # strips 0-25 and 25-50 m north -> swath lines at y = 12.5 and 37.5; driven east then west
    expected = [[0, 12.5], [100, 12.5], [100, 37.5], [0, 37.5]]
    np.testing.assert_allclose(plan.waypoints, expected, atol=1e-9)
    np.testing.assert_array_equal(plan.swath, [0, 0, 1, 1])
    # 100 m + 25 m turn + 100 m = 225 m
    assert plan.path_length == pytest.approx(225.0)
    # samples every 5 m: 225 / 5 + 1 = 46; the turn's interior samples (5 of 25 m -> 4) are -1
    assert plan.samples.shape == (46, 2)
    assert np.sum(plan.sample_swath == -1) == 4
    np.testing.assert_allclose(np.diff(plan.swath_offsets), [25.0])  # width 50 / N 2


@pytest.mark.parametrize("n", [1, 3, 10, 37])
@pytest.mark.parametrize("heading", [0.0, 33.0, 90.0, 247.5])
def test_lawnmower_swaths_inside_and_evenly_spaced(n, heading):
    region = rotate(box(0, 0, 300, 120), 20, origin=(0, 0))
    plan = lawnmower(region, n, heading=heading)
    assert sorted(set(plan.swath.tolist())) == list(range(n))
    assert plan.swath_offsets.shape == (n,)
    assert _inside(region, plan.waypoints).all() and _inside(region, plan.samples).all()
    # across-track width of the region / N, measured independently from its vertices
    across = plan.to_swath_frame(np.asarray(region.exterior.coords))[:, 1]
    width = across.max() - across.min()
    if n > 1:
        np.testing.assert_allclose(np.diff(plan.swath_offsets), width / n)
    # every swath waypoint lies on its swath line
    fr = plan.to_swath_frame(plan.waypoints)
    np.testing.assert_allclose(fr[:, 1], plan.swath_offsets[plan.swath], atol=1e-6)
    assert plan.heading_deg == pytest.approx(heading % 360)


def test_lawnmower_holes_split_swaths():
    plan = lawnmower(REGION, 10, heading=0.0)
    # holes split some swaths into pieces: more than 2 waypoints on those swaths
    assert np.bincount(plan.swath).max() > 2
    # No sample lies in a hole's interior except on transit legs (sample_swath == -1), which
    # are allowed to cross holes (driving around is not modelled).
    holes = [Polygon(h) for h in HOLES]
    in_hole = np.any([shapely.contains_xy(h, *plan.samples.T) for h in holes], axis=0)
    assert in_hole.any()  # the straight transit legs do cross the holes here
    assert np.all(plan.sample_swath[in_hole] == -1)
    on_swath = plan.sample_swath >= 0
    assert _inside(REGION, plan.samples[on_swath]).all()


def test_default_heading_follows_long_axis():
    assert default_heading(box(0, 0, 100, 50)) == pytest.approx(90.0)
    assert default_heading(box(0, 0, 50, 100)) == pytest.approx(0.0)
    # a 300 x 120 box rotated 30 deg counter-clockwise: long axis at 60 deg clockwise from north
    tilted = rotate(box(0, 0, 300, 120), 30, origin=(0, 0))
    assert default_heading(tilted) == pytest.approx(60.0, abs=1e-6)
    plan = lawnmower(tilted, 4)
    assert plan.heading_deg == pytest.approx(60.0, abs=1e-6)
    assert plan.params["heading_source"] == "minimum_rotated_rectangle"


def test_plan_round_trips_through_json():
    plan = lawnmower(REGION, 5, heading=10.0, crs="EPSG:32608")
    data = json.loads(json.dumps(plan.to_dict()))
    back = SurveyPlan.from_dict(data)
    np.testing.assert_array_equal(back.waypoints, plan.waypoints)
    np.testing.assert_array_equal(back.sample_swath, plan.sample_swath)
    assert back.crs == plan.crs and back.params == plan.params
    xy = np.array([[3.0, 4.0], [-7.0, 2.0]])
    np.testing.assert_allclose(plan.from_swath_frame(plan.to_swath_frame(xy)), xy)


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"n_swaths": 0}, "n_swaths"),
        ({"n_swaths": 2.5}, "n_swaths"),
        ({"spacing": 0.0}, "spacing"),
        ({"spacing": -1.0}, "spacing"),
        ({"heading": float("nan")}, "heading"),
        ({"margin": -1.0}, "margin"),
    ],
)
def test_lawnmower_bad_input(kwargs, field):
    args = {"region": REGION, "n_swaths": 3, **kwargs}
    with pytest.raises(InputError, match=field):
        lawnmower(**args)


def test_plan_validates_shapes():
    with pytest.raises(InputError, match="waypoints"):
        SurveyPlan(
            np.full((2, 2), np.nan),
            [0, 0],
            "lawnmower",
            {},
            np.zeros((1, 2)),
            [0],
            [0.0],
            0.0,
            (0.0, 0.0),
        )
    with pytest.raises(InputError, match="pattern"):
        SurveyPlan(
            np.zeros((2, 2)), [0, 0], "spiral", {}, np.zeros((1, 2)), [0], [0.0], 0.0, (0.0, 0.0)
        )


# -- piecewise continuous ------------------------------------------------------------------
def test_piecewise_seeded_reproducibility(prior):
    a = piecewise_continuous(REGION, 4, prior, seed=1)
    b = piecewise_continuous(REGION, 4, prior, seed=1)
    c = piecewise_continuous(REGION, 4, prior, seed=2)
    np.testing.assert_array_equal(a.waypoints, b.waypoints)
    np.testing.assert_array_equal(a.samples, b.samples)
    assert a.waypoints.shape != c.waypoints.shape or not np.array_equal(a.waypoints, c.waypoints)
    assert a.params["seed"] == 1 and a.pattern == "piecewise_continuous"


@pytest.mark.parametrize("n", [1, 3, 8])
@pytest.mark.parametrize("heading", [None, 25.0])
def test_piecewise_bounded_inside_and_never_crossing(prior, n, heading):
    plan = piecewise_continuous(REGION, n, prior, seed=3, heading=heading)
    fr = plan.to_swath_frame(plan.waypoints)
    dev = np.abs(fr[:, 1] - plan.swath_offsets[plan.swath])
    assert dev.max() <= plan.params["max_deviation"] + 1e-9
    assert dev.max() > 1.0  # it does wander
    if n > 1:
        assert plan.params["max_deviation"] < np.diff(plan.swath_offsets).min() / 2
    assert _inside(REGION, plan.waypoints).all()
    assert _inside(REGION, plan.samples[plan.sample_swath >= 0]).all()
    # Neighbouring swaths never cross: the swath legs (not transits) of different swaths are
    # pairwise disjoint.
    legs = [shapely.linestrings(plan.waypoints[np.flatnonzero(plan.swath == i)]) for i in range(n)]
    for i in range(n - 1):
        assert not shapely.intersects(legs[i], legs[i + 1])
    assert sorted(set(plan.swath.tolist())) == list(range(n))


@pytest.mark.parametrize(("flag", "sign"), [(1, 1.0), (0, -1.0)])
def test_piecewise_follows_ascent_and_descent(planar, flag, sign):
    # heading 90 (east): across = northing - origin. Ascent on z = 0.1 y drifts north,
    # descent south; with the flag fixed every step moves one full step across (|g.v|/|g| = 1)
    # until the deviation bound.
    plan = piecewise_continuous(
        box(0, 0, 600, 600),
        3,
        planar,
        heading=90.0,
        step=10.0,
        switch_probability=0.0,
        initial_flag=flag,
        max_deviation=50.0,
    )
    fr = plan.to_swath_frame(plan.waypoints)
    dev = fr[:, 1] - plan.swath_offsets[plan.swath]
    for i in range(3):
        d = dev[plan.swath == i]
        np.testing.assert_allclose(d[:6], sign * np.array([0, 10, 20, 30, 40, 50]), atol=1e-9)
        np.testing.assert_allclose(d[6:], sign * 50.0, atol=1e-9)


def test_piecewise_bad_input(prior):
    with pytest.raises(InputError, match="prior.*region bounds"):
        piecewise_continuous(box(0, 0, 800, 600), 2, prior)  # prior covers 0..600 only
    with pytest.raises(InputError, match="n_swaths"):
        piecewise_continuous(REGION, 0, prior)
    with pytest.raises(InputError, match="spacing"):
        piecewise_continuous(REGION, 2, prior, spacing=0.0)
    with pytest.raises(InputError, match="max_deviation"):
        piecewise_continuous(REGION, 2, prior, max_deviation=150.0)  # = half of 300 m spacing
    with pytest.raises(InputError, match="switch_probability"):
        piecewise_continuous(REGION, 2, prior, switch_probability=1.5)
    with pytest.raises(InputError, match="region"):
        piecewise_continuous(Polygon([(0, 0), (10, 10), (10, 0), (0, 10)]), 2, prior)
