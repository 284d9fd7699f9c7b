"""Breaklines from the scenario file: ``[reconstruct] breaklines``, ``breakline_width`` and
``breakline_taper`` for ``glacimap run``, ``process --config`` and ``reconstruct --config``.

References: the command-line options (``--breaklines``...) on the same samples: the
scenario's lines must give the same map, byte for byte in its mean's record; bad values are
refused by the scenario key's name before any work.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import xarray as xr
from scipy.special import expit
from typer.testing import CliRunner

from terrain import InputError, default_site
from terrain.sampling import sample_dem
from toolkit.breaklines_io import scenario_lines, step_notes
from toolkit.cli import app
from toolkit.config import load_scenario

runner = CliRunner()
CRS = "EPSG:32608"
X0, Y0 = 526000.0, 6475000.0
EXAMPLE = Path(__file__).resolve().parents[1] / "docs" / "examples" / "field"


def _wkt(path: Path, xy: np.ndarray | None = None) -> Path:
    """``xy`` (k, 2) as a WKT LineString; default: a sinuous east-west line through the
    default site (run 100 m beyond it)."""
    if xy is None:
        u = np.linspace(-100.0, 700.0, 161)
        xy = np.column_stack([X0 + u, Y0 + 300.0 + 25.0 * np.sin(u / 70.0)])
    path.write_text("LINESTRING (" + ", ".join(f"{x:.3f} {y:.3f}" for x, y in xy) + ")\n")
    return path


@pytest.fixture(scope="module")
def scarp(tmp_path_factory):
    """600 spot heights (20 cm 1-sigma) of the default site with a 3 m step, 1 m wide, up
    to the north of the line; the line's WKT and a scenario naming it by a relative path."""
    d = tmp_path_factory.mktemp("scarp")
    rng = np.random.default_rng(1)
    xy = rng.uniform([X0 + 2, Y0 + 2], [X0 + 598, Y0 + 598], size=(600, 2))
    across = xy[:, 1] - (Y0 + 300.0 + 25.0 * np.sin((xy[:, 0] - X0) / 70.0))
    z = sample_dem(default_site(resolution=4.0), xy) + 3.0 * expit(across) + rng.normal(0, 0.2, 600)
    pd.DataFrame({"x": xy[:, 0], "y": xy[:, 1], "z": z, "z_var": 0.04}).to_csv(
        d / "spots.csv", index=False
    )
    (d / "lines").mkdir()
    _wkt(d / "lines" / "cliff.wkt")
    cfg = d / "scenario.toml"
    cfg.write_text('[reconstruct]\nbreaklines = "lines/cliff.wkt"\nbreakline_width = 1.5\n')
    return d


def test_the_keys_default_to_none_and_read_like_the_options(scarp, monkeypatch):
    rc = load_scenario()["reconstruct"]
    assert (rc["breaklines"], rc["breakline_width"], rc["breakline_taper"]) == ("", "auto", "auto")
    assert scenario_lines(load_scenario()) == (None, "auto", "auto")
    # a relative path is read from the scenario file's folder, not the working directory
    monkeypatch.chdir(scarp / "lines")
    rc = load_scenario(scarp / "scenario.toml")["reconstruct"]
    assert rc["breaklines"] == str((scarp / "lines" / "cliff.wkt").resolve())
    assert (rc["breakline_width"], rc["breakline_taper"]) == (1.5, "auto")
    over = {"reconstruct": {"breaklines": " AUTO ", "breakline_taper": 40}}
    assert scenario_lines(load_scenario(overrides=over)) == ("auto", "auto", 40.0)
    # settings written before the keys existed (a dict handed to process) mean no lines
    assert scenario_lines({"reconstruct": {"resolution_m": 2.0}}) == (None, "auto", "auto")


@pytest.mark.parametrize(
    ("key", "value", "words"),
    [
        ("breaklines", "missing.gpkg", "an existing vector file"),
        ("breaklines", 3, "a str"),
        ("breakline_width", "wide", '"auto" or a positive width'),
        ("breakline_width", 0, '"auto" or a positive width'),
        ("breakline_taper", True, '"auto" or a positive length'),
        ("breakline_taper", -40.0, '"auto" or a positive length'),
    ],
)
def test_bad_values_are_refused_by_the_scenario_key(key, value, words):
    with pytest.raises(InputError, match=f"reconstruct.{key}") as err:
        load_scenario(overrides={"reconstruct": {key: value}})
    assert words in str(err.value)


