"""The command line as a new user meets it (issue 17): a one-line error however narrow the
terminal, a readable command list, no empty --out left by a failure, and no product of an
earlier run left beside a new one in the same --out."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from terrain.errors import InputError
from toolkit import process
from toolkit.cli import COMMANDS, app
from toolkit.export._files import previous_products, remove_stale

EXAMPLE = Path(__file__).resolve().parents[1] / "docs" / "examples" / "field"


def test_error_is_one_line_in_a_narrow_terminal_or_a_pipe(tmp_path):
    env = {**os.environ, "COLUMNS": "40"}
    missing = tmp_path / "no such dir" / "dem.tif"  # a path with a space, as users have
    res = subprocess.run(
        [sys.executable, "-m", "toolkit", "certify", str(missing), str(tmp_path / "cp.csv")],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )
    assert res.returncode == 2
    lines = [ln for ln in res.stderr.splitlines() if ln.startswith("error:") or "Fix" in ln]
    assert len(lines) == 1 and "Fix: check the path" in lines[0]  # before: 3 wrapped lines


def test_command_list_has_one_short_line_per_command():
    names = {c.name for c in app.registered_commands}
    assert names == {name for name, _, _ in COMMANDS}
    out = CliRunner().invoke(app, ["--help"]).output
    flat = " ".join(re.sub(r"[│╭╮╰╯─]", " ", out).split())  # rich's box and wrapping removed
    for _, _, short in COMMANDS:
        assert "\n" not in short and len(short) <= 90
        assert short in flat  # before: each docstring's first paragraph with its line breaks


def test_failed_process_leaves_no_empty_out(tmp_path):
    out = tmp_path / "new" / "deeper" / "out"
    with pytest.raises(InputError, match="LOG_DIR"):
        process(tmp_path, out=out)  # not a field folder: fails at ingest
    assert not (tmp_path / "new").exists()  # before: new/deeper/out stayed, empty
    (tmp_path / "kept").mkdir()
    with pytest.raises(InputError):
        process(tmp_path, out=tmp_path / "kept")
    assert (tmp_path / "kept").is_dir()  # a folder the user made is never removed


def test_stale_products_of_an_earlier_run_are_removed(tmp_path):
    for name in ("report.html", "certificate.json", "mine.txt"):
        (tmp_path / name).write_text("x")
    listed = ["report.html", "certificate.json", "summary.json", "../escape"]
    (tmp_path / "summary.json").write_text(json.dumps({"products": listed}))
    before = previous_products(tmp_path)
    assert before == ["report.html", "certificate.json", "summary.json"]  # no path tricks
    gone = remove_stale(tmp_path, before, ["certificate.json", "summary.json"])
    assert gone == ["report.html"]
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "certificate.json",
        "mine.txt",  # not a product of an earlier run: never touched
        "summary.json",
    ]
    (tmp_path / "summary.json").write_text("not json")
    assert previous_products(tmp_path) == []


@pytest.mark.slow
def test_process_twice_into_one_out_without_then_with_checkpoints(tmp_path):
    """The example field folder with and then without checkpoints: the second run's folder
    holds no report.html from the first (it would describe a certificate no longer there)."""
    import numpy as np

    from terrain.synthetic import default_site
    from toolkit.field_survey import simulated_prior

    truth = default_site(resolution=4.0)
    prior = simulated_prior(truth, 75.0, 1.5, 0.3, np.random.default_rng(0))
    cps = tmp_path / "cp.csv"
    cps.write_text("id;x;y;z;crs\n1;526300,5;6475280,25;100;EPSG:32608\n")  # semicolons
    out = tmp_path / "out dir"
    first = process(EXAMPLE, prior=prior, checkpoints=cps, out=out)
    assert "report.html" in first.products
    second = process(EXAMPLE, prior=prior, out=out)
    assert second.removed == ["report.html"] and not (out / "report.html").exists()
    assert sorted(second.products) == sorted(p.name for p in out.iterdir() if p.is_file())


def test_a_missing_prior_and_an_out_that_is_a_file_name_their_option(tmp_path):
    with pytest.raises(InputError, match=r"^--prior: expected an existing DEM file"):
        process(EXAMPLE, prior=tmp_path / "dem.tif", out=tmp_path / "o")  # before: "source"
    assert not (tmp_path / "o").exists()
    (tmp_path / "f").write_text("")
    with pytest.raises(InputError, match=r"--out: expected a folder, not a file"):
        process(EXAMPLE, out=tmp_path / "f")  # before: "[Errno 17] File exists"


def test_bounds_that_miss_every_sample_are_named():
    """--bounds in the wrong CRS or order (here 0 0 1000 1000 for a UTM site) used to fail
    later with a resolution or prior-footprint message, or map nothing but the mean."""
    import numpy as np

    from terrain import ElevationSamples
    from toolkit.stages import map_grid

    xy = np.array([[526240.0, 6475250.0], [526360.0, 6475320.0], [526300.0, 6475280.0]])
    data = ElevationSamples(xy, np.zeros(3), np.full(3, 0.01), crs="EPSG:32608")
    with pytest.raises(InputError, match=r"--bounds.*holding some of the 3 samples.*526240.0"):
        map_grid((0, 0, 1000, 1000), 2.0, "EPSG:32608", data)
    grid = map_grid((526200, 6475200, 526300, 6475300), 2.0, "EPSG:32608", data)  # 2 inside
    assert grid.shape == (50, 50)


def test_reconstruct_twice_into_one_out_leaves_no_stale_report(tmp_path):
    import numpy as np

    rng = np.random.default_rng(1)
    xy = rng.uniform(0, 200, (150, 2)) + [526000, 6475000]
    z = 100 + 0.05 * (xy[:, 0] - 526000) + rng.normal(0, 0.05, 150)
    rows = "\n".join(
        f"{a:.3f},{b:.3f},{c:.3f},0.0025,EPSG:32608" for (a, b), c in zip(xy, z, strict=True)
    )
    (tmp_path / "s.csv").write_text("x,y,z,z_var,crs\n" + rows + "\n")
    cp = "\n".join(f"{a:.3f},{b:.3f},{100 + 0.05 * (a - 526000):.3f}" for a, b in xy[:25])
    (tmp_path / "cp.csv").write_text("x,y,z\n" + cp + "\n")
    args = [
        "reconstruct",
        str(tmp_path / "s.csv"),
        "--resolution",
        "10",
        "--out",
        str(tmp_path / "o"),
    ]
    runner = CliRunner()
    first = runner.invoke(app, [*args, "--checkpoints", str(tmp_path / "cp.csv")])
    assert first.exit_code == 0, first.output
    assert (tmp_path / "o" / "report.html").is_file()
    second = runner.invoke(app, args)
    assert second.exit_code == 0, second.output
    assert not (tmp_path / "o" / "report.html").exists()  # before: the first run's, stale
    assert "removed report.html" in " ".join(second.output.split())
    listed = json.loads((tmp_path / "o" / "reconstruct_summary.json").read_text())["products"]
    assert sorted(listed) == sorted(p.name for p in (tmp_path / "o").iterdir())


def test_glacimap_process_cli_on_the_example_folder(tmp_path):
    """``glacimap process`` end to end from the command line (none tested it): a prior
    GeoTIFF, checkpoints with semicolons and decimal commas, an --out with a space; the
    table says how the clock was set and how many checkpoints were scored."""
    import numpy as np

    from terrain.synthetic import default_site
    from toolkit.field_survey import _write_geotiff, simulated_prior

    prior = simulated_prior(default_site(4.0), 75.0, 1.5, 0.3, np.random.default_rng(0))
    dem = _write_geotiff(prior, tmp_path / "prior.tif")
    cps = tmp_path / "cp.csv"
    cps.write_text("id;x;y;z;crs\n1;526300,5;6475280,25;100;EPSG:32608\n2;1;2;3;EPSG:32608\n")
    out = tmp_path / "out dir"
    args = ["process", str(EXAMPLE), "--prior", str(dem), "--checkpoints", str(cps)]
    res = CliRunner().invoke(app, [*args, "--out", str(out)])
    assert res.exit_code == 0, res.output
    flat = " ".join(re.sub(r"[│┃]", " ", res.output).split())
    assert "GPS fixes used 156" in flat
    assert "clock offset (s, survey.json) 1782936000.000" in flat
    assert "checkpoints scored 1 of 2" in flat  # the second point is 526 km away
    assert "1 of 2 checkpoints were not scored (1 outside the DEM)" in flat
    assert {"report.html", "elevation.tif", "summary.json"} <= {p.name for p in out.iterdir()}


def test_command_help_paragraphs_are_not_cut_mid_sentence():
    from toolkit.cli import command_help

    for name, fn, _ in COMMANDS:
        text = command_help(fn)
        assert all("\n" not in par for par in text.split("\n\n")), name
    out = CliRunner().invoke(app, ["change", "--help"]).output
    starts = [ln.strip() for ln in out.splitlines()]
    # before: the docstring's own line breaks, "...(a product folder" / "of run / process ..."
    assert not any(ln.startswith("of run / process holds samples.csv") for ln in starts)
    assert not any(ln.startswith("GP is refitted on its samples") for ln in starts)


def test_mesh_render_prints_no_vtk_warning(tmp_path):
    """Without a display, VTK printed "vtkXOpenGLRenderWindow ... WARN| bad X server
    connection" on stderr on every run / process / export (the PNG is made anyway)."""
    code = (
        "import numpy as np\n"
        "from terrain import Grid\n"
        "from terrain.product import terrain_dataset\n"
        "from toolkit.export.mesh import write_mesh\n"
        "g = Grid.from_bounds((526000.0, 6475000.0, 526100.0, 6475100.0), 10.0, crs='EPSG:32608')\n"
        "ds = terrain_dataset(g, np.full(g.shape, 100.0), np.full(g.shape, 0.3), {'seed': 0})\n"
        f"write_mesh(ds, png_path={str(tmp_path / 'm.png')!r}, window_size=(200, 150))\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "DISPLAY"}
    res = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120
    )
    assert res.returncode == 0, res.stderr
    assert (tmp_path / "m.png").stat().st_size > 0
    assert "WARN" not in res.stderr, res.stderr


