"""``glacimap simulate`` and ``glacimap localize`` on a short single-swath survey, chained with
``glacimap plan`` and ``glacimap reconstruct`` through the command line; bad input."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import xarray as xr
from typer.testing import CliRunner

from factorgraph.log import read_log
from factorgraph.sensors import SensorSuite
from factorgraph.simulate import simulate_traverse
from survey import SurveyPlan
from terrain import InputError, default_site
from toolkit.cli import app
from toolkit.config import DEFAULT_SCENARIO

runner = CliRunner()
# One 160 m swath inside the default site: 81 keyframes, 160 s of driving.
BOUNDS = ["526020", "6475020", "526180", "6475120"]
LOG_TABLES = ("gps", "keyframes", "landmarks", "observations", "odometry")


def _ok(args):
    res = runner.invoke(app, [str(a) for a in args])
    assert res.exit_code == 0, (res.output, res.exception)
    return res


def _bad(args, *needles):
    """The command fails with an InputError whose message names every needle."""
    res = runner.invoke(app, [str(a) for a in args])
    assert res.exit_code != 0, res.output
    assert isinstance(res.exception, InputError), repr(res.exception)
    for needle in needles:
        assert needle in str(res.exception), str(res.exception)
    return str(res.exception)


@pytest.fixture(scope="module")
def chain(tmp_path_factory):
    """plan -> simulate (CSV) -> localize -> reconstruct, all through the CLI."""
    root = tmp_path_factory.mktemp("chain")
    _ok(["plan", "--swaths", "1", "--bounds", *BOUNDS, "--out", root / "plan"])
    sim = _ok(["simulate", "--plan", root / "plan" / "plan.json", "--out", root / "log"])
    loc = _ok(["localize", root / "log", "--out", root / "loc"])
    rec = _ok(
        ["reconstruct", root / "loc" / "samples.csv", "--resolution", "4", "--out", root / "rec"]
    )
    return {"root": root, "simulate": sim.output, "localize": loc.output, "rec": rec.output}


def test_simulate_writes_the_log_of_the_plan(chain):
    root = chain["root"]
    names = sorted(p.name for p in (root / "log").iterdir())
    assert names == sorted([f"{t}.csv" for t in LOG_TABLES] + ["meta.json"])
    log = read_log(root / "log")
    # reference: the library, driven directly with the plan file and the default sensors
    plan = SurveyPlan.from_dict(json.loads((root / "plan" / "plan.json").read_text()))
    ref = simulate_traverse(
        default_site(2.0), plan, SensorSuite.from_dict(DEFAULT_SCENARIO["sensors"]), seed=0
    )
    assert log.n_keyframes == ref.n_keyframes == 81  # 160 m at 2 m per keyframe, + 1
    for name, cols in ref.tables().items():
        got = log.tables()[name]
        assert list(got) == list(cols), name
        for col, want in cols.items():  # CSV keeps 9 significant digits
            np.testing.assert_allclose(got[col], want, rtol=1e-8, atol=1e-6, err_msg=col)
    assert log.seed == 0 and log.crs == "EPSG:32608"
    assert "81" in chain["simulate"] and "feature observations" in chain["simulate"]


def test_localize_tables_and_counts(chain):
    root = chain["root"]
    names = sorted(p.name for p in (root / "loc").iterdir())
    assert names == ["landmarks.csv", "localize_summary.json", "samples.csv", "trajectory.csv"]
    summary = json.loads((root / "loc" / "localize_summary.json").read_text())
    counts = summary["selection_counts"]
    removed = counts["sigma_above_max"] + counts["first_seen_too_close"]
    assert counts["in_graph"] == removed + counts["kept"]
    traj = pd.read_csv(root / "loc" / "trajectory.csv")
    lms = pd.read_csv(root / "loc" / "landmarks.csv")
    samples = pd.read_csv(root / "loc" / "samples.csv")
    assert len(traj) == summary["keyframes"] == 81
    assert np.array_equal(traj["k"], np.arange(81)) and (traj[["std_x", "std_z"]] > 0).all().all()
    assert len(lms) == counts["in_graph"] > 0
    # samples + what the error budget needs, so reconstruct gives run's sigma; CRS named
    cols = ["x", "y", "z", "z_var", "track_z_std_m", "shared_offset_std_m", "t_s", "crs"]
    assert list(samples.columns) == cols
    np.testing.assert_allclose(samples["shared_offset_std_m"], summary["shared_offset_std_m"][2])
    assert (samples["crs"] == "EPSG:32608").all()
    assert len(samples) == int(lms["kept"].sum()) == counts["kept"] > 0
    assert (samples["z_var"] > 0).all()
    # Eq 7: the sample variance is the landmark's z variance, its std in the landmark table
    kept = lms[lms["kept"]].sort_values(["x", "y"]).reset_index(drop=True)
    smp = samples.sort_values(["x", "y"]).reset_index(drop=True)
    np.testing.assert_allclose(np.sqrt(smp["z_var"]), kept["z_std_m"], rtol=1e-9)
    # the keyframe errors printed come from the truth columns of the trajectory table
    err = traj[["x", "y"]].to_numpy() - traj[["true_x", "true_y"]].to_numpy()
    assert summary["horizontal_rmse_m"] == pytest.approx(np.sqrt((err**2).sum(1).mean()))
    # the expected RMSE printed is the trajectory table's own horizontal 1-sigmas
    pred = np.sqrt((traj["std_x"] ** 2 + traj["std_y"] ** 2).mean())
    assert summary["predicted_horizontal_rmse_m"] == pytest.approx(pred, rel=1e-6)
    # no ordering against the frame floor here: over 81 s the GPS says little about the
    # heading and the estimator's 5-degree yaw prior at the start (which the floor leaves
    # out) is worth more (measured: expected 2.63 m against a floor of 2.66 m)
    assert summary["frame_floor_m"] > summary["horizontal_floor_m"] > 0
    out = chain["localize"]
    for text in ("landmarks selected", "never triangulated", "step median", "frame floor"):
        assert text in out, out
    for text in (str(counts["kept"]),):
        assert text in out, out
    assert summary["settings"]["select"]["max_sigma_m"] == DEFAULT_SCENARIO["select"]["max_sigma_m"]


def test_reconstruct_accepts_the_samples(chain):
    ds = xr.open_dataset(chain["root"] / "rec" / "product.nc")
    truth = default_site(2.0).interp(x=ds.x, y=ds.y)
    err = (ds["elevation"] - truth).values
    shared = json.loads((chain["root"] / "loc" / "localize_summary.json").read_text())
    # the map shares the traverse's GPS offset (1-sigma ~1.7 m vertically): its mean error
    # stays within 3 sigma of it, and its shape error below the offset itself
    assert abs(err.mean()) < 3 * shared["shared_offset_std_m"][2]
    assert np.sqrt(((err - err.mean()) ** 2).mean()) < 1.5
    assert (ds["elevation_std"].values > 0).all()
    # the shared offset is in the total sigma, not in the relative one
    assert (ds["elevation_std"].values >= ds["elevation_std_relative"].values).all()
    assert ds.attrs["shared_vertical_offset_std_m"] == pytest.approx(
        shared["shared_offset_std_m"][2]
    )


def test_parquet_round_trip_and_no_stale_tables(chain, tmp_path):
    log_dir = tmp_path / "log"
    _ok(["simulate", "--plan", chain["root"] / "plan" / "plan.json", "--out", log_dir])
    _ok(
        [
            "simulate",
            "--plan",
            chain["root"] / "plan" / "plan.json",
            "--out",
            log_dir,
            "--format",
            "parquet",
        ]
    )
    assert sorted(p.name for p in log_dir.iterdir()) == sorted(
        [f"{t}.parquet" for t in LOG_TABLES] + ["meta.json"]
    )
    _ok(["localize", log_dir, "--out", tmp_path / "loc", "--format", "parquet"])
    names = sorted(p.name for p in (tmp_path / "loc").iterdir())
    assert names == ["landmarks.parquet", "localize_summary.json", "samples.csv"] + [
        "trajectory.parquet"
    ]
    same = pd.read_csv(chain["root"] / "loc" / "samples.csv")
    got = pd.read_csv(tmp_path / "loc" / "samples.csv")
    # the same traverse: CSV keeps 9 digits of each measurement, Parquet all of them
    num = same.columns.drop("crs")
    np.testing.assert_allclose(got[num].to_numpy(), same[num].to_numpy(), rtol=1e-4)
    assert len(pd.read_parquet(tmp_path / "loc" / "trajectory.parquet")) == 81


def test_simulate_from_a_scenario_is_seeded(tmp_path):
    toml = tmp_path / "small.toml"
    toml.write_text(
        '[site]\nkind = "random"\nbounds = [526000.0, 6475000.0, 526140.0, 6475080.0]\n'
        "[plan]\nn_swaths = 1\n"
    )
    for name, seed in (("a", 3), ("b", 3), ("c", 4)):
        _ok(["simulate", "--config", toml, "--seed", seed, "--out", tmp_path / name])
    a, b, c = ((tmp_path / n / "gps.csv").read_bytes() for n in "abc")
    assert a == b and a != c
    assert read_log(tmp_path / "a").seed == 3


# -- bad input ---------------------------------------------------------------------------------
def test_localize_missing_log_dir(tmp_path):
    out = tmp_path / "out"
    _bad(["localize", tmp_path / "nope", "--out", out], "LOG_DIR", "nope")
    assert not out.exists()


@pytest.fixture
def log_copy(chain, tmp_path):
    """A writable copy of the chain's CSV log."""
    import shutil

    return Path(shutil.copytree(chain["root"] / "log", tmp_path / "log"))


