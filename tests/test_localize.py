"""Localization: iSAM2 fusion, exact landmark marginals, selection, logs and bad input."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from factorgraph.localize import LocalizeParams, localize
from factorgraph.log import MeasurementLog, read_log, write_log
from factorgraph.select import select_landmarks
from factorgraph.sensors import CameraModel, GPSModel, SensorSuite
from factorgraph.simulate import simulate_traverse
from terrain.errors import InputError
from terrain.synthetic import default_site

W, N = 526000.0, 6475600.0


@pytest.fixture(scope="module")
def dem():
    return default_site(2.0)


@pytest.fixture(scope="module")
def short_log(dem):
    """A 120 m straight traverse (121 keyframes, ~5k feature observations)."""
    return simulate_traverse(dem, np.array([[W + 20, N - 75], [W + 140, N - 75]]), seed=3)


@pytest.fixture(scope="module")
def short_result(short_log):
    return localize(short_log)


def test_marginals_match_gtsam_marginals(short_result):
    """Reference: gtsam.Marginals (batch Bayes tree) at the same final estimate."""
    import gtsam

    res = short_result
    m = gtsam.Marginals(res.graph, res.estimate)
    L, X = gtsam.symbol_shorthand.L, gtsam.symbol_shorthand.X
    for j in np.linspace(0, res.n_landmarks - 1, 6).astype(int):
        ref = m.marginalCovariance(L(int(res.landmark_id[j])))
        np.testing.assert_allclose(res.landmark_cov[j], ref, rtol=1e-3, atol=1e-4)
    for k in (0, 60, res.log.n_keyframes - 1):
        c = m.marginalCovariance(X(k))[3:, 3:]  # body-frame translation block
        R = res.keyframe_R[k]
        np.testing.assert_allclose(res.pose_cov_xyz[k], R @ c @ R.T, rtol=1e-3, atol=1e-4)


def test_relative_covariance_removes_shared_offset(short_result):
    res = short_result
    assert (np.linalg.eigvalsh(res.landmark_cov_relative)[:, 0] > -1e-9).all()  # PSD
    # a 120 s traverse cannot average the GPS bias: the shared offset dominates (sigma_b 2.5 m)
    assert np.sqrt(np.diag(res.shared_offset_cov)).min() > 1.0
    # removing the shared translation helps; over 120 m the tilt and yaw of the whole map stay
    # uncertain too (GPS cannot fix them on a short baseline), so the relative part stays large
    full, rel = res.landmark_cov[:, 2, 2], res.landmark_cov_relative[:, 2, 2]
    assert np.median(rel) < 0.5 * np.median(full)


def test_landmarks_and_poses_are_honest(short_result):
    """True positions inside the stated covariance: NEES near its dof (3), not ~260."""
    res = short_result
    err = res.landmark_xyz - res.true_landmarks()
    nees = np.einsum("ni,nij,nj->n", err, np.linalg.inv(res.landmark_cov), err)
    assert res.n_landmarks > 100
    assert 0.5 < nees.mean() < 8.0  # one traverse = one draw of the shared offset
    assert res.step_s.size == res.log.n_keyframes and np.isfinite(res.keyframe_xyz).all()


def test_select_landmarks_rules_and_eq7(short_result):
    res = short_result
    # 120 m of GPS leave the map's yaw uncertain (~1 m at its ends): loosen the paper's 0.5 m
    sel = select_landmarks(res, max_sigma=2.0)
    c = sel.counts
    assert c["kept"] + c["sigma_above_max"] + c["first_seen_too_close"] == c["in_graph"]
    assert sel.samples.n == c["kept"] - sel.samples.n_merged
    kept = sel.table["kept"]
    assert (sel.table["sigma_max_m"][kept] <= 2.0).all() and c["kept"] > 50
    assert (sel.table["first_seen_distance_m"][kept] > 5.0).all()
    # Eq 7: var(z) is the zz entry of the (relative) covariance
    np.testing.assert_allclose(
        sel.table["z_std_m"] ** 2, res.landmark_cov_relative[:, 2, 2], rtol=1e-12
    )
    stricter = select_landmarks(res, max_sigma=1.0)
    assert stricter.counts["kept"] < c["kept"]
    with pytest.raises(InputError, match="no landmark passed"):
        select_landmarks(res, max_sigma=0.01)
    slope = select_landmarks(res, max_sigma=2.0, variance="slope")
    assert slope.counts["kept"] == c["kept"] and np.isfinite(slope.samples.z_var).all()
    # samples are in the log's projected CRS
    assert sel.samples.xy[:, 0].min() > W and sel.samples.xy[:, 1].max() < N


def test_same_seed_same_estimate(dem, short_log, short_result):
    again = simulate_traverse(dem, np.array([[W + 20, N - 75], [W + 140, N - 75]]), seed=3)
    np.testing.assert_array_equal(again.obs_uv, short_log.obs_uv)
    res = localize(again)
    np.testing.assert_array_equal(res.keyframe_xyz, short_result.keyframe_xyz)
    np.testing.assert_array_equal(res.landmark_cov, short_result.landmark_cov)


@pytest.mark.parametrize("fmt", ["csv", "parquet"])
def test_log_round_trip(tmp_path, short_log, fmt):
    write_log(short_log, tmp_path / "log", fmt=fmt)
    back = read_log(tmp_path / "log")
    np.testing.assert_allclose(back.obs_uv, short_log.obs_uv, rtol=1e-8)
    np.testing.assert_allclose(back.truth["xyz"], short_log.truth["xyz"], rtol=1e-8)
    np.testing.assert_array_equal(back.obs_id, short_log.obs_id)
    np.testing.assert_allclose(back.tilt_up, short_log.tilt_up, rtol=1e-8)
    assert back.sensors == short_log.sensors and back.crs == short_log.crs
    assert not list((tmp_path / "log").glob("*.tmp"))


def test_gps_outage_is_survived(dem):
    """A 60 s outage in a 200 s traverse: the run ends, the error grows gracefully."""
    gps = GPSModel(dropouts=((70.0, 130.0),))
    sensors = SensorSuite(gps=gps, camera=CameraModel(texture_density_per_m2=0.03))
    log = simulate_traverse(dem, np.array([[W + 20, N - 300], [W + 220, N - 300]]), sensors, 5)
    assert log.gps_k.size < log.n_keyframes - 55
    res = localize(log)
    err = np.linalg.norm((res.keyframe_xyz - log.truth["xyz"])[:, :2], axis=1)
    assert np.isfinite(err).all() and err.max() < 10.0


def _bad(log: MeasurementLog, **change):
    fields = {f.name: getattr(log, f.name) for f in dataclasses.fields(log)}
    fields.update(change)
    return MeasurementLog(**fields)


def test_bad_input_names_the_field(dem, short_log):
    t = short_log.t.copy()
    t[5] = t[4]
    with pytest.raises(InputError, match="keyframes.t_s"):
        _bad(short_log, t=t)
    gps = short_log.gps_xyz.copy()
    gps[3, 1] = np.nan
    with pytest.raises(InputError, match="gps.xyz"):
        _bad(short_log, gps_xyz=gps)
    up = short_log.tilt_up.copy()
    up[7] *= 3.0
    with pytest.raises(InputError, match="keyframes.up_x"):
        _bad(short_log, tilt_up=up)
    with pytest.raises(InputError, match="gps.sigma_white_m"):
        GPSModel(sigma_white_m=(2.5, 0.0, 2.5))
    with pytest.raises(InputError, match="camera.cx_px"):
        CameraModel(cx_px=900.0)
    with pytest.raises(InputError, match="camera.fx_px"):
        CameraModel(fx_px=-1.0)
    with pytest.raises(InputError, match="waypoints"):
        simulate_traverse(dem, np.empty((0, 2)))
    with pytest.raises(InputError, match="waypoints"):
        simulate_traverse(dem, np.array([[W + 20, N - 75], [W + 20, N - 75]]))
    with pytest.raises(InputError, match="params.gps_model"):
        LocalizeParams(gps_model="kalman")


def test_outliers_are_absorbed_and_counted(short_log, short_result):
    """Gross feature outliers (3 % of observations moved 40-80 px, 15 tracks replaced by
    random pixels) never end the run: the Huber kernel keeps the trajectory where the clean
    log put it, garbage tracks fail the triangulation gates and are counted."""
    rng = np.random.default_rng(11)
    uv = short_log.obs_uv.copy()
    hit = rng.random(len(uv)) < 0.03
    uv[hit] += rng.choice([-1.0, 1.0], (hit.sum(), 2)) * rng.uniform(40, 80, (hit.sum(), 2))
    garbage = rng.choice(np.unique(short_log.obs_id), 15, replace=False)
    g = np.isin(short_log.obs_id, garbage)
    cam = short_log.sensors.camera
    uv[g] = rng.uniform([0, 0], [cam.width_px, cam.height_px], (g.sum(), 2))
    uv[:, 0] = np.clip(uv[:, 0], 0, cam.width_px - 1)
    uv[:, 1] = np.clip(uv[:, 1], 0, cam.height_px - 1)
    res = localize(_bad(short_log, obs_uv=uv))
    clean = short_result
    shift = np.linalg.norm(res.keyframe_xyz - clean.keyframe_xyz, axis=1)
    assert shift.max() < 0.5, shift.max()
    assert sum(res.dropped.values()) > sum(clean.dropped.values())
    # garbage tracks that did enter the graph are far off, never silently "accurate"
    assert not set(res.landmark_id) >= set(garbage)


def test_elevation_rule_bounds_the_slope_aware_sigma(short_result):
    """rule="elevation": kept <=> slope-aware elevation 1-sigma <= max_sigma (and the
    first-seen rule); that sigma is a^T Sigma a with a = (-dz/dx, -dz/dy, 1) (hand form)."""
    from factorgraph.select import local_slopes

    res = short_result
    s_el = np.median(np.sqrt(res.landmark_cov_relative[:, 2, 2])) * 1.5
    sel = select_landmarks(res, max_sigma=s_el, rule="elevation", variance="slope")
    t = sel.table
    far = res.first_seen_distance_m > 5.0
    np.testing.assert_array_equal(t["kept"], (t["z_std_slope_m"] <= s_el) & far)
    g = local_slopes(res.landmark_xyz)
    a = np.column_stack([-g, np.ones(len(g))])
    hand = np.sqrt(np.einsum("ni,nij,nj->n", a, res.landmark_cov_relative, a))
    np.testing.assert_allclose(t["z_std_slope_m"], hand, rtol=1e-9)
    np.testing.assert_allclose(sel.samples.z_var, t["z_std_slope_m"][t["kept"]] ** 2)
    with pytest.raises(InputError, match="rule"):
        select_landmarks(res, rule="circle")


def test_tilt_fixes_the_elevation_drift(dem):
    """Gravity direction (0.5 deg) against none: pitch no longer random-walks, so the
    trajectory's elevation error shrinks (measured on the default survey: landmark vertical
    RMSE 1.36 -> 0.49 m; here a 300 m L-shaped traverse)."""
    wp = np.array([[W + 20, N - 75], [W + 220, N - 75], [W + 220, N - 175]])
    log = simulate_traverse(dem, wp, seed=2)
    assert log.tilt_up.shape == (log.n_keyframes, 3)
    on, off = localize(log), localize(log, LocalizeParams(use_tilt=False))
    vz = lambda r: np.sqrt(((r.keyframe_xyz - log.truth["xyz"])[:, 2] ** 2).mean())  # noqa: E731
    sz = lambda r: np.median(np.sqrt(r.landmark_cov_relative[:, 2, 2]))  # noqa: E731
    assert vz(on) < vz(off) and sz(on) < 0.7 * sz(off), (vz(on), vz(off), sz(on), sz(off))


def test_grazing_views_on_flat_snow_are_deferred_not_rebuilt(dem):
    """Perfectly flat snow: feature rays from a rover-height camera graze the plane, and views
    of landmarks that lie on or behind the guessed camera at the online linearization point
    made iSAM2's elimination fail (before the guard: 1 rebuild, 4 landmarks dropped as
    ``degenerate_in_graph`` on this seed). The guard (factorgraph/rebuild.py) defers those
    views to the batch refinement instead, counted; no rebuild, no landmark dropped for it.
    Measured on this seed: 891 views deferred, horizontal RMSE 0.38 m (0.38 m before)."""
    flat = dem * 0 + float(dem.mean())
    wp = np.array([[W + 20, N - 60], [W + 140, N - 60], [W + 140, N - 90], [W + 20, N - 90]])
    log = simulate_traverse(flat, wp, seed=2)
    res = localize(log)
    rec = res.refine["isam2_recovery"]
    assert rec["deferred_views"] >= 1 and rec["rebuilds"] == res.n_rebuilds == 0
    assert "degenerate_in_graph" not in res.dropped
    # the deferred views are in the final graph: its projection factors cover >= 99 % of the
    # log's views of the kept landmarks (measured 10,136 of 10,146; without the deferred
    # 891 it would be 91 %; the rest are views of earlier, failed segments)
    gtsam = pytest.importorskip("gtsam")
    proj = sum(
        1
        for i in range(res.graph.size())
        if res.graph.at(i) is not None
        and sorted(chr(gtsam.Symbol(k).chr()) for k in res.graph.at(i).keys()) == ["l", "x"]
    )
    assert proj >= 0.99 * np.isin(log.obs_id, res.landmark_id).sum()
    d = res.keyframe_xyz[:, :2] - log.truth["xyz"][:, :2]
    assert np.sqrt(np.mean(np.sum(d**2, axis=1))) < 1.5  # measured 0.38 m


def test_true_landmarks_match_by_id_and_leave_unknown_ones_nan():
    """Image tracks whose reference ray met the sky have no truth row (attach_tracks drops
    them). The truth is matched by id: before, a missing id took its neighbour's position
    and one past the last raised IndexError (bei's 240 m window, vision_dem)."""
    from types import SimpleNamespace

    from factorgraph.result import LocalizationResult

    truth = {"landmark_id": np.array([0, 1, 3, 4]), "landmark_xyz": np.arange(12.0).reshape(4, 3)}
    res = SimpleNamespace(log=SimpleNamespace(truth=truth), landmark_id=np.array([1, 2, 4, 5]))
    got = LocalizationResult.true_landmarks(res)
    np.testing.assert_array_equal(got[0], [3.0, 4.0, 5.0])  # id 1: the second truth row
    np.testing.assert_array_equal(got[2], [9.0, 10.0, 11.0])  # id 4: the last
    assert np.isnan(got[1]).all() and np.isnan(got[3]).all()  # ids 2 and 5: no truth


def test_marginals_of_adjacent_swaths_match_gtsam_marginals(dem):
    """Two legs 15 m apart: landmarks seen from both couple keyframes a leg apart in time. The
    keyframes are renumbered (reverse Cuthill-McKee) to a narrow band; the marginals still
    equal gtsam.Marginals' (batch Bayes tree at the same estimate)."""
    import gtsam

    path = np.array([[W + 20, N - 300], [W + 120, N - 300], [W + 120, N - 285], [W + 20, N - 285]])
    log = simulate_traverse(dem, path, seed=4)
    res = localize(log, LocalizeParams(refine=False))
    lid = np.asarray(res.landmark_id)
    seen = np.isin(log.obs_id, lid)  # views in the graph span a leg in time ...
    k, j = log.obs_k[seen], log.obs_id[seen]
    span = max(k[j == i].max() - k[j == i].min() for i in np.unique(j))
    assert span > 0.5 * log.n_keyframes
    assert res.bandwidth < 0.4 * span  # ... the band after renumbering, a few local windows
    m = gtsam.Marginals(res.graph, res.estimate)
    L, X = gtsam.symbol_shorthand.L, gtsam.symbol_shorthand.X
    for j in np.linspace(0, lid.size - 1, 8).astype(int):
        ref = m.marginalCovariance(L(int(lid[j])))
        np.testing.assert_allclose(res.landmark_cov[j], ref, rtol=1e-3, atol=1e-4)
    for k in (0, log.n_keyframes // 2, log.n_keyframes - 1):
        c = m.marginalCovariance(X(k))[3:, 3:]
        R = res.keyframe_R[k]
        np.testing.assert_allclose(res.pose_cov_xyz[k], R @ c @ R.T, rtol=1e-3, atol=1e-4)
