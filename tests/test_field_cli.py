"""``glacimap simulate --format field``: the example folder in docs/examples/field is what the
command writes (same seed, same bytes), and it reads back into a log that localizes."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from factorgraph import read_field_log
from terrain.errors import InputError
from toolkit.cli import app

EXAMPLE = Path(__file__).resolve().parents[1] / "docs" / "examples" / "field"
runner = CliRunner()


def _simulate(out: Path, *extra: str):
    args = ["simulate", "--config", str(EXAMPLE / "scenario.toml"), "--format", "field"]
    return runner.invoke(app, [*args, "--out", str(out), *extra])


def _same_table(made: Path, kept: Path) -> None:
    """The CSV ``made`` holds ``kept``'s columns and rows: integers exactly, floats to 1e-12
    relative (the last of 17 digits moves with the numerical libraries' versions: session 24
    saw 12 of 3,726 pixel rows of tracks.csv differ by up to 1e-14 after a fresh install)."""
    import numpy as np
    import pandas as pd

    a, b = pd.read_csv(made), pd.read_csv(kept)
    assert list(a.columns) == list(b.columns) and a.shape == b.shape, made.name
    for col in a.columns:
        if a[col].dtype.kind == "f" or b[col].dtype.kind == "f":
            np.testing.assert_allclose(a[col], b[col], rtol=1e-12, atol=0, err_msg=col)
        else:
            assert a[col].tolist() == b[col].tolist(), (made.name, col)


def test_example_folder_is_reproducible(tmp_path):
    first, second = tmp_path / "first", tmp_path / "second"
    for out in (first, second):
        res = _simulate(out)
        assert res.exit_code == 0, res.output
    made = sorted(p.name for p in first.iterdir())
    assert made == [
        "camera.yaml",
        "gps.nmea",
        "odometry.csv",
        "survey.json",
        "tilt.csv",
        "tracks.csv",
    ]
    for name in made:
        # Same seed, same bytes: the command run twice.
        assert (first / name).read_bytes() == (second / name).read_bytes(), name
        # The example folder: the same bytes, or for tables the same numbers to 1e-12.
        if (first / name).read_bytes() != (EXAMPLE / name).read_bytes():
            assert name.endswith(".csv"), name
            _same_table(first / name, EXAMPLE / name)
    assert sum((EXAMPLE / n).stat().st_size for n in made) < 400_000  # a small example


def test_example_reads_back(tmp_path):
    log, rep = read_field_log(EXAMPLE)
    man = json.loads((EXAMPLE / "survey.json").read_text())
    assert log.seed == man["seed"] == 7 and log.crs == "EPSG:32608"
    assert rep.gps_used == rep.gps_records == log.gps_k.size and not rep.gps_skipped
    assert log.truth == {} and log.n_keyframes == 156


@pytest.mark.parametrize("fmt", ["gpx", "rtklib"])
def test_gps_format_option(tmp_path, fmt):
    res = _simulate(tmp_path, "--gps-format", fmt)
    assert res.exit_code == 0, res.output
    assert (tmp_path / {"gpx": "gps.gpx", "rtklib": "gps.pos"}[fmt]).is_file()
    assert not (tmp_path / "gps.nmea").exists()
    _, rep = read_field_log(tmp_path)
    assert rep.gps_format == fmt


def test_bad_gps_format_writes_nothing(tmp_path):
    res = _simulate(tmp_path / "out", "--gps-format", "kml")
    assert isinstance(res.exception, InputError)  # glacimap's main() turns it into exit 2
    assert "--gps-format" in str(res.exception) and "nmea or gpx or rtklib" in str(res.exception)
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


def test_localize_reads_a_field_folder(tmp_path):
    """``glacimap localize FIELD_FOLDER`` as ``process`` reads it (before: "expected a folder
    with meta.json"); the samples match what process's select stage gives."""
    res = runner.invoke(app, ["localize", str(EXAMPLE), "--out", str(tmp_path)])
    assert res.exit_code == 0, res.output
    assert "GPS gps.nmea (nmea): 156 of 156 records used" in res.output
    summary = json.loads((tmp_path / "localize_summary.json").read_text())
    assert summary["keyframes"] == 156
    n_rows = len((tmp_path / "samples.csv").read_text().splitlines()) - 1
    assert n_rows == summary["selection_counts"]["kept"] > 300
