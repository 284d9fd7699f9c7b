"""The held-out check on a line survey of a real DEM (benchmarks/heldout_lines.py): dense
lines 300 m apart with scattered samples between them, where blocks cut gaps along the lines
that no map cell has. Before session 14 the check read an SE map's coverage 15 points low
and said its 1-sigma was too small; the truth said it was right."""

from __future__ import annotations

import sys
import tempfile
import warnings
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_line_survey_check_reads_the_map_not_the_gaps_along_lines(monkeypatch):
    sys.path.insert(0, str(ROOT / "scripts"))
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import heldout_lines
    import real_dems

    import toolkit.stages as stages
    from terrain import TerrainGP

    try:
        dem = real_dems.load("olinda")
    except real_dems.RealDataUnavailable as exc:
        pytest.skip(f"real DEM 'olinda' unavailable: {exc}")
    warnings.simplefilter("ignore")
    with tempfile.TemporaryDirectory() as tmp:
        prior = heldout_lines._prior_file(dem, Path(tmp))
        # The default kernel (session 23's window evidence picks a Matérn 5/2 here, whose
        # 1-sigma is wide: 77.8 % of the truth inside it): the check reads the truth.
        default = heldout_lines.run_case("lines+scattered", "prior", prior)
        # The mechanism needs the SE map it was found on (the default's pick up to session
        # 22): pinned, as a user passing kernel="se" would.
        monkeypatch.setattr(stages, "TerrainGP", lambda **kw: TerrainGP(kernel="se", **kw))
        row = heldout_lines.run_case("lines+scattered", "prior", prior)
    assert abs(default["heldout68"] - default["truth68"]) <= 3.0
    assert abs(default["heldout95"] - default["truth95"]) <= 3.5
    assert not any("too small" in v for v in default["verdict"])
    assert row["kernel"] == "se"
    # the mechanism: held-out line samples in gaps along their line read far below the
    # truth, the scattered ones (neighbourhoods like the map cells') read it
    assert row["true_at_lines68"] < row["truth68"] - 15.0
    assert abs(row["true_at_scattered68"] - row["truth68"]) <= 3.0
    # the check switched to the neighbourhood weights, and reads the truth within 3 points
    assert row["matched_on"] == "neighbourhood" and row["difference_sd"] > 3.0
    assert abs(row["heldout68"] - row["truth68"]) <= 3.0
    # 95 %: 94.0 with single held-out samples (session 14), 92.2 since their elevations come
    # from local planes (session 15; truth 95.3): the planes average the noise of the line
    # samples, not of the isolated scattered ones, so the line samples' own shape (gaps
    # along lines, true errors 77 % inside 1.96 sigma) weighs more in the mixture
    assert abs(row["heldout95"] - row["truth95"]) <= 3.5
    assert row["distance_matched68"] < row["truth68"] - 10.0  # what it read before
    assert not any("too small" in v for v in row["verdict"])
