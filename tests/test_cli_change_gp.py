"""``glacimap change`` on two glacimap product folders takes the GP route.

Two small simulated epochs are made here the way ``glacimap reconstruct`` / ``process``
make theirs (``toolkit.stages.reconstruct_stage``: kernel by evidence, a prior DEM file as
the mean with its offset and scale fitted, a shared offset 1-sigma in the product), written
as product folders (``product.nc`` + ``samples.csv`` + the prior DEM). The reference value
is the library's own GP route on the in-memory GPs, ``terrain.volume_change(diff, outline,
models=(gp_before, gp_after))``: the CLI, rebuilding the GPs from the files, must give the
same volume 1-sigma. Fallbacks are checked too: no samples (variogram, said why), samples
that do not belong to the map (variogram, said why), a missing samples file (error).
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import xarray as xr
from test_cli_change import _write_polygon
from typer.testing import CliRunner

from survey.lawnmower import lawnmower
from terrain import (
    BreaklineMean,
    ElevationSamples,
    Grid,
    default_outline,
    default_site,
    difference,
    sample_along_path,
    second_epoch,
    volume_change,
)
from terrain.synthetic import DEFAULT_SITE_BOUNDS
from terrain.volume import outline_weights
from toolkit.change_inputs import kernel_from_provenance, locate_product, rebuild_gp
from toolkit.cli import app
from toolkit.config import load_scenario
from toolkit.export import write_cog
from toolkit.field_survey import simulated_prior
from toolkit.processing import prior_mean
from toolkit.products import write_csv
from toolkit.stages import reconstruct_stage

runner = CliRunner()
SHARED_SD = 0.085  # m, each survey's shared offset 1-sigma (benchmarks/change.py)


def _epoch(folder, truth, path, seed, offset, grid, settings, line=None):
    """One epoch as a product folder: samples.csv, prior.tif, product.nc; with ``line``
    (vertices, m) the prior DEM is the base of a ``BreaklineMean`` across it."""
    folder.mkdir()
    rng = np.random.default_rng(seed)
    s, _ = sample_along_path(truth, path, 300, seed=rng)
    s = ElevationSamples(s.xy, s.z + offset, s.z_var, crs=s.crs)
    prior = simulated_prior(truth, 75.0, 1.5, 0.3, rng)
    pds = prior.to_dataset(name="elevation")
    pds.attrs = dict(prior.attrs)
    write_cog(pds, folder / "prior.tif", bands=[("elevation", "prior DEM")])
    mean = prior_mean(folder / "prior.tif", settings)
    rec = reconstruct_stage(
        s,
        grid,
        mean if line is None else BreaklineMean([line], base=mean),
        settings,
        seed,
        shared_z_std=SHARED_SD,
        heldout_folds=0,
    )
    rec.product.to_netcdf(folder / "product.nc", engine="scipy")
    write_csv(
        folder / "samples.csv",
        {
            "x": s.xy[:, 0],
            "y": s.xy[:, 1],
            "z": s.z,
            "z_var": s.z_var,
            "shared_offset_std_m": np.full(s.n, SHARED_SD),
            "crs": np.full(s.n, s.crs.to_string()),
        },
    )
    return rec


def _make_epochs(d, settings, line=None):
    """Two epochs of the default site (before, after a known change) as product folders;
    with ``line``, a 3 m step across it (up to its left) in both and in their means."""
    truth = default_site(resolution=4.0)
    outline = default_outline(DEFAULT_SITE_BOUNDS)
    after = second_epoch(truth, outline, seed=3)
    if line is not None:
        X, Y = np.meshgrid(truth.x.values, truth.y.values)
        xy = np.column_stack([X.ravel(), Y.ravel()])
        step = 3.0 * BreaklineMean([line], width=2.0).steps(xy)[:, 0].reshape(X.shape)
        truth, after = truth + step, after + step
    path = lawnmower(DEFAULT_SITE_BOUNDS, 4, margin=20.0).waypoints
    grid = Grid.from_bounds(DEFAULT_SITE_BOUNDS, 10.0)  # 60 x 60 cells
    rec_b = _epoch(d / "before", truth, path, 1, 0.05, grid, settings, line)
    rec_a = _epoch(d / "after", after, path, 2, -0.1, grid, settings, line)
    gpkg = _write_polygon(d / "glacier.gpkg", outline)
    W = outline_weights(grid, outline)
    true_v = float(np.sum(W * (after - truth).interp(x=grid.x, y=grid.y).values))
    return d, outline, gpkg, rec_b, rec_a, true_v


def _change(d, gpkg, out):
    """``glacimap change BEFORE AFTER --outline`` on the two folders; the CLI result."""
    return runner.invoke(
        app, ["change", str(d / "before"), str(d / "after"), "--outline", str(gpkg),
              "--out", str(out)],
    )  # fmt: skip


@pytest.fixture(scope="module")
def epochs(tmp_path_factory):
    settings = load_scenario(overrides={"reconstruct": {"max_fit_samples": 300}})
    return _make_epochs(tmp_path_factory.mktemp("gp_epochs"), settings)


def test_rebuilt_gp_reproduces_the_map(epochs):
    d, *_ = epochs
    rec = epochs[3]
    ds = xr.open_dataset(d / "before" / "product.nc").load()
    gp, note = rebuild_gp(ds, locate_product(d / "before", None, "BEFORE"))
    assert gp is not None, note
    assert repr(gp.kernel_) == repr(rec.gp.kernel_) and gp.nugget_ == rec.gp.nugget_
    np.testing.assert_allclose(gp.mean_.coef_, rec.gp.mean_.coef_, rtol=1e-9)
    xy = rec.samples.xy[:50] + 3.0
    np.testing.assert_allclose(gp.predict(xy), rec.gp.predict(xy), atol=1e-9)
    # the kernel comes back from the provenance exactly (JSON values, not the 4-digit repr)
    k = kernel_from_provenance(ds.attrs["kernel"], ds.attrs["hyperparameters"])
    np.testing.assert_array_equal(k.theta, rec.gp.kernel_.theta)


def test_samples_that_state_no_crs_are_read_in_the_maps(epochs, tmp_path):
    # a user's CSV of x, y, z (reconstruct took --crs; change has no --crs): read in the
    # map's CRS and said so; a file stating another CRS is refused as before
    d, *_ = epochs
    text = (d / "before" / "samples.csv").read_text().splitlines()
    cols = text[0].split(",")
    keep = [i for i, c in enumerate(cols) if c != "crs"]
    plain = tmp_path / "plain.csv"
    plain.write_text("\n".join(",".join(r.split(",")[i] for i in keep) for r in text) + "\n")
    ds = xr.open_dataset(d / "before" / "product.nc").load()
    gp, note = rebuild_gp(ds, locate_product(d / "before", plain, "BEFORE"))
    assert gp is not None, note
    assert "plain.csv states no CRS: read in the map's, EPSG:32608" in note
    other = tmp_path / "other.csv"
    other.write_text(plain.read_text())
    (tmp_path / "other.crs").write_text("EPSG:32607\n")
    gp, note = rebuild_gp(ds, locate_product(d / "before", other, "BEFORE"))
    assert gp is None and "is not in the map's CRS (EPSG:32608)" in note


def test_kernel_with_microscale_parts_comes_back_from_the_provenance():
    # Real-terrain maps carry the nugget as Microscale parts (50k: one per length the window
    # evidence weights); they were read as a count mismatch and the GP route fell back.
    from terrain.kernels import Matern, SquaredExponential
    from terrain.microscale import Microscale

    k = SquaredExponential(6.8, 13.6) + Matern(1.0, 40.0, nu=2.5)
    k = k + Microscale(2.7e-4, 4.03) + Microscale(5.5e-4, 16.1)
    hyper = dict(zip(k.param_names, np.exp(k.theta).tolist(), strict=True)) | {"nugget": 1e-6}
    got = kernel_from_provenance(repr(k), json.dumps(hyper))
    assert repr(got) == repr(k)
    assert [type(p) for p in got.parts] == [type(p) for p in k.parts]
    np.testing.assert_allclose(got.theta, k.theta, rtol=0, atol=1e-12)


def test_cli_gp_route_matches_the_library(epochs, tmp_path):
    d, outline, gpkg, rec_b, rec_a, true_v = epochs
    out = tmp_path / "out"
    res = _change(d, gpkg, out)
    assert res.exit_code == 0, res.output
    assert "route: gp_structure" in res.output
    vol = json.loads((out / "volume.json").read_text())
    assert vol["route"] == "gp_structure" and vol["method"] == "gp_posterior"
    assert "not co-registered" in vol["route_reason"] and vol["coregistration"] is None
    assert "Route gp_structure" in (out / "change_report.html").read_text()
    # the library's GP route on the in-memory GPs: the reference
    diff = difference(rec_b.product, rec_a.product, coregister=False)
    ref = volume_change(diff, outline, models=(rec_b.gp, rec_a.gp))
    assert vol["volume_m3"] == pytest.approx(ref.volume_m3, rel=1e-9)
    assert vol["volume_std_m3"] == pytest.approx(ref.volume_std_m3, rel=1e-6)
    for k in ("gp_before", "gp_after", "shared_offset_before", "shared_offset_after"):
        assert vol["budget_m3"][k] == pytest.approx(ref.budget_m3[k], rel=1e-6)
    # the shared offsets are in it: each about SHARED_SD x area (the whole map moves)
    area = vol["area_m2"]
    assert vol["budget_m3"]["shared_offset_before"] == pytest.approx(SHARED_SD * area, rel=0.05)
    # and the known change is inside the interval (3 sigma)
    assert abs(vol["volume_m3"] - true_v) < 3 * vol["volume_std_m3"]


def test_cli_falls_back_to_variogram_and_says_why(epochs, tmp_path):
    d, _, gpkg, *_ = epochs
    bare = tmp_path / "bare"
    bare.mkdir()
    shutil.copy(d / "before" / "product.nc", bare / "product.nc")  # no samples.csv
    out = tmp_path / "out"
    res = runner.invoke(
        app, ["change", str(bare), str(d / "after"), "--outline", str(gpkg), "--out", str(out)]
    )
    assert res.exit_code == 0, res.output
    vol = json.loads((out / "volume.json").read_text())
    assert vol["route"] == "variogram" and vol["method"] == "variogram"
    assert "no samples.csv" in vol["route_reason"] and "co-registered" in vol["route_reason"]
    # samples that are not the map's: the rebuilt GP does not reproduce it -> variogram
    out2 = tmp_path / "out2"
    res = runner.invoke(
        app, ["change", str(d / "before"), str(d / "after"), "--outline", str(gpkg),
              "--samples-before", str(d / "after" / "samples.csv"), "--out", str(out2)],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    vol = json.loads((out2 / "volume.json").read_text())
    assert vol["route"] == "variogram"
    assert "does not reproduce the map" in vol["route_reason"]


def test_a_stated_horizontal_sigma_is_said_to_be_outside_the_volumes(epochs, tmp_path):
    # a map made with --horizontal-sd (digitised contours): its cells' dh 1-sigma carry it,
    # the GP route's volume 1-sigma does not, and the change says so in words and in JSON
    d, _, gpkg, *_ = epochs
    contour = tmp_path / "before"
    shutil.copytree(d / "before", contour)
    ds = xr.open_dataset(contour / "product.nc").load()
    ds.attrs["samples_horizontal_std_m"] = 10.0
    (contour / "product.nc").unlink()
    ds.to_netcdf(contour / "product.nc", engine="scipy")
    out = tmp_path / "out"
    res = runner.invoke(
        app, ["change", str(contour), str(d / "after"), "--outline", str(gpkg), "--out", str(out)]
    )
    assert res.exit_code == 0, res.output
    vol = json.loads((out / "volume.json").read_text())
    assert vol["route"] == "gp_structure"
    (note,) = [n for n in vol["notes"] if "horizontal" in n]
    assert "the before map's 10 m samples' horizontal 1-sigma" in note
    assert "not in the volume's" in " ".join(res.output.split())


def test_missing_samples_file_is_an_error(epochs, tmp_path):
    d, _, gpkg, *_ = epochs
    out = tmp_path / "out"
    res = runner.invoke(
        app, ["change", str(d / "before"), str(d / "after"), "--outline", str(gpkg),
              "--samples-after", str(tmp_path / "nope.csv"), "--out", str(out)],
    )  # fmt: skip
    assert res.exit_code != 0
    assert "--samples-after" in str(res.exception)
    assert not out.exists() or not any(out.iterdir())


@pytest.fixture(scope="module")
def tiled_epochs(tmp_path_factory):
    """The same two epochs reconstructed with ``[reconstruct] method = "tiled"``: products
    whose provenance says tiled, which the CLI must rebuild as tiled GPs."""
    settings = load_scenario(overrides={"reconstruct": {"max_fit_samples": 300, "method": "tiled"}})
    return _make_epochs(tmp_path_factory.mktemp("gp_epochs_tiled"), settings)


def test_cli_gp_route_on_tiled_products_matches_the_library(tiled_epochs, tmp_path):
    # Reference: the library's GP route on the in-memory tiled GPs (the same
    # volume_change(..., models=...) as the exact case above).
    d, outline, gpkg, rec_b, rec_a, _ = tiled_epochs
    assert str(rec_b.product.attrs.get("method", "")).startswith("tiled")
    ds = xr.open_dataset(d / "before" / "product.nc").load()
    gp, note = rebuild_gp(ds, locate_product(d / "before", None, "BEFORE"))
    assert gp is not None, note
    assert gp.method == "tiled"
    out = tmp_path / "out"
    res = _change(d, gpkg, out)
    assert res.exit_code == 0, res.output
    vol = json.loads((out / "volume.json").read_text())
    assert vol["route"] == "gp_structure"
    diff = difference(rec_b.product, rec_a.product, coregister=False)
    ref = volume_change(diff, outline, models=(rec_b.gp, rec_a.gp))
    assert vol["volume_m3"] == pytest.approx(ref.volume_m3, rel=1e-9)
    assert vol["volume_std_m3"] == pytest.approx(ref.volume_std_m3, rel=1e-6)


@pytest.fixture(scope="module")
def breakline_epochs(tmp_path_factory):
    """The two epochs with a 3 m step across the site, mapped with a ``BreaklineMean`` whose
    base is the prior DEM (width chosen by the fit): the product records the lines and
    widths (``breaklines``), from which the CLI rebuilds the mean."""
    settings = load_scenario(overrides={"reconstruct": {"max_fit_samples": 300}})
    w, s, e, n = DEFAULT_SITE_BOUNDS
    line = np.array([[w - 10.0, 0.5 * (s + n) - 40.0], [e + 10.0, 0.5 * (s + n) + 40.0]])
    return _make_epochs(tmp_path_factory.mktemp("gp_epochs_breakline"), settings, line)


def test_cli_gp_route_rebuilds_a_breakline_mean(breakline_epochs, tmp_path):
    # Reference: the library's GP route on the in-memory GPs, as above.
    d, outline, gpkg, rec_b, rec_a, true_v = breakline_epochs
    ds = xr.open_dataset(d / "before" / "product.nc").load()
    feature = json.loads(ds.attrs["breaklines"])
    assert feature["geometry"]["type"] == "MultiLineString"
    assert feature["properties"]["widths_m"] == list(rec_b.gp.mean_.widths_)
    gp, note = rebuild_gp(ds, locate_product(d / "before", None, "BEFORE"))
    assert gp is not None, note
    assert type(gp.mean_).__name__ == "BreaklineMean" and gp.mean_.widths_ == rec_b.gp.mean_.widths_
    np.testing.assert_allclose(gp.mean_.coef_, rec_b.gp.mean_.coef_, rtol=1e-9)
    out = tmp_path / "out"
    res = _change(d, gpkg, out)
    assert res.exit_code == 0, res.output
    vol = json.loads((out / "volume.json").read_text())
    assert vol["route"] == "gp_structure", vol["route_reason"]
    diff = difference(rec_b.product, rec_a.product, coregister=False)
    ref = volume_change(diff, outline, models=(rec_b.gp, rec_a.gp))
    assert vol["volume_m3"] == pytest.approx(ref.volume_m3, rel=1e-9)
    # the widths' 1-sigma is derived again at the rebuild by central differences of the
    # misfit (terrain.breakline_evidence.width_uncertainty), which turn the rebuild's 1e-9
    # differences into ~4e-6 of the coefficients' covariance
    assert vol["volume_std_m3"] == pytest.approx(ref.volume_std_m3, rel=2e-5)
    assert abs(vol["volume_m3"] - true_v) < 3 * vol["volume_std_m3"]
    # each map's line and its step, the widths' 1-sigma recorded and rebuilt (the same 3 m
    # step, measured at 0.41.0: 3.01 +- 0.42 m at 2.72 +- 0.96 m wide and 3.49 +- 0.50 m at
    # 2.69 +- 0.76 m; at 0.40.0, without the widths' own uncertainty, 2.63 +- 0.29 m at
    # 1.23 m wide and 4.86 +- 0.55 m at 5.65 m: a false growth of 3.6 sd)
    assert feature["properties"]["widths_sd_m"] == list(rec_b.gp.mean_.widths_sd_)
    assert gp.mean_.widths_sd_ == pytest.approx(rec_b.gp.mean_.widths_sd_, rel=5e-3)
    lines = vol["breaklines"]
    assert [r["step_m"] for r in lines["before"]] == [rec_b.gp.mean_.coef_[2]]
    assert [r["step_m"] for r in lines["after"]] == [rec_a.gp.mean_.coef_[2]]
    assert [r["width_m"] for r in lines["after"]] == list(rec_a.gp.mean_.widths_)
    # the same line in both maps, both widths chosen by the evidence, both GPs rebuilt: the
    # change is read at one shared width (reference: the library on the in-memory GPs), the
    # independent pair kept; the unchanged 3 m step reads no change within 2 sd
    from terrain.breakline_change import shared_width_change

    (change,) = lines["step_changes"]
    ref = shared_width_change(rec_b.gp, rec_a.gp, 0)
    assert change["method"] == "both maps at one shared width"
    assert change["change_m"] == pytest.approx(ref["change_m"], abs=1e-3)
    assert change["change_sd_m"] == pytest.approx(ref["change_sd_m"], rel=1e-2)
    assert change["shared_width_m"] == pytest.approx(ref["width_m"], rel=1e-3)
    indep = rec_a.gp.mean_.coef_[2] - rec_b.gp.mean_.coef_[2]
    assert change["independent_change_m"] == pytest.approx(indep)
    assert abs(change["change_m"]) <= 2.0 * change["change_sd_m"]
    html = (out / "change_report.html").read_text()
    assert 'id="breaklines"' in html and 'id="step_changes"' in html
    # a product that does not record its lines (made before 0.36.0): variogram, said why
    old = tmp_path / "old"
    shutil.copytree(d / "before", old)
    ds.attrs["breaklines"] = ""
    (old / "product.nc").unlink()
    ds.to_netcdf(old / "product.nc", engine="scipy")
    gp, note = rebuild_gp(ds, locate_product(old, None, "BEFORE"))
    assert gp is None and "breaklines are not recorded" in note