def test_localize_malformed_tables_are_named(log_copy, tmp_path):
    out = tmp_path / "out"
    kf = log_copy / "keyframes.csv"
    text = kf.read_text()
    kf.write_text(text + ",".join(["81"] * 30) + "\n")  # a row with too many cells
    _bad(["localize", log_copy, "--out", out], "keyframes.csv")
    kf.write_text(text.replace("t_s", "time", 1))  # a missing column
    _bad(["localize", log_copy, "--out", out], "keyframes.csv", "t_s")
    lines = text.splitlines()
    lines[5] = ",".join(["4", "nan"] + lines[5].split(",")[2:])  # a NaN timestamp
    kf.write_text("\n".join(lines) + "\n")
    _bad(["localize", log_copy, "--out", out], "keyframes.t_s", "row 4")
    kf.write_text(text)
    (log_copy / "meta.json").write_text("{not json")
    _bad(["localize", log_copy, "--out", out], "meta.json")
    assert not out.exists() or not any(out.iterdir())


def test_localize_bad_options_fail_before_work(chain, tmp_path):
    log_dir, out = chain["root"] / "log", tmp_path / "out"
    _bad(["localize", log_dir, "--out", out, "--variance", "cubic"], "--variance", "cubic")
    _bad(["localize", log_dir, "--out", out, "--max-sigma", "-1"], "--max-sigma")
    _bad(["localize", log_dir, "--out", out, "--format", "xlsx"], "--format")
    (tmp_path / "file").write_text("")
    _bad(["localize", log_dir, "--out", tmp_path / "file" / "out"], "--out")
    assert not out.exists()


