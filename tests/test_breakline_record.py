"""The breaklines read back from a product's attributes (``toolkit.breakline_record``).

References: hand values (a 3-4-5 triangle's legs and a straight 10 m line); the attribute
layout written by ``terrain.product.gp_provenance`` (a fitted map's round trip is in
``tests/test_breakline_scenario.py``: certificate and report of a ``glacimap run``).
"""

from __future__ import annotations

import json

from toolkit.breakline_record import breakline_rows


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