def test_run_table_shows_the_maps_heldout_coverage_and_its_verdict():
    """The table quoted the held-out coverage of the noisy samples (0.795 / 0.977 on the
    default run) while the README and the report quote the map's, noise removed (72.9 /
    96.5 %); and a verdict "too large" stayed in the JSON."""
    from rich.console import Console
    from rich.table import Table

    from toolkit.cli._progress import certificate_rows, print_warnings

    held = {"coverage_68": 0.977, "coverage_95": 0.997, "map_coverage_68": 0.91,
            "map_coverage_95": 0.998, "map_coverage_68_interval": [0.724, 1.0],
            "map_coverage_95_interval": [0.964, 1.0],
            "verdict": ["held-out 68 % map coverage 91.0 % is 22.7 points above"]}  # fmt: skip
    table = Table()
    table.add_column("q")
    table.add_column("v")
    certificate_rows(table, {"heldout_calibration": held})
    console = Console(width=200, record=True)
    console.print(table)
    print_warnings(console, {"heldout_calibration": held})
    text = console.export_text()
    assert "held-out 68 % coverage of the map (%) │ 91.0 [72.4, 100.0]" in text
    assert "0.977" not in text
    assert "held-out check: held-out 68 % map coverage 91.0 % is 22.7 points above" in text
    # the check switched to the map cells' neighbourhoods (terrain.heldout_weights): said
    table = Table()
    table.add_column("q")
    table.add_column("v")
    certificate_rows(table, {"heldout_calibration": {**held, "matched_on": "neighbourhood"}})
    console = Console(width=200, record=True)
    console.print(table)
    text = console.export_text()
    assert "held-out 68 % coverage of the map (neighbourhoods) (%) │ 91.0 [72.4, 100.0]" in text
    # ... and read its held-out elevations from local planes (terrain.heldout_local_fit)
    table = Table()
    table.add_column("q")
    table.add_column("v")
    both = {**held, "matched_on": "neighbourhood", "local_fit_used": True}
    certificate_rows(table, {"heldout_calibration": both})
    console = Console(width=200, record=True)
    console.print(table)
    text = console.export_text()
    assert "coverage of the map (neighbourhoods, local planes) (%) │ 91.0" in text


def test_process_refuses_checkpoints_off_the_map_before_localizing(tmp_path, monkeypatch):
    """With --bounds the map's grid is known at ingest: checkpoints that miss it (here a
    semicolon CSV in another zone's metres) fail there, not after iSAM2 and the GP fit."""
    import toolkit.processing

    def no_localize(*args, **kwargs):
        raise AssertionError("localized before the checkpoints were checked")

    monkeypatch.setattr(toolkit.processing, "localize_stage", no_localize)
    cps = tmp_path / "cp.csv"
    cps.write_text("id;x;y;z;crs\n1;326300,5;6475280,25;100;EPSG:32608\n")
    out = tmp_path / "out"
    with pytest.raises(InputError, match=r"0 of 1 usable .* 1 outside the DEM"):
        process(EXAMPLE, checkpoints=cps, bounds=(526000, 6475000, 526600, 6475600), out=out)
    assert not out.exists()
