"""Stops on ground-control points through the field folder (``stops.csv``,
docs/field-format.md): written by ``write_field_log``, read by ``read_field_log`` into the
log's ``control_id``, counted when not used, and carried by ``glacimap run`` (``[control]
mode``) through ``process`` into the graph and the certificate."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from _scenarios import small_run

from factorgraph import localize, read_field_log, write_field_log
from factorgraph.control_sim import path_corners, simulate_control
from factorgraph.field.stops import read_stops
from factorgraph.simulate import simulate_traverse
from terrain.errors import InputError
from terrain.synthetic import default_site

W, N = 526000.0, 6475600.0
#: three 60 m legs joined by 15 m cross legs (tests/test_field_roundtrip.py): 4 path corners
LEGS = np.array(
    [[W + 20, N - 75], [W + 80, N - 75], [W + 80, N - 60], [W + 20, N - 60]]
    + [[W + 20, N - 45], [W + 80, N - 45]]
)


@pytest.fixture(scope="module")
def dem():
    return default_site(2.0)


@pytest.fixture(scope="module")
def stopped(dem):
    """The traverse with stops on 3 points: the first keyframe, the path's SE corner (where
    the first leg turns) and the last keyframe."""
    log = simulate_traverse(dem, LEGS, seed=3)
    ks = [0, int(path_corners(log)[1]), log.n_keyframes - 1]
    slog, ctrl, _ = simulate_control(log, ks, names=["A", "B", "C"])
    return log, slog, ctrl


def test_stops_round_trip_through_the_field_folder(stopped, tmp_path):
    _, slog, _ = stopped
    write_field_log(slog, tmp_path)
    text = (tmp_path / "stops.csv").read_text().splitlines()
    assert text[0] == "t_s,k,control_id" and len(text) == 1 + 3
    assert json.loads((tmp_path / "survey.json").read_text())["stops"] == "stops.csv"
    back, rep = read_field_log(tmp_path)
    assert back.control_id.tolist() == slog.control_id.tolist()
    assert rep.stops == {
        "file": "stops.csv",
        "rows": 3,
        "keyframes": 3,
        "points": ["A", "B", "C"],
        "skipped": {},
    }
    assert any(line.startswith("stops stops.csv: 3 keyframes on 3") for line in rep.lines())


def test_no_stops_no_file(stopped, tmp_path):
    log, slog, _ = stopped
    write_field_log(slog, tmp_path)
    write_field_log(log, tmp_path)  # rewritten without stops: no stale stops.csv
    assert not (tmp_path / "stops.csv").exists()
    assert "stops" not in json.loads((tmp_path / "survey.json").read_text())
    back, rep = read_field_log(tmp_path)
    assert back.control_id is None and rep.stops == {}


def test_stops_by_time_are_matched_and_bad_rows_counted(tmp_path):
    """Hand-made table on keyframes at 0, 2, 4, 6 s with a 1 s tolerance: each reason once."""
    t_kf = np.array([0.0, 2.0, 4.0, 6.0])
    path = tmp_path / "stops.csv"
    path.write_text(
        "t_s,control_id\n"
        "0.4,GCP1\n"  # -> k 0
        "3.6,7\n"  # -> k 2, a numeric id stays "7"
        "4.2,7\n"  # -> k 2 again: duplicate_stop
        "9.5,GCP2\n"  # 3.5 s after the last keyframe: off_keyframe
        "6.0,\n"  # empty_control_id
        "nan,GCP3\n"  # not a time: off_keyframe
    )
    ids, skipped, n = read_stops(path, t_kf, 1.0)
    assert ids.tolist() == ["GCP1", "", "7", ""] and n == 6
    assert dict(skipped) == {"duplicate_stop": 1, "off_keyframe": 2, "empty_control_id": 1}
    path.write_text("k,control_id\n0,GCP1\n4,GCP2\n-1,GCP3\n1.5,GCP4\n3,GCP5\n")
    ids, skipped, _ = read_stops(path, t_kf, 1.0)
    assert ids.tolist() == ["GCP1", "", "", "GCP5"]
    assert dict(skipped) == {"keyframe_out_of_range": 3}


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("t_s,control_id\n0,A\n0.2,B\n", "row 3.*'B' at keyframe 0.*already stands on 'A'"),
        ("t_s,point\n0,A\n", "columns control_id and t_s"),
        ("control_id\nA\n", "columns control_id and t_s"),
    ],
)
def test_bad_stops_files_name_the_problem(tmp_path, text, match):
    path = tmp_path / "stops.csv"
    path.write_text(text)
    with pytest.raises(InputError, match=match):
        read_stops(path, np.array([0.0, 2.0]), 1.0)


def test_localize_uses_stops_read_from_the_folder(stopped, tmp_path):
    """The read-back log with the control file's points ties the graph at the stops exactly
    as the in-memory log does (same GPS rounding: the in-memory log with the read-back GPS)."""
    _, slog, ctrl = stopped
    write_field_log(slog, tmp_path)
    back, _ = read_field_log(tmp_path)
    res = localize(back, control=ctrl)
    same = dataclasses.replace(slog, gps_xyz=back.gps_xyz, gps_sigma=back.gps_sigma)
    ref = localize(same, control=ctrl)
    rep = res.control
    assert rep["n_used"] == 3 and rep["unused"] == {}
    assert {u["id"]: u["kind"] for u in rep["used"]} == {"A": "stop", "B": "stop", "C": "stop"}
    assert [u["keyframes"] for u in rep["used"]] == [u["keyframes"] for u in ref.control["used"]]
    np.testing.assert_allclose(res.keyframe_xyz, ref.keyframe_xyz, atol=1e-9)
    assert np.sqrt(res.shared_offset_cov[2, 2]) < 0.1  # 2 cm control on a 3-minute traverse
    plain = localize(back)  # the stops without a control file: nothing to tie to
    assert plain.control == {} and np.sqrt(plain.shared_offset_cov[2, 2]) > 0.5


#: a small seeded run (tests/test_run_products.py: a 300 m corner of the default site, two
#: swaths, a 5 m grid) with 4 control points at the path's corners
SMALL_RUN = small_run(
    n_boot=200,
    extra='heldout_folds = 0\n[export]\nmesh = false\n[control]\nn_targets = 4\nmode = "{mode}"\n',
)


@pytest.mark.slow
def test_glacimap_run_stops_reach_the_graph_and_the_certificate(tmp_path):
    """``[control] mode = "stops"``: the run writes rover/stops.csv and control.csv, process
    reads the stops back and ties the graph there; the certificate names each point and how it
    was used. The same field folder processed without the control file uses no control and
    says that the stops were not used."""
    from toolkit.pipeline import run_scenario
    from toolkit.processing import process

    cfg = tmp_path / "small.toml"
    cfg.write_text(SMALL_RUN.format(mode="stops"))
    res = run_scenario(cfg, out=tmp_path / "run")
    field = tmp_path / "run" / "field"
    rows = (field / "rover" / "stops.csv").read_text().splitlines()
    stops = {int(r.split(",")[1]): r.split(",")[2] for r in rows[1:]}  # k -> id, by time
    corners = path_corners(res.objects["log"])  # SW, SE, NE, NW
    assert stops == {int(k): f"GCP{i + 1}" for i, k in enumerate(corners)}
    cert = json.loads((tmp_path / "run" / "certificate.json").read_text())
    ctl = cert["localization"]["control"]
    assert ctl["n_used"] == 4 and ctl["unused"] == {}
    assert {u["id"]: u["kind"] for u in ctl["used"]} == {f"GCP{i}": "stop" for i in (1, 2, 3, 4)}
    assert cert["inputs"]["control"].startswith("4 points (control.csv); used: GCP1 stop")
    assert cert["ingest"]["stops"]["keyframes"] == 4
    # 2 cm control: the stated shared vertical offset is small, the keyframes near the truth
    assert cert["localization"]["shared_offset_std_m"][2] < 0.15
    for u in ctl["used"]:
        assert np.abs(u["stop_residual_m"]).max() < 0.1

    plain = process(
        field / "rover",
        prior=field / "prior.tif",
        checkpoints=field / "checkpoints.csv",
        config=res.settings,
        out=tmp_path / "plain",
    )
    pc = plain.summary["certificate"]
    assert "control" not in pc["localization"] and pc["inputs"]["control"] is None
    assert any("stops were not used" in w for w in pc["warnings"])
    assert pc["localization"]["shared_offset_std_m"][2] > 0.3  # consumer GPS, no control


def _scenario(n: int, mode: str) -> dict:
    return {"seed": 3, "control": {"n_targets": n, "mode": mode, "sigma_m": 0.02}}


def test_simulated_control_modes(dem, stopped):
    """``[control]`` of a simulated survey: 4 corner stops, 4 targets, both (8 points), or a
    stop at every waypoint of the plan (``n_targets = 8``; LEGS has 6: all 6)."""
    from types import SimpleNamespace

    from factorgraph.control_sim import nearest_keyframes
    from toolkit.field_survey import simulated_control

    log = stopped[0]
    assert simulated_control(_scenario(0, "stops"), dem, log) == (log, None)
    slog, ctrl = simulated_control(_scenario(4, "stops"), dem, log)
    corners = path_corners(log)
    assert ctrl.ids.tolist() == ["GCP1", "GCP2", "GCP3", "GCP4"] and (ctrl.target_id < 0).all()
    assert slog.control_id[corners].tolist() == ctrl.ids.tolist()
    tlog, tctrl = simulated_control(_scenario(4, "targets"), dem, log)
    assert tctrl.ids.tolist() == ["T1", "T2", "T3", "T4"] and tlog.control_id is None
    blog, bctrl = simulated_control(_scenario(4, "both"), dem, log)
    assert bctrl.n == 8 and (bctrl.target_id >= 0).sum() == 4
    assert (blog.control_id != "").sum() == 4 and blog.obs_id.size == tlog.obs_id.size
    plan = SimpleNamespace(waypoints=LEGS)
    elog, ectrl = simulated_control(_scenario(8, "stops"), dem, log, plan)
    ks = nearest_keyframes(log, LEGS)
    assert ectrl.n == 6 and elog.control_id[ks].tolist() == [f"GCP{i}" for i in range(1, 7)]
    for n, mode, p, match in [
        (8, "targets", plan, 'mode = "stops" with a plan'),
        (8, "stops", None, 'mode = "stops" with a plan'),
        (5, "stops", None, "0, 4 or 8"),
    ]:
        with pytest.raises(InputError, match=match):
            simulated_control(_scenario(n, mode), dem, log, p)


def test_corner_stops_on_a_single_swath_are_refused_when_the_scenario_loads():
    """One straight swath has two ends, not four corners: refused before any simulation
    (a run with rendered frames would otherwise fail minutes later)."""
    from terrain.errors import InputError
    from toolkit.config import load_scenario

    with pytest.raises(InputError, match=r"control\.n_targets") as err:
        load_scenario(overrides={"plan": {"n_swaths": 1}, "control": {"n_targets": 4}})
    assert "n_swaths" in str(err.value)
    assert load_scenario(overrides={"plan": {"n_swaths": 1}})["control"]["n_targets"] == 0
