"""``glacimap plan`` and ``glacimap sweep`` over the public survey API."""

import json

from typer.testing import CliRunner

from toolkit.cli import app

runner = CliRunner()


def test_plan_writes_json_and_png(tmp_path):
    res = runner.invoke(
        app, ["plan", "--pattern", "piecewise_continuous", "--swaths", "3", "--out", str(tmp_path)]
    )
    assert res.exit_code == 0, res.output
    plan = json.loads((tmp_path / "plan.json").read_text())
    assert plan["pattern"] == "piecewise_continuous" and plan["params"]["n_swaths"] == 3
    assert 0 < plan["metrics"]["centeredness_alpha"] < 1
    assert (tmp_path / "plan.png").read_bytes()[:4] == b"\x89PNG"


def test_plan_bad_pattern_and_swaths(tmp_path):
    res = runner.invoke(app, ["plan", "--pattern", "spiral", "--out", str(tmp_path)])
    assert res.exit_code != 0 and "spiral" in str(res.exception)
    res = runner.invoke(app, ["plan", "--swaths", "0", "--out", str(tmp_path)])
    assert res.exit_code != 0 and "n_swaths" in str(res.exception)
    assert not (tmp_path / "plan.json").exists()


def test_sweep_cli_small_prints_minimum_swaths(tmp_path):
    res = runner.invoke(
        app,
        [
            "sweep",
            "--terrains",
            "2",
            "--swaths",
            "1,3",
            "--resolution",
            "30",
            "--spacing",
            "30",
            "--workers",
            "1",
            "--out",
            str(tmp_path),
        ],
    )
    assert res.exit_code == 0, res.output
    assert "Minimum swaths" in res.output and "tasks/s" in res.output
    for name in (
        "results.sqlite",
        "summary.json",
        "fig10_rmse_vs_swaths.png",
        "fig11_class_limit.png",
    ):
        assert (tmp_path / name).exists()
    res = runner.invoke(
        app, ["sweep", "--terrains", "2", "--swaths", "1-x", "--out", str(tmp_path / "bad")]
    )
    assert res.exit_code != 0 and "--swaths" in str(res.exception)
