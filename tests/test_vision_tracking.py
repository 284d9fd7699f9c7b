"""factorgraph.vision front-end: motion prediction by hand, tracks against the renderer's
ground truth, counted rejections and survival of bad frames."""

import math

import numpy as np
import pytest

from factorgraph.sensors import CameraModel, SensorSuite
from factorgraph.simulate import simulate_traverse
from factorgraph.vision import (
    SCENES,
    TrackParams,
    predict_motion,
    render_frames,
    track_features,
    track_truth,
    vision_sensors,
)
from terrain.errors import InputError
from terrain.synthetic import default_site

CAM = CameraModel(
    width_px=320,
    height_px=240,
    fx_px=300.0,
    fy_px=300.0,
    cx_px=160.0,
    cy_px=120.0,
    height_m=1.5,
    pitch_deg=10.0,
    range_max_m=20.0,
)


@pytest.fixture(scope="module")
def rendered():
    """12 keyframes, 2 m apart, over the default site in sun (small frames: fast)."""
    dem = default_site(2.0)
    x, y = dem.x.values, dem.y.values
    wp = np.array([[x[40], y[150]], [x[40] + 24.0, y[150] + 2.0]])
    sensors = vision_sensors(SensorSuite(keyframe_dt_s=2.0), CAM)
    log = simulate_traverse(dem, wp, sensors, seed=4)
    ren, frames = render_frames(log, dem, SCENES["sunny_snow"])
    return log, ren, list(frames)


def test_predict_motion_matches_exact_projection_on_flat_ground():
    # a ground point 8 m ahead, 1 m left, seen before and after a 2 m step with a 3 deg turn
    P_b = np.array([8.0, 1.0, 0.0])
    bTc = CAM.body_T_camera()
    R_bc, c_b = bTc[:3, :3], bTc[:3, 3]

    def project(P):
        pc = R_bc.T @ (P - c_b)
        return np.array(
            [CAM.fx_px * pc[0] / pc[2] + CAM.cx_px, CAM.fy_px * pc[1] / pc[2] + CAM.cy_px]
        )

    yaw = math.radians(3.0)
    step = np.array([0.0, 0.0, yaw, 2.0, 0.1, 0.0])
    Rz = np.array(
        [[math.cos(yaw), -math.sin(yaw), 0], [math.sin(yaw), math.cos(yaw), 0], [0, 0, 1]]
    )
    P_b1 = Rz.T @ (P_b - step[3:])  # the point in the next body frame, by hand
    uv0, uv1 = project(P_b), project(P_b1)
    pred, ok = predict_motion(uv0[None], CAM, step)
    assert ok[0] and pred[0] == pytest.approx(uv1, abs=1e-6)
    same, _ = predict_motion(uv0[None], CAM, np.zeros(6))
    assert same[0] == pytest.approx(uv0, abs=1e-9)


def test_sift_tracks_match_ground_truth(rendered):
    log, ren, frames = rendered
    tr = track_features(frames, CAM, TrackParams(), odometry=log.odometry)
    xyz, err = track_truth(ren, tr, ren.poses)
    e = err[np.isfinite(err) & (err > 0)]
    assert tr.n_tracks >= 20
    assert np.median(e) < 1.0  # px: kept tracks against the renderer's 3-D points
    assert np.mean(e > 4.0) < 0.05
    # every track has >= 3 views and is contiguous (the localizer's contract)
    for lid in np.unique(tr.landmark_id):
        ks = np.sort(tr.k[tr.landmark_id == lid])
        assert ks.size >= 3 and np.all(np.diff(ks) == 1)
    t = tr.table()
    assert set(t) == {"k", "landmark_id", "u_px", "v_px"}
    assert (t["u_px"] >= 0).all() and (t["u_px"] < CAM.width_px).all()
    # same frames, same bytes
    tr2 = track_features(frames, CAM, TrackParams(), odometry=log.odometry)
    assert np.array_equal(tr.uv, tr2.uv) and np.array_equal(tr.landmark_id, tr2.landmark_id)


def test_bad_frames_are_counted_and_survived(rendered):
    log, _, frames = rendered
    imgs = [f for _, f in frames]
    seq = [
        (0, imgs[0]),
        (1, imgs[1]),
        (2, imgs[2]),
        (3, None),  # missing
        (4, np.full_like(imgs[4], 128)),  # blank: no features
        (5, imgs[5][:100]),  # wrong size
        (6, imgs[6]),
        (7, imgs[7]),
        (8, imgs[8]),
        (10, imgs[10]),  # 9 absent from the stream
    ]
    tr = track_features(seq, CAM, TrackParams(), odometry=log.odometry)
    c = tr.counts
    assert c["frame_missing"] == 2 and c["frame_wrong_size"] == 1
    assert c["frame_without_features"] == 1
    assert set(np.unique(tr.k)) <= {0, 1, 2, 6, 7, 8}
    for lid in np.unique(tr.landmark_id):  # no track bridges a gap
        ks = np.sort(tr.k[tr.landmark_id == lid])
        assert np.all(np.diff(ks) == 1)


@pytest.mark.parametrize("detector", ["orb", "akaze", "klt"])
def test_other_detectors_give_valid_tracks(rendered, detector):
    log, _, frames = rendered
    tr = track_features(frames[:6], CAM, TrackParams(detector=detector, clahe=True), log.odometry)
    assert len(tr.per_frame) == 6 and all(p["features"] > 0 for p in tr.per_frame)
    for lid in np.unique(tr.landmark_id):
        assert np.sum(tr.landmark_id == lid) >= 3
    rejected = sum(v for k, v in tr.counts.items() if k != "lost")
    assert rejected > 0  # every rejection is counted somewhere


@pytest.mark.parametrize(
    "kwargs", [{"detector": "surf"}, {"ratio": 1.5}, {"ransac_px": 0.0}, {"min_track_length": 1}]
)
def test_params_reject_bad_values(kwargs):
    with pytest.raises(InputError):
        TrackParams(**kwargs)


def test_no_usable_frame_is_an_input_error():
    with pytest.raises(InputError):
        track_features([np.zeros((10, 10), np.uint8)], CAM)
    with pytest.raises(InputError):
        CameraModel(fx_px=-300.0)
    with pytest.raises(InputError):
        CameraModel(cx_px=900.0)
