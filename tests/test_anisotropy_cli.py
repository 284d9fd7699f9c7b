"""A known grain from the command line and the scenario file, recorded in the products, and
a change between two anisotropic products rebuilt by the GP route.

References: the library's own ``TerrainGP`` (same settings) and the in-memory GPs of the
two epochs (``tests/test_cli_change_gp.py`` makes them as ``glacimap reconstruct`` does).
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
import xarray as xr
from test_cli_change_gp import _make_epochs
from typer.testing import CliRunner

from terrain import Anisotropy, InputError, TerrainGP, default_site
from terrain.sampling import sample_dem
from toolkit.change_inputs import locate_product, rebuild_gp
from toolkit.cli import app
from toolkit.config import anisotropy_option, load_scenario
from toolkit.stages import certify_stage

runner = CliRunner()
CRS = "EPSG:32608"


@pytest.fixture(scope="module")
def samples_csv(tmp_path_factory):
    """300 spot heights with a 20 cm 1-sigma on the default site (seeded)."""
    rng = np.random.default_rng(0)
    xy = rng.uniform([526002.0, 6475002.0], [526598.0, 6475598.0], size=(300, 2))
    z = sample_dem(default_site(resolution=4.0), xy) + rng.normal(0.0, 0.2, 300)
    path = tmp_path_factory.mktemp("in") / "spots.csv"
    pd.DataFrame({"x": xy[:, 0], "y": xy[:, 1], "z": z, "z_var": 0.04}).to_csv(path, index=False)
    return path


def test_settings_read_the_three_forms():
    assert anisotropy_option("none") is None and anisotropy_option("AUTO") == "auto"
    assert anisotropy_option([30, 2]) == Anisotropy(30.0, 2.0)
    assert anisotropy_option("45,1.5") == Anisotropy(45.0, 1.5)
    # the scenario's default is the library's default: isotropic
    rc = load_scenario()["reconstruct"]
    assert anisotropy_option(rc["anisotropy"]) is TerrainGP().anisotropy is None
    for bad in ("diagonal", [30.0, 0.5], [1, 2, 3]):
        with pytest.raises(InputError, match="reconstruct.anisotropy"):
            load_scenario(overrides={"reconstruct": {"anisotropy": bad}})


def test_cli_grain_is_fitted_and_recorded(samples_csv, tmp_path):
    out = tmp_path / "map"
    res = runner.invoke(app, ["reconstruct", str(samples_csv), "--crs", CRS, "--resolution",
                              "20", "--anisotropy", "30,2", "--out", str(out)])  # fmt: skip
    assert res.exit_code == 0, res.output
    assert "grain" in res.output and "azimuth 30.0" in " ".join(res.output.split())
    attrs = xr.open_dataset(out / "product.nc").attrs
    assert json.loads(attrs["anisotropy"])["azimuth_deg"] == pytest.approx(30.0)
    assert json.loads(attrs["anisotropy"])["ratio"] == pytest.approx(2.0)


def test_cli_bad_grain_is_refused_before_anything_is_written(samples_csv, tmp_path):
    out = tmp_path / "never"
    res = runner.invoke(app, ["reconstruct", str(samples_csv), "--crs", CRS,
                              "--anisotropy", "north", "--out", str(out)])  # fmt: skip
    assert res.exit_code != 0
    assert isinstance(res.exception, InputError) and "reconstruct.anisotropy" in str(res.exception)
    assert not out.exists()


def test_change_gp_route_rebuilds_an_anisotropic_product(tmp_path):
    over = {"reconstruct": {"max_fit_samples": 300, "anisotropy": [60.0, 1.5]}}
    settings = load_scenario(overrides=over)
    d, _, _, rec_b, _, _ = _make_epochs(tmp_path, settings)
    assert rec_b.gp.anisotropy_ == Anisotropy(60.0, 1.5)
    # the certificate states the grain with the kernel
    cert = certify_stage(rec_b, None, settings, 0)
    assert cert["reconstruction"]["anisotropy"]["ratio"] == pytest.approx(1.5)
    ds = xr.open_dataset(d / "before" / "product.nc").load()
    gp, note = rebuild_gp(ds, locate_product(d / "before", None, "BEFORE"))
    assert gp is not None, note
    assert gp.anisotropy_ == rec_b.gp.anisotropy_
    xy = rec_b.samples.xy[:50] + 3.0
    np.testing.assert_allclose(gp.predict(xy), rec_b.gp.predict(xy), atol=1e-9)
