"""The HTML report: written atomically, self-contained, well-formed, with the figures and
tables its inputs call for. The product is the demo's GP + satellite prior map
(toolkit.demo.reconstruction_demo, small and coarse so the module runs in seconds)."""

from __future__ import annotations

import base64
import json
from html.parser import HTMLParser

import numpy as np
import pytest
import typer
from typer.testing import CliRunner

from terrain import InputError
from terrain.sampling import sample_dem
from toolkit.certify import certify, write_certificate
from toolkit.cli.report import RUN_FILES, report_command
from toolkit.demo import reconstruction_demo
from toolkit.report import CHI2_2D_95, write_report

VOID = {"meta", "img", "br", "hr", "link", "input", "col", "area", "base", "source", "wbr"}
PNG = b"\x89PNG\r\n\x1a\n"


class _Checker(HTMLParser):
    """Well-formedness: every non-void tag closed in order; collects imgs and verdict rows."""

    def __init__(self):
        super().__init__()
        self.stack, self.errors, self.imgs, self.verdicts = [], [], [], []

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if tag == "img":
            self.imgs.append(attrs)
        if tag == "tr" and "verdict" in (attrs.get("class") or "").split():
            self.verdicts.append(attrs)
        if tag not in VOID:
            self.stack.append(tag)

    def handle_endtag(self, tag):
        if tag in VOID:
            return
        if not self.stack or self.stack[-1] != tag:
            self.errors.append(f"</{tag}> closes {self.stack[-1:] or 'nothing'}")
        else:
            self.stack.pop()


def _parse(path):
    checker = _Checker()
    checker.feed(path.read_text(encoding="utf-8"))
    checker.close()
    assert not checker.errors and not checker.stack, (checker.errors, checker.stack)
    return checker


@pytest.fixture(scope="module")
def demo():
    return reconstruction_demo(seed=0, n_samples=400, resolution=20.0, max_fit_samples=300)


@pytest.fixture(scope="module")
def cert(demo):
    rng = np.random.default_rng(0)
    w, s, e, n = 526010.0, 6475010.0, 526590.0, 6475590.0
    xy = np.column_stack([rng.uniform(w, e, 30), rng.uniform(s, n, 30)])
    table = {"x": xy[:, 0], "y": xy[:, 1], "z": sample_dem(demo.truth, xy)}
    return certify(demo.maps["gp_satellite"], table, seed=0, n_boot=500)


@pytest.fixture(scope="module")
def trajectory(demo):
    k = len(demo.path)
    cov = np.tile(np.array([[0.04, 0.01], [0.01, 0.09]]), (k, 1, 1))  # m^2
    return {"xy_est": demo.path + 0.3, "xy_true": demo.path, "cov_xy": cov, "landmarks_xy": None}


def test_full_report_is_self_contained_and_well_formed(demo, cert, trajectory, tmp_path):
    path = write_report(
        tmp_path / "report.html",
        product=demo.maps["gp_satellite"],
        certificate=cert,
        truth=demo.truth,
        samples=demo.samples,
        trajectory=trajectory,
        coverage={"science-centric coverage (Eq 11)": 0.4321, "centeredness alpha": 0.0123},
        title="Demo <site>",
    )
    html = path.read_text(encoding="utf-8")
    page = _parse(path)
    # elevation, 1-sigma, error, calibration, checkpoint histogram, trajectory
    assert len(page.imgs) == 6
    for img in page.imgs:
        assert img["src"].startswith("data:image/png;base64,")
        assert base64.b64decode(img["src"].split(",", 1)[1])[:8] == PNG
    assert 'src="http' not in html and "<script" not in html and "<link" not in html
    assert "Demo &lt;site&gt;" in html  # autoescaped
    assert [v["data-standard"] for v in page.verdicts] == [v["standard"] for v in cert["verdicts"]]
    passed = {True: "pass", False: "fail", None: "na"}
    for row, v in zip(page.verdicts, cert["verdicts"], strict=True):
        assert passed[v["passed"]] in row["class"].split()
    assert "science-centric coverage (Eq 11)" in html and "0.4321" in html
    assert f"{cert['accuracy']['rmse_m']:.4g}" in html
    assert cert["dem"]["sha256"] in html and f"numpy</td><td>{np.__version__}" in html
    assert [p.name for p in tmp_path.iterdir()] == ["report.html"]  # no temporaries left


def test_figures_follow_the_inputs(demo, cert, tmp_path):
    path = write_report(tmp_path / "r.html", product=demo.maps["gp_satellite"], certificate=cert)
    assert len(_parse(path).imgs) == 3  # elevation, 1-sigma, checkpoint histogram
    no_hist = {k: v for k, v in cert.items() if k != "error_histogram"}
    path = write_report(tmp_path / "r.html", product=demo.maps["gp_satellite"], certificate=no_hist)
    assert len(_parse(path).imgs) == 2
    assert "Survey coverage" not in path.read_text()


