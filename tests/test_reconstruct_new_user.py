"""``glacimap reconstruct`` as a new user runs it on a samples CSV someone else made (QA pass
of issues 16/17): bad input is one clear line, exit 2, nothing written, before any fitting;
what the products say about their inputs; the held-out check's verdict printed in words."""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import rasterio
import xarray as xr
from typer.testing import CliRunner

from terrain import InputError, default_site
from terrain.sampling import sample_dem
from toolkit.cli import app

runner = CliRunner()
CRS = "EPSG:32608"


def _invoke(*args: str):
    """In-process; a library error stays an exception here (``main`` maps it to exit 2)."""
    res = runner.invoke(app, list(args))
    text = res.output + (str(res.exception) if res.exception is not None else "")
    return res, " ".join(text.split())  # rich wraps at 80 columns


def _shell(*args: str) -> subprocess.CompletedProcess:
    """As a user runs it: the installed command, its exit code and stderr."""
    exe = Path(sys.executable).with_name("glacimap")
    return subprocess.run([str(exe), *args], capture_output=True, text=True, timeout=120)


@pytest.fixture(scope="module")
def site():
    return default_site(resolution=4.0)  # the paper's 600 m x 600 m site, UTM 8N


@pytest.fixture(scope="module")
def samples_csv(site, tmp_path_factory):
    """300 spot heights with a 20 cm 1-sigma, uniform over the site (seeded)."""
    rng = np.random.default_rng(0)
    xy = rng.uniform([526002.0, 6475002.0], [526598.0, 6475598.0], size=(300, 2))
    z = sample_dem(site, xy) + rng.normal(0.0, 0.2, 300)
    path = tmp_path_factory.mktemp("in") / "spots.csv"
    pd.DataFrame({"x": xy[:, 0], "y": xy[:, 1], "z": z, "z_var": 0.04}).to_csv(path, index=False)
    return path


def test_resolution_larger_than_the_site_is_refused_before_the_fit(samples_csv, tmp_path):
    """Before: a 1 x 1-cell map was fitted (7 s), warned it 'reverts to its prior on 100 %'
    and then failed in the mesh export with an empty Fix."""
    out = tmp_path / "out"
    t = time.perf_counter()
    res = _shell("reconstruct", str(samples_csv), "--crs", CRS, "--resolution", "5000",
                 "--out", str(out))  # fmt: skip
    assert time.perf_counter() - t < 20.0  # start-up and CSV only: no GP was fitted (7 s)
    assert res.returncode == 2, res.stderr
    text = " ".join(res.stderr.split())
    assert res.stderr.count("\n") == 1 and text.startswith("error: --resolution")
    assert "at least 2 x 2 cells" in text
    # the samples span ~592 m: half of it, rounded down to 2 digits, is the largest that works
    assert "Fix: pass --resolution 290 or less" in text
    assert not out.exists() or not any(out.iterdir())


def test_rows_without_values_are_named_by_file_line(samples_csv, tmp_path):
    bad = tmp_path / "holes.csv"
    df = pd.read_csv(samples_csv)
    df.loc[5, "z"] = np.nan  # file line 7 (the header is line 1)
    df.loc[7, "x"] = np.nan  # file line 9
    df.to_csv(bad, index=False)
    res, text = _invoke("reconstruct", str(bad), "--crs", CRS, "--out", str(tmp_path / "o"))
    assert isinstance(res.exception, InputError)
    assert "2 of 300" in text and "file lines 7, 9" in text and "holes.csv" in text
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").iterdir())


