"""``terrain.find_breaklines``: steps found in the samples, where the surveyor drew none.

References: the step put into the samples (3 m, 1 m wide, along a known sinuous line) and
the ground without it; the found lines are measured against the known line with shapely.
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
import xarray as xr
from scipy.special import expit
from shapely import LineString, Point
from typer.testing import CliRunner

from terrain import (
    BreaklineMean,
    ElevationSamples,
    InputError,
    TerrainGP,
    default_site,
    find_breaklines,
)
from terrain.breakline_search import _confirm
from terrain.sampling import sample_dem
from toolkit.cli import app

X0, Y0 = 526000.0, 6475000.0
CRS = "EPSG:32608"


def _true_line(x: np.ndarray) -> np.ndarray:
    """The step's line: sinuous, east-west through the default site's middle."""
    return Y0 + 300.0 + 25.0 * np.sin((x - X0) / 70.0)


@pytest.fixture(scope="module")
def ground():
    """2,000 spot heights (20 cm 1-sigma) of the default site, and a 3 m step, 1 m wide,
    up to the north of :func:`_true_line`; optionally dying out east of x = 400 m."""
    rng = np.random.default_rng(1)
    xy = rng.uniform([X0 + 2, Y0 + 2], [X0 + 598, Y0 + 598], size=(2000, 2))
    z = sample_dem(default_site(resolution=4.0), xy) + rng.normal(0, 0.2, len(xy))
    across = xy[:, 1] - _true_line(xy[:, 0])
    fade = 0.5 - 0.5 * np.cos(np.pi * np.clip((X0 + 400.0 - xy[:, 0]) / 100.0, 0, 1))
    return xy, z, 3.0 * expit(across), 3.0 * expit(across) * fade


def _samples(xy, z) -> ElevationSamples:
    return ElevationSamples(xy, z, np.full(len(z), 0.04), crs=CRS)


def _offsets(line: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Distances (m) of the line's vertices inside the samples' box to the true line."""
    u = np.linspace(X0 - 200, X0 + 800, 2001)
    ref = LineString(np.column_stack([u, _true_line(u)]))
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    inside = [v for v in line if np.all(v >= lo) and np.all(v <= hi)]
    return np.array([ref.distance(Point(v)) for v in inside])


def test_a_step_across_the_survey_is_found_where_it_is(ground):
    xy, z, step, _ = ground
    found = find_breaklines(_samples(xy, z + step))
    assert len(found.lines) == 1, found.summary()
    (line,) = found.lines
    d = _offsets(line, xy)
    # a straight line across a 97 m disc is a chord of the sinuous step (its sagitta up to
    # 6 m): measured median 2.4, max 5.4 m over the spline's 45 vertices inside the box
    assert len(d) >= 5 and np.median(d) < 3.0 and np.max(d) < 6.5
    # both ends carried past the samples' box: the step runs on across the survey
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    assert line[0, 0] < lo[0] and line[-1, 0] > hi[0]
    # the local least squares only confirms the step (4.73 +- 0.45: its width chosen wide,
    # 3.0 m, where the line strays); the map's GLS height is the one a user reads: measured
    # 3.37 +- 0.14 (the drawn line's local start on the same samples: 3.44 +- 0.20)
    assert abs(found.steps_m[0]) > 5 * found.steps_sd_m[0]
    gp = TerrainGP(seed=0, mean=BreaklineMean(found.lines)).fit(_samples(xy, z + step))
    assert abs(gp.mean_.coef_[1]) == pytest.approx(3.0, abs=0.6)
    # counted, never silently dropped
    assert found.n_unlinked == found.n_edge_points - sum(found.points)
    assert "1 line(s)" in found.summary()


def test_no_line_on_ground_without_a_step(ground):
    xy, z, _, _ = ground
    found = find_breaklines(_samples(xy, z))
    assert found.lines == [] and found.steps_m == []
    assert found.residual_sd_m == pytest.approx(0.31, abs=0.1)  # noise 0.2 m and roughness


