"""``glacimap change`` on the GP route with observation times in samples.csv: the budget
has the along-track terms, equal to the quadratic form on the in-memory GP's estimator
weights; without times it says "not available" (console and volume.json), never zero.

Reference: ``terrain.along_track.along_track_quadratic`` on ``gp_integral``'s sample
weights of the in-memory GPs (what the CLI must reproduce after rebuilding them from the
files), with the default model (``ALONG_TRACK_FRACTION``, ``ALONG_TRACK_TAU_S``).
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pandas as pd
import pytest
from test_cli_change_gp import _change, _make_epochs

from terrain import Grid
from terrain.along_track import ALONG_TRACK_FRACTION, ALONG_TRACK_TAU_S, along_track_quadratic
from terrain.synthetic import DEFAULT_SITE_BOUNDS
from terrain.volume import gp_integral, outline_weights
from toolkit.config import load_scenario


@pytest.fixture(scope="module")
def timed_epochs(tmp_path_factory):
    settings = load_scenario(overrides={"reconstruct": {"max_fit_samples": 300}})
    d, outline, gpkg, rec_b, rec_a, true_v = _make_epochs(
        tmp_path_factory.mktemp("timed"), settings
    )
    timed = d.parent / "timed_copy"
    shutil.copytree(d, timed)
    times = {}
    for k, name in enumerate(("before", "after")):
        f = timed / name / "samples.csv"
        frame = pd.read_csv(f)
        # samples along the lawnmower in the order drawn, 0.7 s apart; the second epoch
        # starts at another clock origin (only differences matter)
        times[name] = 1000.0 * k + 0.7 * np.arange(len(frame))
        frame.insert(len(frame.columns) - 1, "t_s", times[name])
        frame.to_csv(f, index=False)
    return d, timed, outline, gpkg, (rec_b, rec_a), times


def _volume(src, gpkg, out):
    """``glacimap change`` on ``src`` (exit 0 required): its console and volume.json."""
    res = _change(src, gpkg, out)
    assert res.exit_code == 0, res.output
    return res.output, json.loads((out / "volume.json").read_text())


def test_cli_budget_has_the_along_track_terms(timed_epochs, tmp_path):
    d, timed, outline, gpkg, recs, times = timed_epochs
    output, vol = _volume(timed, gpkg, tmp_path / "out")
    assert "along-track term, before: included" in output
    grid = Grid.from_bounds(DEFAULT_SITE_BOUNDS, 10.0)
    W = outline_weights(grid, outline)
    for name, rec in zip(("before", "after"), recs, strict=True):
        g = gp_integral(rec.gp, grid, W)
        s = np.sqrt(ALONG_TRACK_FRACTION * rec.gp.z_var_)
        # the fit's rows are in order of position (easting, then northing), not the file's
        frame = pd.read_csv(timed / name / "samples.csv")
        xy = frame.iloc[:, :2].to_numpy(float)
        by_position = np.lexsort((xy[:, 1], xy[:, 0]))
        np.testing.assert_allclose(xy[by_position], rec.gp.samples_.xy, rtol=0, atol=1e-6)
        t = times[name][by_position][g["sample_index"]]
        var = along_track_quadratic(g["sample_weights"], t, s, ALONG_TRACK_TAU_S, off_diagonal=True)
        assert var > 0
        assert vol["budget_m3"][f"along_track_{name}"] == pytest.approx(np.sqrt(var), rel=1e-6)
    assert vol["details"]["along_track"]["model"] == {
        "fraction": ALONG_TRACK_FRACTION,
        "tau_s": ALONG_TRACK_TAU_S,
    }
    total = np.sqrt(sum(v**2 for v in vol["budget_m3"].values()))
    assert vol["volume_std_m3"] == pytest.approx(total, rel=1e-9)


def test_cli_without_times_says_not_available(timed_epochs, tmp_path):
    d, timed, outline, gpkg, recs, times = timed_epochs
    output, vol = _volume(d, gpkg, tmp_path / "out")
    assert "along-track term, after: not available" in output
    assert not any(k.startswith("along_track") for k in vol["budget_m3"])
    assert vol["details"]["along_track"]["after"]["status"].startswith("not available")
    assert "along-track term NOT in the 1-sigma" in vol["details"]["method_note"]