def test_report_is_reproducible(demo, cert, trajectory, tmp_path):
    kwargs = dict(product=demo.maps["gp_satellite"], certificate=cert, trajectory=trajectory)
    a = write_report(tmp_path / "a.html", **kwargs).read_bytes()
    assert write_report(tmp_path / "b.html", **kwargs).read_bytes() == a


def test_95_percent_ellipse_factor():
    # chi-square with 2 dof has CDF 1 - exp(-q/2): the 95 % quantile is -2 ln 0.05 = 5.9915
    from scipy.stats import chi2

    assert CHI2_2D_95**2 == pytest.approx(chi2.ppf(0.95, 2), rel=1e-12)


def test_bad_inputs_leave_no_file(demo, cert, trajectory, tmp_path):
    product = demo.maps["gp_satellite"]
    target = tmp_path / "report.html"
    bad_traj = {**trajectory, "cov_xy": np.zeros((3, 2, 2))}
    with pytest.raises(InputError, match="cov_xy"):
        write_report(target, product=product, certificate=cert, trajectory=bad_traj)
    with pytest.raises(InputError, match="truth"):
        write_report(target, product=product, certificate=cert, truth=np.zeros((3, 3)))
    with pytest.raises(InputError, match="report path"):
        write_report(tmp_path / "missing" / "r.html", product=product, certificate=cert)
    assert list(tmp_path.iterdir()) == []


def _app():
    app = typer.Typer()
    app.command()(report_command)
    return app