def test_a_file_without_header_is_said_to_have_none(samples_csv, tmp_path):
    bare = tmp_path / "bare.csv"
    pd.read_csv(samples_csv)[["x", "y", "z"]].to_csv(bare, index=False, header=False)
    res, text = _invoke("reconstruct", str(bare), "--crs", CRS, "--out", str(tmp_path / "o"))
    assert isinstance(res.exception, InputError)
    assert "bare.csv header" in text and "so the file has none" in text
    assert "add a first line naming the columns in the file's order, e.g. x,y,z" in text
    # a controller's PNEZD export: a point name and a code around the numbers
    pnezd = tmp_path / "pnezd.csv"
    df = pd.read_csv(samples_csv)
    rows = [f"CP{i},{r.y:.3f},{r.x:.3f},{r.z:.3f},STAKE" for i, r in enumerate(df.itertuples())]
    pnezd.write_text("\n".join(rows) + "\n")
    res, text = _invoke("reconstruct", str(pnezd), "--crs", CRS, "--out", str(tmp_path / "o"))
    assert isinstance(res.exception, InputError) and "3 numbers of 5 cells" in text
    assert "name,northing,easting,elevation,code for PNEZD" in text
    pnezd.write_text("name,northing,easting,elevation,code\n" + pnezd.read_text())
    res, text = _invoke("reconstruct", str(pnezd), "--crs", CRS, "--resolution", "50",
                        "--out", str(tmp_path / "o"))  # fmt: skip
    assert res.exit_code == 0, text


def test_products_name_the_samples_file_and_its_hash(samples_csv, tmp_path):
    out = tmp_path / "map"
    res, _ = _invoke("reconstruct", str(samples_csv), "--crs", CRS, "--resolution", "20",
                     "--out", str(out))  # fmt: skip
    assert res.exit_code == 0, res.output
    with rasterio.open(out / "elevation.tif") as src:
        inputs = json.loads(src.tags()["inputs"])
    sha = hashlib.sha256(samples_csv.read_bytes()).hexdigest()
    assert inputs == [{"role": "samples", "name": "spots.csv", "sha256": sha}]
    assert str(samples_csv.parent) not in (out / "product.nc").read_bytes().decode("latin-1")


def test_heldout_verdict_is_printed_in_words(site, tmp_path):
    """Samples on one straight line: the held-out check finds the map's 1-sigma off by more
    than 5 points (measured: 68 % coverage 94.5 %, seed 0). The certificate said so, but
    ``reconstruct`` without --checkpoints writes no report: the words must reach the user."""
    rng = np.random.default_rng(0)
    t = rng.uniform(0.0, 1.0, 500)
    xy = np.column_stack([526010.0 + 580.0 * t, 6475010.0 + 580.0 * t])
    path = tmp_path / "line.csv"
    pd.DataFrame({"x": xy[:, 0], "y": xy[:, 1], "z": sample_dem(site, xy)}).to_csv(path)
    out = tmp_path / "map"
    res, text = _invoke("reconstruct", str(path), "--crs", CRS, "--resolution", "10",
                        "--out", str(out))  # fmt: skip
    assert res.exit_code == 0, res.output
    verdicts = json.loads((out / "certificate.json").read_text())["heldout_calibration"]
    verdicts = verdicts["verdict"]
    assert verdicts, "this layout is expected to fail the held-out check"
    for v in verdicts:
        assert f"held-out check: {' '.join(v.split())}" in text


