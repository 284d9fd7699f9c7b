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


def test_example_folder_is_reproducible(tmp_path):
    res = _simulate(tmp_path)
    assert res.exit_code == 0, res.output
    made = sorted(p.name for p in tmp_path.iterdir())
    assert made == [
        "camera.yaml",
        "gps.nmea",
        "odometry.csv",
        "survey.json",
        "tilt.csv",
        "tracks.csv",
    ]
    for name in made:
        assert (tmp_path / name).read_bytes() == (EXAMPLE / name).read_bytes(), name
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
