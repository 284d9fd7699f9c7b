"""The main job: ``glacimap reconstruct --demo`` and the paper's Fig. 5 comparison."""

import json
import subprocess
import sys

import numpy as np
import pytest
from typer.testing import CliRunner

from toolkit.cli import app
from toolkit.demo import reconstruction_demo

runner = CliRunner()


def test_cli_demo_small_writes_figure_and_summary(tmp_path):
    res = runner.invoke(
        app,
        [
            "reconstruct",
            "--demo",
            "--n-samples",
            "600",
            "--resolution",
            "10",
            "--out",
            str(tmp_path),
        ],
    )
    assert res.exit_code == 0, res.output
    assert "GP + satellite prior" in res.output and "Delaunay" in res.output
    png = (tmp_path / "demo.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    summary = json.loads((tmp_path / "demo_summary.json").read_text())
    assert summary["seed"] == 0 and summary["n_samples"] == 600
    assert not list(tmp_path.glob("*.tmp"))  # no temporary files left behind


def test_cli_csv_reconstruction_roundtrip(tmp_path):
    import xarray as xr

    rng = np.random.default_rng(0)
    xy = rng.uniform(0, 100, (80, 2)) + [526000, 6475000]
    z = 100 + 0.05 * (xy[:, 0] - 526000)
    csv = tmp_path / "pts.csv"
    np.savetxt(
        csv,
        np.column_stack([xy, z, np.full(80, 0.01)]),
        delimiter=",",
        header="x,y,z,z_var",
        comments="",
    )
    res = runner.invoke(
        app, ["reconstruct", str(csv), "--resolution", "10", "--out", str(tmp_path / "o")]
    )
    assert res.exit_code == 0, res.output
    ds = xr.open_dataset(tmp_path / "o" / "reconstruction.nc", engine="scipy")
    assert set(ds.data_vars) == {"elevation", "elevation_std"} and ds.attrs["seed"] == 0
    assert float(np.abs(ds.elevation - (100 + 0.05 * (ds.x - 526000))).max()) < 0.2


def test_cli_bad_input_exit_codes(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("x,y,elev\n1,2,3\n4,5,6\n7,8,9\n")
    cmd = [sys.executable, "-m", "toolkit", "reconstruct"]
    out = subprocess.run(
        [*cmd, str(bad), "--out", str(tmp_path / "o")], capture_output=True, text=True
    )
    assert out.returncode == 2 and "missing ['z']" in out.stderr
    out = subprocess.run(cmd + ["--out", str(tmp_path / "o")], capture_output=True, text=True)
    assert out.returncode == 2 and "exactly one of" in out.stderr
    assert not (tmp_path / "o" / "reconstruction.nc").exists()


@pytest.mark.slow
def test_fig5_comparison_and_calibration_on_default_site():
    # Issue "must show": ~5,000 noisy track samples on the default site.
    r = reconstruction_demo(seed=0, n_samples=5000, resolution=4.0)
    m = r.metrics
    assert m["gp_satellite"]["rmse"] < m["gp_constant"]["rmse"] < m["delaunay"]["rmse"]
    assert m["delaunay"]["covered_fraction"] < 1.0
    assert m["gp_satellite"]["covered_fraction"] == 1.0
    for key in ("gp_satellite", "gp_constant"):
        assert 0.90 <= m[key]["coverage_95"] <= 0.98, m[key]
        assert 0.8 <= m[key]["z_std"] <= 1.2, m[key]