def test_a_point_file_is_refused_by_the_key_before_any_work(tmp_path):
    (tmp_path / "p.wkt").write_text("POINT (1 2)\n")
    cfg = tmp_path / "s.toml"
    cfg.write_text('[reconstruct]\nbreaklines = "p.wkt"\n')
    never = tmp_path / "never"
    res = runner.invoke(app, ["process", str(EXAMPLE), "--config", str(cfg), "--out", str(never)])
    assert isinstance(res.exception, InputError), res.output
    assert "reconstruct.breaklines" in str(res.exception) and "LineStrings" in str(res.exception)
    assert not never.exists()


def _mean_record(out: Path) -> str:
    return xr.open_dataset(out / "product.nc").attrs["mean_function"]


def test_reconstruct_config_lines_make_the_options_map(scarp, tmp_path):
    # Reference: the same line, width given on the command line: the same fitted mean.
    base = ["reconstruct", str(scarp / "spots.csv"), "--crs", CRS, "--resolution", "20"]
    res = runner.invoke(app, [*base, "--config", str(scarp / "scenario.toml"),
                              "--out", str(tmp_path / "cfg")])  # fmt: skip
    assert res.exit_code == 0, res.output
    assert "breaklines: line 1: step" in res.output and "1.5 m wide" in res.output
    cliff = str(scarp / "lines" / "cliff.wkt")
    res = runner.invoke(app, [*base, "--breaklines", cliff, "--breakline-width", "1.5",
                              "--out", str(tmp_path / "opt")])  # fmt: skip
    assert res.exit_code == 0, res.output
    record = _mean_record(tmp_path / "cfg")
    assert record == _mean_record(tmp_path / "opt") and "BreaklineMean" in record
    height = float(record.split("step1_m=")[1].split()[0])
    assert height == pytest.approx(3.0, abs=0.45)  # the step put in the samples
    inputs = json.loads(xr.open_dataset(tmp_path / "cfg" / "product.nc").attrs["inputs"])
    assert {r["role"]: r["name"] for r in inputs}["breaklines"] == "cliff.wkt"


def test_process_reads_the_scenario_lines_and_the_option_wins(scarp, tmp_path):
    # The example field folder (the default site) has no scarp: the scenario's line is
    # fitted (height within 4 sigma of 0, as with --breaklines: test_breakline_cli.py),
    # recorded with its file and printed; --breaklines on the command line replaces it.
    out = tmp_path / "out"
    res = runner.invoke(app, ["process", str(EXAMPLE), "--config", str(scarp / "scenario.toml"),
                              "--out", str(out)])  # fmt: skip
    assert res.exit_code == 0, res.output
    assert "breaklines: line 1: step" in res.output and "1.5 m wide" in res.output
    attrs = xr.open_dataset(out / "product.nc").attrs
    text = attrs["mean_function"].split("step1_m=")[1].split()
    assert abs(float(text[0])) < 4 * float(text[2].rstrip(")"))
    assert {r["role"]: r["name"] for r in json.loads(attrs["inputs"])}["breaklines"] == "cliff.wkt"
    cert = json.loads((out / "certificate.json").read_text())
    assert cert["inputs"]["files"][-1]["role"] == "breaklines"
    out2 = tmp_path / "auto"
    res = runner.invoke(app, ["process", str(EXAMPLE), "--config", str(scarp / "scenario.toml"),
                              "--breaklines", "auto", "--out", str(out2)])  # fmt: skip
    assert res.exit_code == 0, res.output
    assert "0 line(s)" in res.output and "BreaklineMean" not in _mean_record(out2)


