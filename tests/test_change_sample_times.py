"""Each selected landmark's observation time, from the log into samples.csv and back: what
the along-track term of terrain.volume_change needs (terrain.along_track).

References: hand arithmetic on a tiny observation table (mean of the keyframe times of a
landmark's observations); a samples.csv round trip; an old file without ``t_s``.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from factorgraph.result import LocalizationResult
from factorgraph.select import LandmarkSelection
from terrain import ElevationSamples, InputError
from toolkit.products import samples_table, write_csv
from toolkit.samples_io import read_samples


def test_landmark_time_is_the_mean_time_of_its_observations():
    # keyframes at 0, 10, ..., 50 s; landmark 3 seen at k 0 and 2 -> (0 + 20) / 2 = 10 s;
    # landmark 7 at k 1, 4 and 4 -> (10 + 40 + 40) / 3 = 30 s; landmark 9 is not in the graph
    log = SimpleNamespace(
        t=np.arange(6) * 10.0,
        obs_k=np.array([0, 1, 2, 4, 5, 4]),
        obs_id=np.array([3, 7, 3, 7, 9, 7]),
    )
    fake = SimpleNamespace(landmark_id=np.array([3, 7]), log=log)
    got = LocalizationResult.landmark_time_s(fake)
    np.testing.assert_allclose(got, [10.0, 30.0], rtol=0, atol=1e-12)
    empty = SimpleNamespace(landmark_id=np.zeros(0, int), log=log)
    assert LocalizationResult.landmark_time_s(empty).shape == (0,)


def _selection(with_time: bool) -> LandmarkSelection:
    rng = np.random.default_rng(0)
    n = 40
    xy = rng.uniform([500_000, 6_800_000], [500_100, 6_800_100], (n, 2))
    extra = {"landmark_id": np.arange(n)}
    if with_time:
        extra["t_s"] = np.linspace(3.0, 600.0, n)
    s = ElevationSamples(xy, rng.normal(1000, 1, n), 0.04, crs="EPSG:32608", extra=extra)
    table = {"kept": np.ones(n, bool), "z_std_m": np.full(n, 0.2)}
    return LandmarkSelection(s, table, {}, np.array([0.5, 0.5, 0.3]))


def test_samples_csv_carries_the_time_and_reads_it_back(tmp_path):
    sel = _selection(True)
    table = samples_table(sel)
    assert list(table)[-2:] == ["t_s", "crs"]
    path = write_csv(tmp_path / "samples.csv", table)
    back = read_samples(path)
    np.testing.assert_allclose(back.samples.extra["t_s"], sel.samples.extra["t_s"], rtol=1e-12)
    np.testing.assert_allclose(back.samples.z, sel.samples.z, rtol=1e-12)


def test_old_samples_csv_without_time_still_reads(tmp_path):
    table = samples_table(_selection(False))
    assert "t_s" not in table
    back = read_samples(write_csv(tmp_path / "samples.csv", table))
    assert "t_s" not in back.samples.extra and back.samples.n == 40


def test_samples_csv_with_a_missing_time_is_an_error(tmp_path):
    table = samples_table(_selection(True))
    table["t_s"] = table["t_s"].copy()
    table["t_s"][5] = np.nan
    path = write_csv(tmp_path / "samples.csv", table)
    with pytest.raises(InputError, match="t_s"):
        read_samples(path)
