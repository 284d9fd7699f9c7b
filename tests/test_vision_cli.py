"""``glacimap simulate --camera images`` and ``glacimap localize`` on a log with images/."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from factorgraph.log import read_log
from terrain import InputError
from toolkit.cli import app

runner = CliRunner()
BOUNDS = ["526020", "6475020", "526070", "6475060"]  # one 30 m swath: 16 keyframes


def _ok(args):
    res = runner.invoke(app, [str(a) for a in args])
    assert res.exit_code == 0, (res.output, res.exception)
    return res


@pytest.fixture(scope="module")
def chain(tmp_path_factory):
    root = tmp_path_factory.mktemp("vision_cli")
    _ok(["plan", "--swaths", "1", "--bounds", *BOUNDS, "--out", root / "plan"])
    sim = _ok(
        [
            "simulate",
            "--plan",
            root / "plan" / "plan.json",
            "--out",
            root / "log",
            "--camera",
            "images",
        ]
    )
    loc = _ok(["localize", root / "log", "--out", root / "loc"])
    return {"root": root, "simulate": sim.output, "localize": loc.output}


@pytest.mark.slow  # renders and tracks 16 frames, localizes 3 times: ~100 s here
def test_simulate_writes_frames_and_their_tracks(chain):
    root = chain["root"]
    log = read_log(root / "log")
    stamps = pd.read_csv(root / "log" / "images" / "timestamps.csv")
    assert len(stamps) == log.n_keyframes
    np.testing.assert_allclose(stamps["t_s"], log.t)
    assert all((root / "log" / "images" / f).is_file() for f in stamps["file"])
    assert log.sensors.camera.height_m == 1.5  # the vision preset, recorded in meta.json
    assert log.obs_k.size > 0 and "front-end" in chain["simulate"]
    # every landmark of the truth table is a track of the observations table
    assert set(log.truth["landmark_id"]) <= set(log.obs_id.tolist())


@pytest.mark.slow  # renders and tracks 16 frames, localizes 3 times: ~100 s here
def test_localize_tracks_the_images_and_keeps_the_truth(chain):
    root = chain["root"]
    assert "front-end on" in chain["localize"] and "differ" not in chain["localize"]
    summary = json.loads((root / "loc" / "localize_summary.json").read_text())
    assert summary["selection_counts"]["in_graph"] > 0
    assert 0 < summary["landmark_nees_mean"] < 20  # truth matched the re-tracked landmarks
    # the tracks simulate stored beside the frames were reused, and the summary says so
    assert summary["front_end"]["source"].startswith("reused")
    assert summary["front_end"]["tracks"] > 0 and "(reused" in " ".join(chain["localize"].split())


@pytest.mark.slow  # renders and tracks 16 frames, localizes 3 times: ~100 s here
def test_localize_survives_missing_and_broken_frames(chain, tmp_path):
    import shutil

    log_dir = tmp_path / "log"
    shutil.copytree(chain["root"] / "log", log_dir)
    (log_dir / "images" / "frame_000005.png").unlink()
    (log_dir / "images" / "frame_000010.png").write_bytes(b"\x89PNG broken")
    res = _ok(["localize", log_dir, "--out", tmp_path / "loc"])
    out = " ".join(res.output.split())  # the console wraps long lines
    assert "missing_file" in out and "unreadable" in out
    assert "landmark truth not used" in out  # the tracks changed
    summary = json.loads((tmp_path / "loc" / "localize_summary.json").read_text())
    assert summary["front_end"]["source"].startswith("tracked")  # frames differ: re-tracked


def test_bad_camera_option_is_an_input_error(tmp_path):
    res = runner.invoke(app, ["simulate", "--out", str(tmp_path), "--camera", "lidar"])
    assert isinstance(res.exception, InputError) and "--camera" in str(res.exception)


def test_long_image_plan_states_its_cost_and_warns(monkeypatch, tmp_path):
    """Before rendering, ``--camera images`` states how many frames and about how long; a
    plan far longer than the default survey (a whole DEM with bounds omitted) is warned."""
    from types import SimpleNamespace

    import factorgraph.vision
    import toolkit.cli.simulate as sim
    from toolkit.config import load_scenario

    class Stop(Exception):
        pass

    def no_render(*args, **kwargs):
        raise Stop

    monkeypatch.setattr(factorgraph.vision, "simulate_images", no_render)
    scenario = load_scenario()  # 1 m/s, a keyframe every 2 s
    for length_m, warned in ((2_000.0, False), (20_000.0, True)):
        with sim.console.capture() as cap, pytest.raises(Stop):
            sim._simulate_images(
                scenario, None, SimpleNamespace(path_length=length_m), "sunny_snow", tmp_path
            )
        out = " ".join(cap.get().split())
        frames = int(length_m / 2.0)
        assert f"{frames} frames to render and track: about" in out
        assert ("warning" in out and "[site] bounds" in out) == warned


@pytest.fixture(scope="module")
def field_chain(tmp_path_factory):
    """A rover's field folder with camera frames (``--format field --camera images``)."""
    root = tmp_path_factory.mktemp("vision_field")
    _ok(["plan", "--swaths", "1", "--bounds", *BOUNDS, "--out", root / "plan"])
    plan = root / "plan" / "plan.json"
    _ok(
        ["simulate", "--plan", plan, "--out", root / "field", "--camera", "images"]
        + ["--format", "field"]
    )
    return root


def _elevation(folder):
    import rasterio

    with rasterio.open(folder / "elevation.tif") as src:
        return src.read(1)