def test_glacimap_run_maps_a_scarp_drawn_in_the_scenario(tmp_path):
    # A 4 m scarp (1 m wide) across the small run's 300 m corner of the default site, read
    # as a DEM site; the line drawn in the scenario (a relative path). Reference: the same
    # run without the line. Measured (seed 0): the map's error about its shared offset
    # (relative 1-sigma's row) 0.603 m without the line, 0.425 m with it; the prior's scale
    # 0.938 (0.38 before 0.39.0 counted the step once: the map 0.922 m; 0.87 and 0.464 m
    # before 0.40.0 read the step through the DEM's own warp and chose its width by the
    # map's evidence), the DEM lacking -0.18 +- 0.59 m of the step; the step 5.56 m, 1.41 m
    # wide (6.08 m at the local planes' width; the landmarks' own errors are in it).
    import rasterio
    from _scenarios import small_run

    from toolkit.pipeline import run_scenario

    site = default_site(resolution=2.0)
    X, Y = np.meshgrid(site.x.values, site.y.values)

    def line_y(x):
        return Y0 + 150.0 + 10.0 * np.sin((x - X0) / 50.0)

    z = site.values + 4.0 * expit(Y - line_y(X))
    north_first = z if site.y.values[0] > site.y.values[-1] else z[::-1]
    transform = rasterio.transform.from_origin(X0, Y0 + 600.0, 2.0, 2.0)
    with rasterio.open(tmp_path / "scarp.tif", "w", driver="GTiff", height=300, width=300,
                       count=1, dtype="float64", crs=CRS, transform=transform) as ds:  # fmt: skip
        ds.write(north_first, 1)
    u = np.linspace(X0 - 50.0, X0 + 350.0, 81)
    (tmp_path / "lines").mkdir()
    _wkt(tmp_path / "lines" / "cliff.wkt", np.column_stack([u, line_y(u)]))
    errors = {}
    for name, lines in (("plain", ""), ("drawn", "lines/cliff.wkt")):
        toml = small_run(n_boot=200, extra="heldout_folds = 0\n[export]\nmesh = false\n")
        toml = toml.replace("[site]\n", f'[site]\nkind = "dem"\ndem = "scarp.tif"\ncrs = "{CRS}"\n')
        toml = toml.replace("[reconstruct]\n", f'[reconstruct]\nbreaklines = "{lines}"\n')
        (tmp_path / f"{name}.toml").write_text(toml)
        res = run_scenario(tmp_path / f"{name}.toml", out=tmp_path / name)
        errors[name] = res.summary["metrics"]["gp_satellite_relative_sigma"]["rmse"]
    mean = res.objects["reconstruction"].gp.mean_
    coef = dict(zip(mean.coef_names, mean.coef_, strict=True))
    assert type(mean).__name__ == "BreaklineMean" and 2.0 < coef["step1_m"] < 8.0
    assert coef["scale"] == pytest.approx(1.0, abs=0.3)
    # the step said with what the prior DEM lacks of it (it holds the scarp: near 0)
    (note,) = step_notes(mean)
    assert "the prior DEM lacks" in note and abs(coef["coarse_step1_m"]) < 2.5
    # and the product records it (terrain.dem_reading.dem_lacks), as the note says it
    attrs = xr.open_dataset(next((tmp_path / "drawn").rglob("product.nc"))).attrs
    (lack,) = json.loads(attrs["breakline_dem_lacks"])
    assert abs(lack["m"]) < 2.0 * lack["sd_m"] + 0.2
    assert f"lacks {lack['m']:.2f} +- {lack['sd_m']:.2f} m" in note
    assert errors["drawn"] < 0.85 * errors["plain"], errors
    cert = json.loads((tmp_path / "drawn" / "certificate.json").read_text())
    assert "cliff.wkt" in [f["name"] for f in cert["inputs"]["files"]]
    # the certificate and the report say the line, its step and the DEM's lack of it
    (line,) = cert["breaklines"]
    assert line["step_m"] == pytest.approx(coef["step1_m"], rel=1e-12)
    assert line["dem_lacks_m"] == pytest.approx(lack["m"], rel=1e-12)
    assert line["n_vertices"] == 81 and line["open_ends"] == []
    html = (tmp_path / "drawn" / "report.html").read_text()
    assert 'id="breaklines"' in html and "breakline(s) the map was fitted with" in html
    plain = (tmp_path / "plain" / "report.html").read_text()
    assert 'id="breaklines"' not in plain
    assert "breaklines" not in json.loads((tmp_path / "plain" / "certificate.json").read_text())
    assert cert["scenario"]["reconstruct"]["breaklines"].endswith("lines/cliff.wkt")


def test_a_dropped_line_comes_with_the_advice_to_draw_it(monkeypatch):
    # A search that dropped its one line (as on a rover's four swaths across a 4 m scarp:
    # 3.03 +- 0.93 m, not told from zero) says so, and how to map the step anyway.
    import terrain
    from toolkit.breaklines_io import DROPPED_HINT, with_breaklines

    found = terrain.BreaklineSearch(
        [], [], [], [], ["433 m line: step 3.03 +- 0.93 m, under 5 sd"], 19.1, 0.02, 3708, 9, 9,
        np.zeros((0, 2)),
    )  # fmt: skip
    monkeypatch.setattr(terrain, "find_breaklines", lambda samples: found)
    notes: list[str] = []
    mean = with_breaklines("constant", "auto", notes=notes, samples=object())
    assert mean == "constant"  # no line: the plain mean
    assert notes[1].startswith("dropped: 433 m line") and notes[2] == DROPPED_HINT
    assert "--breaklines FILE" in DROPPED_HINT
