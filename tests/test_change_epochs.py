"""The scenario's second epoch (``[change]``, ``glacimap simulate/run --epoch 2``).

Reference values: the known change is :func:`terrain.surface_change` of the epoch-1 site
(the same function, called independently here); the simulator's texture points lie on its
surface, so an epoch-2 landmark's true height is the site's plus the change at its position
(bilinear on both grids: equal to rounding).
"""

from __future__ import annotations

import json

import numpy as np
import pyogrio
import pytest
import rasterio
import shapely
import xarray as xr
from typer.testing import CliRunner

from factorgraph.log import read_log
from terrain import default_outline, surface_change
from terrain.errors import InputError
from toolkit.cli import app
from toolkit.config import load_scenario
from toolkit.epochs import epoch_truth, survey_scenario, true_change, write_change_truth
from toolkit.pipeline import make_site

runner = CliRunner()


def _at(da, xy):
    return da.interp(x=xr.DataArray(xy[:, 0], dims="p"), y=xr.DataArray(xy[:, 1], dims="p")).values


def test_epoch_2_is_the_site_plus_the_known_change():
    s1 = load_scenario()
    s2 = load_scenario(overrides={"change": {"epoch": 2, "change_seed": 5}})
    site = make_site(s1)
    assert epoch_truth(s1, site) is site and survey_scenario(s1) is s1
    after = epoch_truth(s2, site)
    bounds = tuple(s2["site"]["bounds"])
    dh = surface_change(site, default_outline(bounds, 0.2), seed=5)
    np.testing.assert_allclose(after.values - site.values, dh.values, rtol=0, atol=1e-12)
    assert dh.values.min() < -2.0 and dh.values.max() <= 0.0  # thinning, 0.5-3 m (+features)
    assert after.attrs["epoch"] == 2 and after.attrs["change_seed"] == 5
    s2s = survey_scenario(s2)
    assert s2s["seed"] == s2["seed"] + 2 and s2["seed"] == 0  # the input is not changed


@pytest.mark.parametrize(
    "key, value, match",
    [
        ("epoch", 3, "change.epoch"),
        ("max_thinning_m", 0.1, "min_thinning_m/max_thinning_m"),
        ("outline_margin", 0.6, "change.outline_margin"),
        ("seed_offset", 0, "change.seed_offset"),
    ],
)
def test_bad_change_table(key, value, match):
    change = {"epoch": 2, key: value} if key != "epoch" else {key: value}
    with pytest.raises(InputError, match=match):
        load_scenario(overrides={"change": change})


def test_simulate_epoch_2_surveys_the_changed_site(tmp_path):
    """``glacimap simulate --epoch 2``: the same plan over the changed surface, with its own
    GPS bias draw (seed + seed_offset)."""
    logs = {}
    for epoch in (1, 2):
        out = tmp_path / f"e{epoch}"
        res = runner.invoke(app, ["simulate", "--epoch", str(epoch), "--out", str(out)])
        assert res.exit_code == 0, res.output
        logs[epoch] = read_log(out)
    s = load_scenario()
    site, dh = make_site(s), true_change(s, make_site(s))
    for epoch, log in logs.items():
        lm = log.truth["landmark_xyz"] + np.r_[log.origin, 0.0]
        expect = _at(site, lm) + (_at(dh, lm) if epoch == 2 else 0.0)
        ok = np.isfinite(expect)
        assert ok.mean() > 0.99
        np.testing.assert_allclose(lm[ok, 2], expect[ok], atol=1e-6)
        if epoch == 2:
            assert np.sum(_at(dh, lm)[ok] < -0.5) > 100  # the survey sees the thinning
    assert logs[1].seed == 0 and logs[2].seed == 2
    b1, b2 = logs[1].truth["gps_bias"], logs[2].truth["gps_bias"]
    n = min(len(b1), len(b2))
    assert not np.allclose(b1[:n], b2[:n])  # a fresh GPS bias draw


def test_change_truth_files_round_trip(tmp_path):
    s2 = load_scenario(overrides={"change": {"epoch": 2}})
    site = make_site(s2)
    paths = write_change_truth(s2, site, tmp_path)
    assert write_change_truth(load_scenario(), site, tmp_path / "none") == {}
    _, _, wkb, _ = pyogrio.raw.read(paths["outline"])
    poly = shapely.from_wkb(wkb[0])
    assert poly.equals_exact(default_outline(tuple(s2["site"]["bounds"]), 0.2), 1e-6)
    assert pyogrio.read_info(paths["outline"])["crs"] == "EPSG:32608"
    with rasterio.open(paths["true_change"]) as src:
        assert src.descriptions == ("dh",)
        np.testing.assert_allclose(src.read(1), true_change(s2, site).values, atol=1e-6)
    assert not list(tmp_path.glob(".*"))  # no temporary leftovers


@pytest.mark.slow
def test_two_epochs_from_one_scenario_differ_by_the_known_change(tmp_path):
    """``glacimap run`` twice (epoch 1 and 2) on a small scenario (a 300 m corner of the
    default site, 2 swaths, 5 m grid, as tests/test_run_products.py), then ``glacimap
    change`` on the two folders: the GP route; the map difference against the known change
    on the map grid is inside the stated 1-sigma, per cell and for the volume."""
    cfg = tmp_path / "small.toml"
    cfg.write_text(
        "[site]\nbounds = [526000.0, 6475000.0, 526300.0, 6475300.0]\n[plan]\nn_swaths = 2\n"
        "[reconstruct]\nresolution_m = 5.0\nmax_fit_samples = 300\nn_restarts = 0\n"
        "[certify]\nn_boot = 200\nheldout_folds = 0\n[export]\nmesh = false\n"
    )
    for epoch in (1, 2):
        out = str(tmp_path / f"e{epoch}")
        args = ["run", "--config", str(cfg), "--epoch", str(epoch), "--out", out]
        res = runner.invoke(app, args)
        assert res.exit_code == 0, res.output
    e1, e2 = tmp_path / "e1", tmp_path / "e2"
    cert2 = json.loads((e2 / "certificate.json").read_text())
    assert cert2["scenario"]["seed"] == 2 and cert2["scenario"]["change"]["epoch"] == 2
    with xr.open_dataset(e1 / "product.nc") as p1, xr.open_dataset(e2 / "product.nc") as p2:
        p1, p2 = p1.load(), p2.load()
    s = load_scenario(cfg)
    dh_true = true_change(s, make_site(s))
    dh_true = dh_true.interp(x=p1.x, y=p1.y).values
    z = (p2.elevation.values - p1.elevation.values - dh_true) / np.hypot(
        p1.elevation_std.values, p2.elevation_std.values
    )
    inside = np.abs(z[np.isfinite(z)]) <= 1.96
    assert inside.mean() > 0.85, inside.mean()
    assert np.nanmin(dh_true) < -1.0  # the glacier is in this corner
    out = tmp_path / "change"
    res = runner.invoke(
        app, ["change", str(e1), str(e2), "--outline", str(e2 / "glacier_outline.gpkg"),
              "--out", str(out)],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    vol = json.loads((out / "volume.json").read_text())
    assert vol["route"] == "gp_structure", vol["route_reason"]
    from terrain import Grid
    from terrain.volume import outline_weights
    from toolkit.epochs import glacier_outline

    g = Grid.from_dataarray(p1)
    true_v = float(np.sum(outline_weights(g, glacier_outline(s)) * dh_true))
    assert abs(vol["volume_m3"] - true_v) < 3 * vol["volume_std_m3"]
