"""The geodetic mass balance of a volume change (``terrain.mass_balance``).

Reference values by hand: dV = -1e6 m^3 at 850 kg m^-3 over 1 km^2 is dM = -8.5e8 kg and
B = -8.5e8 / (1e6 x 1000) = -0.85 m w.e.; 2015-08-01 to 2024-08-01 is 3,288 days, 9.0021
Julian years: -0.0944 m w.e. a^-1.
"""

from __future__ import annotations

import csv
import json
from types import SimpleNamespace

import pytest

from terrain import InputError
from terrain.mass_balance import mass_balance, survey_years


def test_specific_mass_balance_and_its_rate_by_hand():
    vc = SimpleNamespace(mass_kg=-8.5e8, mass_std_kg=1.0e8, area_m2=1.0e6, mean_dh_m=-1.0,
                         mean_dh_std_m=0.05)  # fmt: skip
    period = mass_balance(vc)
    assert period["specific_mwe"] == pytest.approx(-0.85, rel=1e-12)
    assert period["specific_std_mwe"] == pytest.approx(0.1, rel=1e-12)
    assert "rate_mwe_a" not in period and "no --dates" in period["note"]
    mb = mass_balance(vc, ("2015-08-01", "2024-08-01"))
    assert mb["years"] == pytest.approx(3288 / 365.25, rel=1e-12)
    assert mb["rate_mwe_a"] == pytest.approx(-0.85 / (3288 / 365.25), rel=1e-12)
    assert mb["dhdt_m_a"] == pytest.approx(-1.0 / (3288 / 365.25), rel=1e-12)
    assert mb["rate_std_mwe_a"] == pytest.approx(0.1 / (3288 / 365.25), rel=1e-12)
    with pytest.raises(InputError, match="--dates.*two ISO dates"):
        survey_years(("2015/08/01", "2024-08-01"))
    with pytest.raises(InputError, match="--dates.*AFTER's date after BEFORE's"):
        survey_years(("2024-08-01", "2015-08-01"))


def test_cli_change_reports_the_mass_balance_per_year(tmp_path):
    from test_cli_change import _write_polygon, runner

    from terrain import Grid, default_outline, default_site
    from terrain.product import terrain_dataset
    from terrain.synthetic import DEFAULT_SITE_BOUNDS
    from toolkit.cli import app

    truth = default_site(resolution=10.0)
    g = Grid.from_dataarray(truth)
    std = truth.values * 0 + 0.05
    terrain_dataset(g, truth.values, std, {"seed": 1}).to_netcdf(tmp_path / "b.nc", engine="scipy")
    terrain_dataset(g, truth.values - 2.0, std, {"seed": 2}).to_netcdf(
        tmp_path / "a.nc", engine="scipy"
    )  # 2 m of thinning everywhere
    gpkg = _write_polygon(tmp_path / "g.gpkg", default_outline(DEFAULT_SITE_BOUNDS))
    args = ["change", str(tmp_path / "b.nc"), str(tmp_path / "a.nc"), "--outline", str(gpkg),
            "--no-coregister"]  # fmt: skip
    out = tmp_path / "out"
    res = runner.invoke(app, [*args, "--dates", "2016-09-01", "2026-09-01", "--out", str(out)])
    assert res.exit_code == 0, res.output
    vol = json.loads((out / "volume.json").read_text())
    mb = vol["mass_balance"]
    years = 3652 / 365.25  # ten years, three of them leap
    assert mb["specific_mwe"] == pytest.approx(-2.0 * 850 / 1000, rel=1e-9)
    assert mb["rate_mwe_a"] == pytest.approx(-1.7 / years, rel=1e-9)
    assert mb["dhdt_m_a"] == pytest.approx(-2.0 / years, rel=1e-9)
    rows = {r["quantity"]: r for r in csv.DictReader((out / "volume.csv").open())}
    assert float(rows["mass_balance_rate"]["value"]) == pytest.approx(mb["rate_mwe_a"])
    assert rows["mass_balance_rate"]["unit"] == "m w.e. a-1"
    assert "m w.e. a&#8315;&sup1; over" in (out / "change_report.html").read_text()
    assert "m w.e. a^-1 over 10.00 years" in " ".join(res.output.split())
    never = tmp_path / "never"
    res = runner.invoke(app, [*args, "--dates", "2026-09-01", "2016-09-01", "--out", str(never)])
    assert isinstance(res.exception, InputError) and not never.exists()


def test_survey_dates_from_utc_times_and_change_reads_them(tmp_path):
    from test_cli_change import _write_polygon, runner

    from terrain import Grid, default_outline, default_site
    from terrain.mass_balance import survey_date_attrs
    from terrain.product import terrain_dataset
    from terrain.synthetic import DEFAULT_SITE_BOUNDS
    from toolkit.cli import app

    t0 = 1_782_864_000.0  # 2026-07-01 00:00 UTC (POSIX)
    got = survey_date_attrs([t0 + 3600.0, t0 + 90_000.0, t0 + 7200.0])
    assert got == {"survey_date": "2026-07-01", "survey_period": "2026-07-01/2026-07-02"}
    assert survey_date_attrs([12.0, 3600.0]) == {}  # a rover's times since its log's start
    assert survey_date_attrs(None) == {}
    truth = default_site(resolution=10.0)
    g = Grid.from_dataarray(truth)
    std = truth.values * 0 + 0.05
    for name, dz, day in (("b", 0.0, "2016-09-01"), ("a", -2.0, "2026-09-01")):
        ds = terrain_dataset(g, truth.values + dz, std, {"seed": 1})
        ds.attrs["survey_date"] = day
        ds.to_netcdf(tmp_path / f"{name}.nc", engine="scipy")
    gpkg = _write_polygon(tmp_path / "g.gpkg", default_outline(DEFAULT_SITE_BOUNDS))
    out = tmp_path / "out"
    args = ["change", str(tmp_path / "b.nc"), str(tmp_path / "a.nc"), "--outline", str(gpkg)]
    res = runner.invoke(app, [*args, "--no-coregister", "--out", str(out)])
    assert res.exit_code == 0, res.output
    mb = json.loads((out / "volume.json").read_text())["mass_balance"]
    assert mb["dates"] == ["2016-09-01", "2026-09-01"]
    assert mb["rate_mwe_a"] == pytest.approx(-1.7 / (3652 / 365.25), rel=1e-9)
    assert "(the products' survey_date)" in mb["note"]
