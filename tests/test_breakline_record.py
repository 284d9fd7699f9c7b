"""The breaklines read back from a product's attributes (``toolkit.breakline_record``).

References: hand values (a 3-4-5 triangle's legs and a straight 10 m line); the attribute
layout written by ``terrain.product.gp_provenance`` (a fitted map's round trip is in
``tests/test_breakline_scenario.py``: certificate and report of a ``glacimap run``).
"""

from __future__ import annotations

import json

import pytest

from toolkit.breakline_record import SAME_LINE_M, breakline_rows, step_changes


def _provenance(lacks: list | None) -> dict[str, str]:
    feature = {
        "type": "Feature",
        "geometry": {
            "type": "MultiLineString",
            "coordinates": [[[0.0, 0.0], [3.0, 0.0], [3.0, 4.0]], [[0.0, 10.0], [10.0, 10.0]]],
        },
        "properties": {
            "widths_m": [1.0, 2.0],
            "tapers_m": [None, 40.0],
            "open_ends": [[False, False], [False, True]],
        },
    }
    coef = {"offset_m": [1.0, 0.1], "step1_m": [4.0, 0.2], "step2_m": [-2.5, 0.3]}
    return {
        "breaklines": json.dumps(feature),
        "mean_coefficients": json.dumps(coef),
        "breakline_dem_lacks": json.dumps(lacks) if lacks else "",
    }


def test_each_line_with_its_step_width_ends_and_length():
    rows = breakline_rows(_provenance([{"m": 0.1, "sd_m": 0.5}, {"m": 2.4, "sd_m": 0.6}]))
    assert [r["line"] for r in rows] == [1, 2]
    assert [r["length_m"] for r in rows] == [7.0, 10.0]  # 3 + 4; 10 (by hand)
    assert [(r["step_m"], r["step_sd_m"]) for r in rows] == [(4.0, 0.2), (-2.5, 0.3)]
    assert [r["width_m"] for r in rows] == [1.0, 2.0]
    assert [r["open_ends"] for r in rows] == [[], ["last"]]
    assert [r["taper_m"] for r in rows] == [None, 40.0]
    assert [(r["dem_lacks_m"], r["dem_lacks_sd_m"]) for r in rows] == [(0.1, 0.5), (2.4, 0.6)]
    assert rows[0]["n_vertices"] == 3 and rows[0]["vertices"][2] == [3.0, 4.0]


def test_no_prior_that_smooths_the_steps_and_no_lines():
    rows = breakline_rows(_provenance(None))
    assert [r["dem_lacks_m"] for r in rows] == [None, None]
    assert breakline_rows({"breaklines": "", "mean_coefficients": "{}"}) == []
    assert breakline_rows({}) == []  # a product made before breaklines were recorded


def _epoch(steps, widths_sd, shift=0.0, widths=(1.0, 2.0)):
    """Rows of a map with the two lines above (the second moved by ``shift`` m)."""
    rows = breakline_rows(_provenance(None))
    for r, (step, sd), w, wsd in zip(rows, steps, widths, widths_sd, strict=True):
        r.update(step_m=step, step_sd_m=sd, width_m=w, width_sd_m=wsd)
    rows[1]["vertices"] = [[x + shift, y] for x, y in rows[1]["vertices"]]
    return rows


def test_a_step_change_for_the_same_line_with_comparable_steps():
    # hand values: 4.0 +- 0.3 -> 4.5 +- 0.4 is +0.5 +- 0.5 (3-4-5); line 2 moved 1 m
    before = _epoch([(4.0, 0.3), (-2.5, 0.3)], [0.1, 0.2])
    after = _epoch([(4.5, 0.4), (-2.0, 0.3)], [0.1, 0.2], shift=1.0)
    one, two = step_changes(before, after)
    assert one == {
        "line": 1,
        "change_m": pytest.approx(0.5),
        "change_sd_m": pytest.approx(0.5),
        "method": "each map at its own width, combined as independent",
    }
    assert "change_m" not in two and "differs" in two["reason"]
    # moved by less than SAME_LINE_M: the same line
    after = _epoch([(4.5, 0.4), (-2.0, 0.3)], [0.1, 0.2], shift=0.5 * SAME_LINE_M)
    assert step_changes(before, after)[1]["change_m"] == pytest.approx(0.5)
    # the after map has one line only
    assert "no line 2" in step_changes(before, after[:1])[1]["reason"]


def test_steps_whose_sigma_leaves_the_width_out_are_compared_only_at_one_width():
    # products before 0.41.0 (no width 1-sigma) at different widths: no change, said why
    before = _epoch([(4.0, 0.3), (-2.5, 0.3)], [None, None])
    after = _epoch([(4.5, 0.4), (-2.0, 0.3)], [None, None], widths=(1.5, 2.0))
    one, two = step_changes(before, after)
    assert "different widths" in one["reason"]
    # the same width given to both maps: comparable
    assert two["change_m"] == pytest.approx(0.5)
    assert two["change_sd_m"] == pytest.approx(0.3 * 2**0.5)
    assert two["method"] == "the width given to both maps"
    # one map's width chosen, the other's given: not comparable
    after = _epoch([(4.5, 0.4), (-2.0, 0.3)], [0.1, None])
    assert "different widths" in step_changes(before, after)[0]["reason"]


def test_without_the_maps_gps_the_changes_stay_independent():
    # at_shared_width needs both GPs (the GP route): without them each change is kept as
    # step_changes gave it; a row without a change (a moved line) is kept as it is
    from toolkit.breakline_record import at_shared_width

    before = _epoch([(4.0, 0.3), (-2.5, 0.3)], [0.1, 0.2])
    after = _epoch([(4.5, 0.4), (-2.0, 0.3)], [0.1, 0.2], shift=1.0)
    changes = step_changes(before, after)
    assert at_shared_width(changes, before, after, None) == changes