def test_report_command_rebuilds_from_a_run_folder(demo, cert, tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    res = CliRunner().invoke(_app(), [str(run)])
    assert isinstance(res.exception, InputError) and "certificate.json" in str(res.exception)
    write_certificate(cert, run / RUN_FILES["certificate"])
    demo.maps["gp_satellite"].to_netcdf(run / "reconstruction.nc", engine="scipy")
    demo.truth.to_dataset(name="elevation").to_netcdf(run / RUN_FILES["truth"], engine="scipy")
    (run / RUN_FILES["coverage"]).write_text(json.dumps({"alpha": 0.25}))
    np.savez(run / RUN_FILES["trajectory"], xy_est=demo.path)
    res = CliRunner().invoke(_app(), [str(run)])
    assert res.exit_code == 0, res.output
    page = _parse(run / RUN_FILES["report"])
    assert len(page.imgs) == 6  # + error, calibration (truth.nc) and trajectory (npz)
    assert len(page.verdicts) == len(cert["verdicts"])
    assert "alpha" in (run / RUN_FILES["report"]).read_text()


# --------------------------------------------------------------------------- held-out sigma
@pytest.fixture(scope="module")
def heldout(demo):
    """A deliberately over-confident GP (kernel variance 1e-3 m^2 on 25 m of relief, nugget
    fixed tiny) checked by spatial block cross-validation: it under-covers."""
    from terrain import SquaredExponential, TerrainGP, cross_validate

    gp = TerrainGP(
        SquaredExponential(1e-3, 15.0),
        nugget=1e-6,
        nugget_bounds="fixed",
        optimize=False,
        method="exact",
    ).fit(demo.samples)
    return cross_validate(gp, demo.samples, seed=0)


@pytest.fixture(scope="module")
def cert_heldout(demo, heldout):
    rng = np.random.default_rng(0)  # the same checkpoints as ``cert``
    w, s, e, n = 526010.0, 6475010.0, 526590.0, 6475590.0
    xy = np.column_stack([rng.uniform(w, e, 30), rng.uniform(s, n, 30)])
    table = {"x": xy[:, 0], "y": xy[:, 1], "z": sample_dem(demo.truth, xy)}
    return certify(demo.maps["gp_satellite"], table, seed=0, n_boot=500, heldout=heldout)


def test_heldout_block_in_the_certificate(cert, cert_heldout, heldout):
    from toolkit.certify import certificate_json, heldout_block

    block = cert_heldout["heldout_calibration"]
    assert {k: v for k, v in cert_heldout.items() if k != "heldout_calibration"} == cert
    assert block["method"] == "spatial block k-fold" and block["n_folds"] == 5
    assert block["block_size_m"] == heldout.block_size and len(block["folds"]) == 5
    for key in ("n", "rmse_m", "nlpd", "coverage_68", "coverage_95", "z_std"):
        assert block[key] == heldout.pooled[key]
    # one sign in the certificate: z = (map - sample) / sd, the sign of mean_error_m (=
    # map - sample); terrain.cross_validate's z is (sample - map) / sd
    assert block["z_mean"] == -heldout.pooled["z_mean"]
    assert np.sign(block["z_mean"]) == np.sign(block["mean_error_m"])
    for fold, ref in zip(block["folds"], heldout.to_dict()["folds"], strict=True):
        assert fold["z_mean"] == -ref["z_mean"] and fold["rmse_m"] == ref["rmse_m"]
    assert block["verdict"] == heldout.verdict() and block["coverage_95"] < 0.9
    assert any("95 %" in v and "too small" in v for v in block["verdict"])
    assert block["map_coverage_95"] == heldout.pooled["map_coverage_95"] < 0.9
    as_json = json.loads(certificate_json(cert_heldout))["heldout_calibration"]
    assert heldout_block(heldout.to_dict()) == block == as_json
    assert heldout_block(as_json) == block  # the block re-reads itself
    with pytest.raises(InputError, match="heldout"):
        heldout_block({"pooled": {"n": 3}})
    with pytest.raises(InputError, match="heldout"):
        certify(None, None, heldout=42)  # checked before any work


def test_report_draws_heldout_curve_and_verdict(demo, cert_heldout, tmp_path):
    from markupsafe import escape

    product = demo.maps["gp_satellite"]
    path = write_report(tmp_path / "h.html", product=product, certificate=cert_heldout)
    page = _parse(path)
    assert [i["alt"] for i in page.imgs] == [
        "Elevation",
        "Uncertainty",
        "Held-out calibration",
        "Checkpoint errors",
    ]
    html = path.read_text(encoding="utf-8")
    block = cert_heldout["heldout_calibration"]
    assert '<div class="warn" id="heldout-verdict">' in html
    assert all(str(escape(v)) in html for v in block["verdict"])
    assert html.count('<tr><td class="num">') >= block["n_folds"]  # per-fold rows
    again = write_report(tmp_path / "h2.html", product=product, certificate=cert_heldout)
    assert again.read_bytes() == path.read_bytes()  # deterministic
    # whether the held-out elevations came from local planes, and why, is stated in words
    assert str(escape(block["local_fit_rule"])) in html
    assert block["local_fit_rule"].startswith(("used: ", "not used: "))
    full = write_report(
        tmp_path / "f.html", product=product, certificate=cert_heldout, truth=demo.truth
    )
    assert len(_parse(full).imgs) == 6  # + error and truth calibration


def test_report_says_when_heldout_coverage_is_nominal(demo, cert_heldout, tmp_path):
    from toolkit.certify import heldout_block

    good = dict(
        cert_heldout["heldout_calibration"],
        coverage_68=0.70,
        coverage_95=0.94,
        map_coverage_68=0.69,
        map_coverage_95=0.95,
        map_coverage_68_interval=[0.6, 0.75],
        map_coverage_95_interval=[0.9, 0.97],
        map_beyond_reach=0.0,  # every cell within the check's reach
    )
    cert = dict(cert_heldout, heldout_calibration=heldout_block(good))
    assert cert["heldout_calibration"]["verdict"] == []
    html = write_report(
        tmp_path / "g.html", product=demo.maps["gp_satellite"], certificate=cert
    ).read_text(encoding="utf-8")
    assert 'class="warn" id="heldout-verdict"' not in html
    assert '<p class="pass" id="heldout-verdict">' in html and "within 5 percentage" in html


def test_report_says_where_the_heldout_check_cannot_reach(demo, cert_heldout, heldout, tmp_path):
    # The fixture's survey leaves a fifth of its 30 x 30 map farther from the samples than
    # 99 % of the held-out samples lay from their folds' data (measured: 20 %, 59 m).
    from toolkit.certify import heldout_block

    block = cert_heldout["heldout_calibration"]
    share, reach = heldout.pooled["map_beyond_reach"], heldout.pooled["heldout_reach_m"]
    assert block["map_beyond_reach"] == share and block["heldout_reach_m"] == reach
    # by hand: the held-out samples' distances to their folds' data, and the map's cells'
    from scipy.spatial import cKDTree

    xy, fold = demo.samples.xy, heldout.fold
    d = [cKDTree(xy[fold != f]).query(p)[0] for p, f in zip(xy, fold, strict=True)]
    assert reach == pytest.approx(np.quantile(d, 0.99))
    assert share > 0.05
    said = [v for v in block["verdict"] if "cannot vouch" in v]
    assert len(said) == 1 and f"{100 * share:.0f} % of the map" in said[0]
    near = heldout_block(dict(block, map_beyond_reach=0.05))  # at the threshold: silent
    assert not [v for v in near["verdict"] if "cannot vouch" in v]
    html = write_report(
        tmp_path / "r.html", product=demo.maps["gp_satellite"], certificate=cert_heldout
    ).read_text(encoding="utf-8")
    assert "cannot vouch for the 1-sigma there" in html