def test_a_step_that_dies_out_is_found_with_an_open_end(ground):
    xy, z, _, dying = ground
    found = find_breaklines(_samples(xy, z + dying))
    assert len(found.lines) == 1, found.summary()
    line = found.lines[0]
    line = line[np.argsort(line[:, 0])]
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    assert line[0, 0] < lo[0]  # the west end runs on past the survey
    assert lo[0] < line[-1, 0] < hi[0]  # the east end stops inside it: an open end
    # it runs on past its last edge point (x = 318 m) by half the link distance (180 m
    # here: 90 m; the taper fitted fades the step there): measured x = 415 m for a step
    # that dies out at 400 m; the spline's vertices: median 2.7, max 5.3 m off
    assert X0 + 300.0 < line[-1, 0] < X0 + 400.0 + 0.5 * 180.0 + 20.0
    spline = found.lines[0][1:-1]  # the run-on ends go straight, the step curves on
    assert np.median(_offsets(spline, xy)) < 3.0 and np.max(_offsets(spline, xy)) < 6.5


def test_a_line_whose_step_is_not_told_from_zero_is_dropped_with_its_reason(ground):
    xy, z, _, _ = ground
    u = np.linspace(X0 - 50, X0 + 650, 8)
    step, sd, why = _confirm(np.column_stack([u, _true_line(u)]), xy, z, 0.3)
    assert why and "step" in why and abs(step) < 5 * sd


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [({"radius": 0.0}, "radius"), ({"radius": float("nan")}, "radius")],
)
def test_bad_input_is_refused_by_name(ground, kwargs, field):
    xy, z, _, _ = ground
    with pytest.raises(InputError, match=field):
        find_breaklines(_samples(xy, z), **kwargs)
    with pytest.raises(InputError, match="samples"):
        find_breaklines(np.column_stack([xy, z]))
    with pytest.raises(InputError, match="samples"):
        find_breaklines(_samples(xy[:20], z[:20]))


def test_cli_finds_the_step_fits_it_and_says_so(ground, tmp_path):
    xy, z, step, _ = ground
    runner = CliRunner()
    for name, zz in (("step", z + step), ("plain", z)):
        csv = tmp_path / f"{name}.csv"
        pd.DataFrame({"x": xy[:, 0], "y": xy[:, 1], "z": zz, "z_var": 0.04}).to_csv(csv)
        out = tmp_path / name
        res = runner.invoke(app, ["reconstruct", str(csv), "--crs", CRS, "--resolution", "10",
                                  "--breaklines", "auto", "--out", str(out)])  # fmt: skip
        assert res.exit_code == 0, res.output
        attrs = xr.open_dataset(out / "product.nc").attrs
        assert "breakline search" in res.output and "breakline search" in attrs["breakline_search"]
        assert "breaklines" not in {r["role"] for r in json.loads(attrs["inputs"])}  # no file
        if name == "step":
            assert "1 line(s)" in res.output and "line 1: step" in res.output
            height = float(attrs["mean_function"].split("step1_m=")[1].split()[0])
            assert abs(height) == pytest.approx(3.0, abs=0.6)  # the GP's GLS step
        else:
            assert "0 line(s)" in res.output and "BreaklineMean" not in attrs["mean_function"]


def test_process_searches_the_selected_samples_and_records_what_it_found(tmp_path):
    # The example field folder (the default site) has no scarp: the search, run on the
    # landmarks the selection kept, finds no line and says so; the map is the plain one.
    from pathlib import Path

    example = Path(__file__).resolve().parents[1] / "docs" / "examples" / "field"
    out = tmp_path / "out"
    res = CliRunner().invoke(app, ["process", str(example), "--breaklines", "auto",
                                   "--out", str(out)])  # fmt: skip
    assert res.exit_code == 0, res.output
    assert "breaklines: breakline search" in res.output and "0 line(s)" in res.output
    cert = json.loads((out / "certificate.json").read_text())
    assert "0 line(s)" in cert["inputs"]["breakline_search"][0]
    attrs = xr.open_dataset(out / "product.nc").attrs
    assert "BreaklineMean" not in attrs["mean_function"]
    assert "breaklines" not in {r["role"] for r in json.loads(attrs["inputs"])}