def test_localize_failure_while_writing_leaves_nothing(chain, tmp_path, monkeypatch):
    import toolkit.cli.localize as cli_localize

    real, calls = cli_localize._write_table, []

    def flaky(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise OSError("disk full")
        return real(*args, **kwargs)

    monkeypatch.setattr(cli_localize, "_write_table", flaky)
    out = tmp_path / "out"
    res = runner.invoke(app, ["localize", str(chain["root"] / "log"), "--out", str(out)])
    assert isinstance(res.exception, OSError)
    assert list(out.iterdir()) == []  # no table, no staging folder, no temporary


def test_simulate_bad_input(chain, tmp_path):
    out = tmp_path / "out"
    _bad(["simulate", "--out", out, "--format", "xls"], "--format", "xls")
    _bad(["simulate", "--plan", tmp_path / "none.json", "--out", out], "--plan")
    bad = tmp_path / "plan.json"
    bad.write_text("{")
    _bad(["simulate", "--plan", bad, "--out", out], "--plan", "JSON")
    plan = json.loads((chain["root"] / "plan" / "plan.json").read_text())
    bad.write_text(json.dumps({k: v for k, v in plan.items() if k != "waypoints"}))
    _bad(["simulate", "--plan", bad, "--out", out], "plan.json keys", "waypoints")
    bad.write_text(json.dumps({**plan, "swath": [0, 5]}))
    _bad(["simulate", "--plan", bad, "--out", out], "plan.json", "swath")
    far = {**plan, "waypoints": [[w + 5000, n] for w, n in plan["waypoints"]]}
    bad.write_text(json.dumps(far))
    _bad(["simulate", "--plan", bad, "--out", out], "waypoints", "inside the DEM")
    toml = tmp_path / "s.toml"
    toml.write_text("[plan]\nn_swath = 1\n")
    _bad(["simulate", "--config", toml, "--out", out], "plan.n_swath", "did you mean 'n_swaths'")
    assert not out.exists() or not any(out.iterdir())


def test_exit_code_and_message_in_a_shell(tmp_path):
    res = subprocess.run(
        [sys.executable, "-m", "toolkit", "localize", str(tmp_path / "nope")],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=tmp_path,
    )
    assert res.returncode == 2, res.stderr
    assert "error: LOG_DIR" in res.stderr and "glacimap simulate" in res.stderr
    assert "Traceback" not in res.stderr
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    "args, needle",
    [
        (["nosuch"], "No such command"),
        (["simulate", "--bogus"], "No such option"),
        (["localize"], "Missing argument"),
    ],
)
def test_usage_errors_exit_2_without_traceback(tmp_path, args, needle):
    """typer vendors its own click: its usage errors must still print click's message."""
    res = subprocess.run(
        [sys.executable, "-m", "toolkit", *args],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=tmp_path,
    )
    assert res.returncode == 2 and needle in res.stderr and "Traceback" not in res.stderr


@pytest.mark.parametrize("table", ["gps", "keyframes", "odometry", "observations"])
def test_localize_empty_required_table_is_one_line(log_copy, tmp_path, table):
    """Issue 17: a gps.csv with a header only ended in a 'zero-size array' traceback."""
    path = log_copy / f"{table}.csv"
    path.write_text(path.read_text().splitlines()[0] + "\n")  # the header, no rows
    out = tmp_path / "out"
    msg = _bad(["localize", log_copy, "--out", out], f"{table}.csv", "no rows", "Fix")
    assert "\n" not in msg.strip()
    assert not out.exists() or not any(out.iterdir())
