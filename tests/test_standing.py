"""benchmarks/standing.py: issue 16's counts over real_terrain.py result files.

Reference values by hand from the two-row file below.
"""

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import standing  # noqa: E402


def _verdict(site, n, method, **kw):
    row = {
        "site": site,
        "n": n,
        "method": method,
        "rmse_over_delaunay": 0.5,
        "rmse_ok": "PASS",
        "rmse_over_rbf": 0.9,
        "rbf_ok": "PASS",
        "cov95": 95.0,
        "cov95_ok": "PASS",
        "cov68": 68.0,
        "cov68_ok": "PASS",
        "d95": 0.5,
        "d68": 1.0,
        "cv_ok": "PASS",
    }
    return {**row, **kw}


@pytest.fixture
def result_file(tmp_path):
    verdicts = [
        _verdict("bei", 3000, "glacimap"),
        _verdict("bei", 3000, "glacimap_dem", cov68=77.2, cov68_ok="MISS"),
        _verdict("rm", 50000, "glacimap", rmse_over_rbf=1.02, rbf_ok="MISS"),
        _verdict("rm", 50000, "glacimap_dem", d68=-4.5, cv_ok="MISS"),
        _verdict("rm", 50000, "delaunay"),  # not a glacimap row: not counted
        _verdict("rm", 50000, "glacimap_pycno", cov95=91.0, cov95_ok="MISS"),
    ]
    results = [
        {
            "site": "bei",
            "n": 3000,
            "method": "glacimap",
            "info": {"kernel_scores": [{"name": "matern32", "selected": True}]},
        },
        {
            "site": "rm",
            "n": 50000,
            "method": "glacimap",
            "info": {
                "kernel_scores": [
                    {"name": "matern52", "selected": False},
                    {"name": "se", "selected": True},
                ]
            },
        },
    ]
    path = tmp_path / "real_terrain_x.json"
    path.write_text(json.dumps({"results": results, "verdicts": verdicts}))
    return path


def test_counts_per_sample_count_and_misses_named(result_file):
    lines = standing.counts(standing.load(result_file))
    assert [(ln["n"], ln["rows"]) for ln in lines] == [(3000, 2), (50000, 3)]
    small, large = lines
    assert (small["accuracy"], small["truth"], small["held-out"]) == (2, 1, 2)
    assert small["truth misses"] == ["bei/8x8 77.2"]
    assert (large["accuracy"], large["truth"], large["held-out"]) == (2, 2, 2)
    assert large["truth misses"] == ["rm/area-means 91.0"]
    assert large["accuracy misses"] == ["rm/const 1.020"]
    assert large["held-out misses"] == ["rm/8x8 +0.5 / -4.5"]


def test_one_sample_count_and_family(result_file):
    only = standing.load(f"{result_file}:50000")
    assert {row["n"] for row in only["rows"]} == {50000}
    fam = standing.by_family([standing.load(result_file)])
    assert {(f["family"], f["samples"], f["rows"]) for f in fam} == {
        ("matern32", "<20k", 1),
        ("not recorded", "<20k", 1),  # no kernel in the results for bei/8x8
        ("se", ">=20k", 1),
        ("not recorded", ">=20k", 2),
    }


def test_a_file_without_verdicts_is_refused(tmp_path):
    path = tmp_path / "partial.json"
    path.write_text(json.dumps({"results": []}))
    with pytest.raises(SystemExit, match="no verdicts"):
        standing.load(path)


def test_a_missing_file_is_named(tmp_path):
    with pytest.raises(SystemExit, match="no such result file"):
        standing.load(tmp_path / "absent.json:3000")


def test_main_prints_the_table_and_writes_json(result_file, tmp_path, capsys):
    out = tmp_path / "standing.json"
    assert standing.main([str(result_file), "--by-family", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "truth misses: bei/8x8 77.2" in text
    payload = json.loads(out.read_text())
    assert payload["total"]["rows"] == 5 and payload["total"]["accuracy"] == 4
