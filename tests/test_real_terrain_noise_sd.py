"""The real-terrain benchmark's ``--noise-sd``: the survey's signal-to-noise ratio as an
option (session 21), drawn into the samples and stated in their ``z_var``.

Reference: the noise is ``track_samples``' N(0, sd^2) on top of the truth it stores in
``extra["true_z"]``; 3,000 draws estimate sd to ~1.3 % (sd / sqrt(2 n)), so the checks below
allow 5 %.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def real_terrain():
    sys.path.insert(0, str(ROOT / "benchmarks"))
    sys.path.insert(0, str(ROOT / "scripts"))
    import real_terrain

    return real_terrain


@pytest.mark.parametrize("sd", [0.05, 0.5])
def test_the_samples_carry_the_noise_asked_for(real_terrain, sd):
    site = dict(real_terrain.parse_site("jacksboro"), noise_sd=sd)  # matplotlib's DEM
    _, _, samples = real_terrain._data(site, 3000)
    err = samples.z - samples.extra["true_z"]
    assert np.std(err) == pytest.approx(sd, rel=0.05)
    assert np.all(samples.z_var == pytest.approx(sd**2))


def test_the_default_is_every_earlier_result(real_terrain):
    _, _, samples = real_terrain._data(real_terrain.parse_site("jacksboro"), 3000)
    assert real_terrain.NOISE_SD == 0.2
    assert np.all(samples.z_var == pytest.approx(0.04))


def test_the_option_is_recorded_in_the_results(real_terrain, tmp_path):
    out = tmp_path / "r.json"
    real_terrain.main(
        ["--sites", "jacksboro", "--sizes", "3000", "--methods", "delaunay", "--noise-sd", "0.1"]
        + ["--out", str(out)]
    )
    payload = json.loads(out.read_text())
    assert payload["results"][0]["rmse_hull"] > 0.0
    settings = payload["settings"]
    assert settings["noise_sd_m"] == 0.1
    assert settings["sites"][0]["noise_sd"] == 0.1