@pytest.mark.slow  # renders and tracks 26 frames, processes 3 times: ~40 s here
def test_process_tracks_a_field_folders_frames_like_its_tracks_table(field_chain, tmp_path):
    """``glacimap process`` on a field folder with images/ runs the front-end (reusing the
    tracks stored beside the frames: the camera read back from camera.yaml and the odometry
    from odometry.csv hash as those tracked), says so in the certificate, and gives the map
    that the folder's tracks.csv gives (``--no-images``) and that the frames alone give."""
    import shutil

    field = field_chain / "field"
    assert (field / "images" / "timestamps.csv").is_file() and (field / "tracks.csv").is_file()
    res = _ok(["process", field, "--out", tmp_path / "img"])
    assert "to track with the OpenCV front-end" in " ".join(res.output.split())
    cert = json.loads((tmp_path / "img" / "certificate.json").read_text())
    fe = cert["ingest"]["front_end"]
    assert fe["source"].startswith("reused images/") and fe["tracks"] > 50
    assert cert["ingest"]["tracks"] == "front-end on images/" and fe["frames_skipped"] == {}
    _ok(["process", field, "--no-images", "--out", tmp_path / "table"])
    cert_t = json.loads((tmp_path / "table" / "certificate.json").read_text())
    assert cert_t["ingest"]["tracks"] == "tracks.csv" and not cert_t["ingest"]["front_end"]
    np.testing.assert_array_equal(_elevation(tmp_path / "img"), _elevation(tmp_path / "table"))
    # what a rover brings home: frames, no tracks table
    only = tmp_path / "frames_only"
    shutil.copytree(field, only)
    (only / "tracks.csv").unlink()
    _ok(["process", only, "--out", tmp_path / "only"])
    np.testing.assert_array_equal(_elevation(tmp_path / "img"), _elevation(tmp_path / "only"))
    res = runner.invoke(app, ["process", str(only), "--no-images", "--out", str(tmp_path / "x")])
    assert isinstance(res.exception, InputError)
    assert "tracks" in str(res.exception) and "--no-images" in str(res.exception)
    assert not (tmp_path / "x").exists()


@pytest.mark.slow  # renders and tracks 26 frames: ~15 s here
def test_localize_on_a_field_folder_tracks_its_frames_once(field_chain, tmp_path):
    res = _ok(["localize", field_chain / "field", "--out", tmp_path / "loc"])
    out = " ".join(res.output.split())
    assert out.count("front-end on images") == 1 and "front-end rejections:" in out
    summary = json.loads((tmp_path / "loc" / "localize_summary.json").read_text())
    assert summary["front_end"]["source"].startswith("reused")
    assert summary["selection_counts"]["in_graph"] > 0


def test_field_camera_settings_are_checked_when_the_scenario_loads():
    from toolkit.config import load_scenario

    for over, field in (
        ({"field": {"camera": "lidar"}}, "field.camera"),
        ({"field": {"camera": "images", "scene": "fog"}}, "field.scene"),
        (
            {"field": {"camera": "images"}, "control": {"n_targets": 4, "mode": "targets"}},
            "control.mode",
        ),
    ):
        with pytest.raises(InputError, match=field.replace(".", r"\.")):
            load_scenario(overrides=over)
    assert load_scenario(overrides={"field": {"camera": "images"}})["field"]["scene"] == (
        "sunny_snow"
    )


@pytest.mark.slow  # renders and tracks ~40 frames, then runs twice: ~40 s here
def test_run_with_camera_images_processes_the_rendered_frames(tmp_path):
    """``glacimap run --camera images``: the frames go into the field folder, ``process``
    tracks them (reusing the tracks stored at rendering) and the certificate says so; a run
    with ideal tracks into the same folder leaves no stale frames behind."""
    toml = tmp_path / "tiny.toml"
    toml.write_text(
        "[site]\nbounds = [526000.0, 6475000.0, 526080.0, 6475080.0]\n"
        "[plan]\nn_swaths = 1\n[certify]\nn_checkpoints = 50\n"
    )
    out = tmp_path / "run"
    _ok(["run", "--config", toml, "--camera", "images", "--out", out])
    cert = json.loads((out / "certificate.json").read_text())
    assert cert["scenario"]["field"]["camera"] == "images"
    assert cert["ingest"]["tracks"] == "front-end on images/"
    assert cert["ingest"]["front_end"]["source"].startswith("reused images/")
    assert (out / "field" / "rover" / "images" / "timestamps.csv").is_file()
    # the landmarks scored against the renderer's truth by id, through the field folder
    sim = cert["localization"]["simulation"]
    assert 0 < sim["landmark_nees_mean"] < 20 and sim["landmark_within_2sigma"] > 0.5
    assert sim["landmark_rmse_3d_m"] > 0
    html = (out / "report.html").read_text()  # the report says where the tracks came from
    assert 'id="ingest"' in html and "camera front-end on images/" in html
    _ok(["run", "--config", toml, "--out", out])
    cert = json.loads((out / "certificate.json").read_text())
    assert cert["ingest"]["tracks"] == "tracks.csv" and not cert["ingest"]["front_end"]
    assert not (out / "field" / "rover" / "images").exists()


def test_process_names_the_frames_it_will_track_from_the_manifest(tmp_path):
    """The pre-ingest estimate reads the frames folder survey.json names (not only images/)."""
    from rich.console import Console

    from toolkit.cli.process import _say_frames

    (tmp_path / "survey.json").write_text(json.dumps({"images": "cam"}))
    (tmp_path / "cam").mkdir()
    rows = "\n".join(f"{2.0 * k},f{k}.png" for k in range(600))
    (tmp_path / "cam" / "timestamps.csv").write_text("t_s,file\n" + rows + "\n")
    console = Console(width=200)
    with console.capture() as cap:
        _say_frames(console, tmp_path)
    out = cap.get()
    assert "600 to track with the OpenCV front-end" in out and "cam" in out
    assert "about 2-4 min" in out  # 600 x 0.16-0.37 s
