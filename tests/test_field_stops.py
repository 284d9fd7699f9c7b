"""Stops on ground-control points through the field folder (``stops.csv``,
docs/field-format.md): written by ``write_field_log``, read by ``read_field_log`` into the
log's ``control_id``, counted when not used, and carried by ``glacimap run`` (``[control]
mode``) through ``process`` into the graph and the certificate."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

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