def _like_raster(path: Path, crs: str, corners_utm, cell: float) -> Path:
    """A constant raster in ``crs`` covering the UTM box ``corners_utm`` (W, S, E, N)."""
    from pyproj import Transformer
    from rasterio.transform import from_origin

    w, s, e, n = corners_utm
    tr = Transformer.from_crs(CRS, crs, always_xy=True)
    xs, ys = tr.transform([w, e, w, e], [s, s, n, n])
    nx = int((max(xs) - min(xs)) // cell)
    ny = int((max(ys) - min(ys)) // cell)
    profile = dict(driver="GTiff", width=nx, height=ny, count=1, dtype="float32", crs=crs)
    transform = from_origin(min(xs), max(ys), cell, cell)
    with rasterio.open(path, "w", transform=transform, **profile) as dst:
        dst.write(np.full((ny, nx), 100.0, np.float32), 1)
    return path


def test_like_raster_in_another_projected_crs_gets_the_samples_projected(
    samples_csv, site, tmp_path
):
    """Before: the GP was fitted, then predict_grid failed with 'samples.crs (EPSG:32608)
    differs from grid.crs (EPSG:3338)', naming no option. Now the map is on the raster's
    own cells and agrees with the truth as the UTM map does."""
    from pyproj import Transformer

    like = _like_raster(
        tmp_path / "albers.tif", "EPSG:3338", (526000, 6475000, 526600, 6475600), 25.0
    )
    out = tmp_path / "map"
    res, text = _invoke("reconstruct", str(samples_csv), "--crs", CRS, "--like", str(like),
                        "--out", str(out))  # fmt: skip
    assert res.exit_code == 0, text
    assert "samples projected from EPSG:32608 to albers.tif's CRS EPSG:3338" in text
    with rasterio.open(out / "elevation.tif") as src, rasterio.open(like) as ref:
        assert src.crs == ref.crs and src.transform == ref.transform and src.shape == ref.shape
        z = src.read(1)
        rows, cols = np.mgrid[0 : src.height, 0 : src.width]
        x, y = rasterio.transform.xy(src.transform, rows.ravel(), cols.ravel())
    ux, uy = Transformer.from_crs("EPSG:3338", CRS, always_xy=True).transform(x, y)
    ux, uy = np.asarray(ux), np.asarray(uy)
    inside = (ux > 526020) & (ux < 526580) & (uy > 6475020) & (uy < 6475580)
    err = z.ravel()[inside] - sample_dem(site, np.column_stack([ux[inside], uy[inside]]))
    # 300 spot heights with 0.2 m noise on 25 m of relief: the UTM map of the same samples
    # at 20 m reads ~0.5 m; a map in the wrong place would read metres
    assert np.sqrt(np.mean(err**2)) < 1.0


def test_like_raster_in_a_geographic_crs_is_refused_before_the_fit(samples_csv, tmp_path):
    like = _like_raster(
        tmp_path / "lonlat.tif", "EPSG:4326", (526000, 6475000, 526600, 6475600), 2e-4
    )
    t = time.perf_counter()
    res, text = _invoke("reconstruct", str(samples_csv), "--crs", CRS, "--like", str(like),
                        "--out", str(tmp_path / "o"))  # fmt: skip
    assert time.perf_counter() - t < 5.0
    assert isinstance(res.exception, InputError)
    assert text.startswith("--like") or "--like: expected a raster in a projected CRS" in text
    assert "gdalwarp -t_srs EPSG:32608" in text


def test_duplicate_points_are_counted_not_merged_silently(samples_csv, tmp_path):
    doubled = tmp_path / "doubled.csv"
    df = pd.read_csv(samples_csv)
    pd.concat([df, df.iloc[:40]]).to_csv(doubled, index=False)
    res, text = _invoke("reconstruct", str(doubled), "--crs", CRS, "--resolution", "50",
                        "--out", str(tmp_path / "m"))  # fmt: skip
    assert res.exit_code == 0, text
    assert "40 rows repeat the x, y of another row" in text and "300 samples from 340 rows" in text


def test_five_samples_make_a_map_whose_sigma_is_said_to_be_unchecked(samples_csv, tmp_path):
    """Five spot heights made a map (exit 0) whose held-out check passed on 5 samples, while
    only 34 % of the truth lay inside its +-1 sigma (seed 0, default site, 10 m grid). The
    check now says a coverage from so few samples cannot judge the 1-sigma."""
    five = tmp_path / "five.csv"
    pd.read_csv(samples_csv).iloc[:5].to_csv(five, index=False)
    out = tmp_path / "map"
    res, text = _invoke("reconstruct", str(five), "--crs", CRS, "--resolution", "25",
                        "--out", str(out))  # fmt: skip
    assert res.exit_code == 0, text
    held = json.loads((out / "certificate.json").read_text())["heldout_calibration"]
    assert held["n"] == 5
    assert any(v.startswith("only 5 held-out samples") for v in held["verdict"])
    assert "held-out check: only 5 held-out samples" in text and "+-21 points" in text


def test_enough_heldout_samples_add_no_sentence():
    from toolkit.certify_heldout import _too_few

    # binomial 1-sigma of a 68 % coverage: sqrt(0.683 * 0.317 / n) * 100 points
    assert _too_few(86, 5.0) and not _too_few(87, 5.0)  # 5.02 and 4.99 points
    assert not _too_few(3790, 5.0) and not _too_few(None, 5.0)


def test_gaps_filled_by_a_prior_dem_are_a_note_not_a_warning(site, tmp_path):
    """With a satellite DEM as the prior, cells far from the samples follow the DEM by
    design (glacimap run's own map: 52 % of its cells). reconstruct warned 'narrow --bounds
    or add samples' for the same map run makes silently; that advice is for a constant mean,
    where those cells are flat."""
    import rioxarray  # noqa: F401  (the .rio accessor)

    from terrain import coarse_dem

    rng = np.random.default_rng(1)
    xy = rng.uniform([526010.0, 6475010.0], [526150.0, 6475150.0], size=(150, 2))  # a corner
    path = tmp_path / "corner.csv"
    z = sample_dem(site, xy) + rng.normal(0.0, 0.1, 150)
    pd.DataFrame({"x": xy[:, 0], "y": xy[:, 1], "z": z, "z_var": 0.01}).to_csv(path)
    prior = tmp_path / "dem.tif"
    coarse_dem(site, cells=(12, 12)).rio.write_crs(CRS).rio.to_raster(prior)
    common = ["reconstruct", str(path), "--crs", CRS, "--resolution", "25"]
    common += ["--bounds", "526000", "6475000", "526600", "6475600"]
    res, text = _invoke(*common, "--prior", str(prior), "--out", str(tmp_path / "a"))
    assert res.exit_code == 0, text
    assert "note: on " in text and "the map there is the prior DEM" in text
    assert "warning: the map reverts" not in text
    res, text = _invoke(*common, "--out", str(tmp_path / "b"))
    assert res.exit_code == 0, text
    assert "warning: the map reverts to its prior mean" in text


@pytest.fixture
def lonlat_csv(samples_csv, tmp_path):
    from pyproj import Transformer

    df = pd.read_csv(samples_csv)
    lon, lat = Transformer.from_crs(CRS, "EPSG:4326", always_xy=True).transform(df.x, df.y)
    path = tmp_path / "lonlat.csv"
    pd.DataFrame({"lon": lon, "lat": lat, "h": df.z}).to_csv(path, index=False)
    return path


def test_lonlat_without_crs_is_told_to_pass_epsg_4326(lonlat_csv, tmp_path):
    """The fix used to read 'pass --crs EPSG:32608' for a lon/lat table too."""
    res, text = _invoke("reconstruct", str(lonlat_csv), "--out", str(tmp_path / "o"))
    assert isinstance(res.exception, InputError)
    assert "named lon/lat: pass --crs EPSG:4326" in text


@pytest.mark.parametrize("header", ["lon,lat,h", "x,y,z"])
def test_lonlat_read_as_metres_is_refused_naming_crs(lonlat_csv, tmp_path, header):
    """lon/lat under --crs EPSG:32608 made a 1 x 1-cell map, then (with the resolution check)
    asked for 0.0026 m cells: the cause is the CRS, and the error now says so."""
    path = tmp_path / "as_metres.csv"
    lines = lonlat_csv.read_text().splitlines()
    path.write_text("\n".join([header, *lines[1:]]) + "\n")
    res, text = _invoke("reconstruct", str(path), "--crs", CRS, "--out", str(tmp_path / "o"))
    assert isinstance(res.exception, InputError)
    assert text.startswith("--crs:") or "--crs: expected the CRS" in text
    assert "look like longitude/latitude in degrees" in text and "EPSG:4326" in text


def test_a_sigma_column_is_read_as_the_samples_noise(samples_csv, tmp_path):
    """A 1-sigma column under any checkpoint alias (sigma, z_std, elevation_std...) was
    silently ignored: 0.2 m spot heights were taken as exact (z_var = 0)."""
    from toolkit.samples_io import read_samples

    df = pd.read_csv(samples_csv)
    for name in ("sigma", "elevation_std"):
        path = tmp_path / f"{name}.csv"
        df[["x", "y", "z"]].assign(**{name: 0.2, "note": "rtk"}).to_csv(path, index=False)
        table = read_samples(path, CRS)
        np.testing.assert_allclose(table.samples.z_var, 0.04)
        assert f"column {name!r} read as each sample's 1-sigma (m)" in table.note
        assert "columns not read: note" in table.note  # counted, not dropped silently
    bare = tmp_path / "bare.csv"
    df[["x", "y", "z"]].to_csv(bare, index=False)
    assert "no z_var or 1-sigma column" in read_samples(bare, CRS).note
    both = tmp_path / "both.csv"
    df.assign(sigma=0.3).to_csv(both, index=False)  # z_var 0.04 against sigma 0.3
    with pytest.raises(InputError, match="z_var and 'sigma'"):
        read_samples(both, CRS)
    df.assign(sigma=0.2).to_csv(both, index=False)  # they agree: fine
    np.testing.assert_allclose(read_samples(both, CRS).samples.z_var, 0.04)


def test_a_map_far_larger_than_the_survey_is_warned_before_the_fit(samples_csv, tmp_path):
    """--bounds 10 km x 10 km at 4 m around a 600 m survey ran > 3 min (6.25 million cells)
    without a word. Here at 100 m cells (fast): the warning comes first, with the share."""
    res, text = _invoke("reconstruct", str(samples_csv), "--crs", CRS,
                        "--bounds", "521000", "6470000", "531000", "6480000",
                        "--resolution", "100", "--out", str(tmp_path / "m"))  # fmt: skip
    assert res.exit_code == 0, text
    # 300 uniform samples span ~592 x 593 m of the 100 km^2 map: 0.35 %
    assert "warning: the samples' bounding box covers 0.35 % of the map" in text
    assert text.index("bounding box covers") < text.index("glacimap reconstruct — seed 0")
    res, text = _invoke("reconstruct", str(samples_csv), "--crs", CRS, "--resolution", "50",
                        "--out", str(tmp_path / "n"))  # fmt: skip
    assert res.exit_code == 0 and "bounding box covers" not in text


def test_the_cli_fits_the_terrain_layers_default_model():
    """`glacimap reconstruct` / `run` and `TerrainGP()` fit hyperparameters on the same number
    of samples. With 1,000 (the scenario's old value) against the library's 2,000, 3,000
    uniform spot heights on the default site got a single Matérn 7/2 (ℓ 370 m, nugget
    0.098 m² against 0.04 stated) and held-out coverage 43.6 / 73.6 %; with 2,000, SE + SE
    and 71.6 / 95.7 % (the default run: RMSE 0.592 m either way)."""
    from terrain import TerrainGP
    from toolkit.config import load_scenario

    rc = load_scenario()["reconstruct"]
    gp = TerrainGP()
    assert rc["max_fit_samples"] == gp.max_fit_samples and rc["method"] == gp.method


def test_spot_heights_without_a_track_column_are_independent(tmp_path):
    """A CSV without ``track_z_std_m`` holds independent spot heights: no along-track term
    (it was sqrt(z_var), shared by every neighbour). Measured with `glacimap reconstruct` on
    3,000 uniform spot heights of the default site (sd 0.2 m, 10 m cells): truth coverage
    68 / 95 % 93.1 / 99.6 % before (z std 0.57), 73.9 / 96.8 % after (z std 0.94)."""
    from toolkit.samples_io import read_samples

    rng = np.random.default_rng(0)
    xy = rng.uniform(0, 500, (200, 2)) + [500_000, 6_800_000]
    z = 100 + 0.01 * xy[:, 0] - 5_000 + rng.normal(0, 0.2, 200)
    plain = pd.DataFrame({"x": xy[:, 0], "y": xy[:, 1], "z": z, "z_var": 0.04})
    plain.to_csv(tmp_path / "spot.csv", index=False)
    t = read_samples(tmp_path / "spot.csv", crs="EPSG:32608")
    assert np.all(t.track_z_std == 0.0) and "independent" in t.note
    rover = plain.assign(track_z_std_m=0.3)  # a rover's landmarks state their shared error
    rover.to_csv(tmp_path / "rover.csv", index=False)
    t = read_samples(tmp_path / "rover.csv", crs="EPSG:32608")
    assert np.all(t.track_z_std == 0.3) and "independent" not in t.note


def test_checkpoints_off_the_map_are_refused_before_the_fit(samples_csv, tmp_path, monkeypatch):
    """Before: lon/lat checkpoints without a CRS were found unusable only after the fit
    (25 s for 32,000 samples); now they are placed on the map's grid first."""
    import toolkit.stages

    def no_fit(*args, **kwargs):
        raise AssertionError("the GP was fitted before the checkpoints were checked")

    monkeypatch.setattr(toolkit.stages, "reconstruct_stage", no_fit)
    cps = tmp_path / "cps.csv"
    # degrees read as metres: every checkpoint lies far outside the UTM map
    pd.DataFrame({"x": [-134.56, -134.55], "y": [58.41, 58.42], "z": [10.0, 11.0]}).to_csv(
        cps, index=False
    )
    out = tmp_path / "out"
    res, text = _invoke("reconstruct", str(samples_csv), "--crs", CRS, "--resolution", "10",
                        "--checkpoints", str(cps), "--out", str(out))  # fmt: skip
    assert isinstance(res.exception, InputError), text
    assert "0 of 2 usable (0 NaN, 0 not projectable, 2 outside the DEM, 0 on nodata)" in text
    assert "add a crs column (e.g. EPSG:4326) or a .crs sidecar" in text
    assert not out.exists()  # before: an empty --out stayed behind


def test_checkpoints_partly_on_the_map_pass_the_early_check(site):
    from terrain import Grid
    from toolkit.certify import require_checkpoints_on

    grid = Grid.from_bounds((526000.0, 6475000.0, 526600.0, 6475600.0), 10.0, crs=CRS)
    table = {"x": [526100.0, 600000.0], "y": [6475100.0, 6475100.0], "z": [1.0, 2.0]}
    cps = require_checkpoints_on(table, grid, crs=CRS)  # one on, one off: certify counts it
    assert cps.n == 2
    table["x"][0] = 700000.0
    with pytest.raises(InputError, match=r"0 of 2 usable .* 2 outside the DEM"):
        require_checkpoints_on(table, grid, crs=CRS)


def test_a_horizontal_sigma_widens_the_map_where_it_slopes(samples_csv, tmp_path):
    # digitised contours' position error (docs/terrain.md "A real map's contours"): the
    # product states it and its 1-sigma grows by w |grad z|^2 h^2; a negative one is refused
    # naming the option, before anything is written
    bad = tmp_path / "bad"
    res, text = _invoke("reconstruct", str(samples_csv), "--crs", CRS, "--resolution", "20",
                        "--horizontal-sd", "-3", "--out", str(bad))  # fmt: skip
    assert res.exit_code != 0 and "--horizontal-sd" in text and ">= 0" in text
    assert not bad.exists() or not any(bad.iterdir())
    maps = {}
    for h in (None, "5"):
        out = tmp_path / f"h{h}"
        extra = [] if h is None else ["--horizontal-sd", h]
        res, text = _invoke("reconstruct", str(samples_csv), "--crs", CRS, "--resolution",
                            "20", *extra, "--out", str(out))  # fmt: skip
        assert res.exit_code == 0, text
        maps[h] = xr.open_dataset(out / "product.nc").load()
    plain, wide = maps[None], maps["5"]
    assert wide.attrs["samples_horizontal_std_m"] == 5.0
    np.testing.assert_array_equal(wide["elevation"].values, plain["elevation"].values)
    added = wide["elevation_std"].values ** 2 - plain["elevation_std"].values ** 2
    gy, gx = np.gradient(plain["elevation"].values, plain["y"].values, plain["x"].values)
    slope2 = gx**2 + gy**2
    assert (added >= -1e-9).all() and (added <= 25.0 * slope2 + 1e-9).all()  # w <= 1
    steep = slope2 > np.quantile(slope2, 0.9)
    assert added[steep].mean() > 0.5 * 25.0 * slope2[steep].mean()
