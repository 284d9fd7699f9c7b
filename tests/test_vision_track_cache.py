"""Tracks stored beside the frames (``images/tracks.npz``) are reused by the front-end only
for the same frame bytes, camera, parameters, odometry and front-end (track_cache.py)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from factorgraph import SensorSuite
from factorgraph.log import read_log, write_log
from factorgraph.vision import (
    SCENES,
    TrackParams,
    read_frames,
    simulate_images,
    track_features,
    vision_sensors,
)
from factorgraph.vision.track_cache import TRACKS_FILE, inputs_digest, load_tracks
from terrain.errors import InputError
from terrain.synthetic import default_site


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """8 keyframes 2 m apart on the default site, rendered in sun, frames and tracks written."""
    root = tmp_path_factory.mktemp("track_cache")
    dem = default_site(2.0)
    x, y = dem.x.values, dem.y.values
    wp = np.array([[x[40], y[150]], [x[40] + 14.0, y[150] + 2.0]])
    sensors = vision_sensors(SensorSuite(keyframe_dt_s=2.0))
    r = simulate_images(dem, wp, sensors, 0, SCENES["sunny_snow"], images_dir=root / "images")
    write_log(r.log, root / "log")  # the log as glacimap localize reads it (CSV, 9 digits)
    return r, root


def _same(a, b):
    return (
        np.array_equal(a.k, b.k)
        and np.array_equal(a.landmark_id, b.landmark_id)
        and np.array_equal(a.uv, b.uv)
    )


def test_the_log_read_back_reuses_the_stored_tracks_which_equal_a_fresh_tracking(run):
    r, root = run
    assert (root / "images" / TRACKS_FILE).is_file() and r.tracks.n_tracks > 20
    log = read_log(root / "log")  # odometry from the CSV: differs in the 10th digit
    assert not np.array_equal(log.odometry, r.log.odometry)
    cam = log.sensors.camera
    frames = read_frames(root / "images", log.t, cam)
    reused = track_features(frames, cam, odometry=log.odometry)
    assert reused.source.startswith("reused") and _same(reused, r.tracks)
    assert reused.counts == r.tracks.counts
    # the honesty condition: tracking the folder again gives the very same tracks
    fresh = track_features(frames, cam, odometry=log.odometry, reuse=False)
    assert fresh.source == "tracked" and _same(fresh, r.tracks)


def test_any_changed_input_changes_the_digest(run, tmp_path):
    r, root = run
    log = read_log(root / "log")
    cam = log.sensors.camera
    frames = read_frames(root / "images", log.t, cam)
    base = inputs_digest(frames, cam, TrackParams(), log.odometry)
    assert base == inputs_digest(frames, cam, TrackParams(), r.log.odometry)  # 9 digits
    odo = log.odometry.copy()
    odo[3, 3] += 1e-6
    changed = [
        inputs_digest(frames, cam, TrackParams(clahe=True), log.odometry),
        inputs_digest(frames, dataclasses.replace(cam, fx_px=601.0), TrackParams(), odo),
        inputs_digest(frames, cam, TrackParams(), odo),
        inputs_digest(frames, cam, TrackParams(), None),
    ]
    files = dict(frames.files)
    files[7] = tmp_path / "absent.png"
    frames.files, saved = files, frames.files
    changed.append(inputs_digest(frames, cam, TrackParams(), log.odometry))
    frames.files = saved
    assert len({base, *changed}) == 1 + len(changed)


def test_a_camera_read_back_from_camera_yaml_hashes_as_the_one_tracked(run, tmp_path):
    """The field folder's camera.yaml gives the same camera with float numbers (640.0 for
    640): the stored tracks must still be found (the field route reuses them)."""
    from factorgraph.field.intrinsics import read_camera, write_camera

    r, root = run
    log = read_log(root / "log")
    cam = log.sensors.camera
    frames = read_frames(root / "images", log.t, cam)
    write_camera(tmp_path / "camera.yaml", cam)
    back, dist = read_camera(tmp_path / "camera.yaml", cam)
    assert dist is None
    as_floats = dataclasses.replace(
        cam, **{f.name: float(getattr(cam, f.name)) for f in dataclasses.fields(cam)}
    )
    base = inputs_digest(frames, cam, TrackParams(), log.odometry)
    assert inputs_digest(frames, back, TrackParams(), log.odometry) == base
    assert inputs_digest(frames, as_floats, TrackParams(), log.odometry) == base


def test_a_changed_frame_or_a_broken_file_is_tracked_again(run, tmp_path):
    import shutil

    import cv2

    r, root = run
    log = read_log(root / "log")
    cam = log.sensors.camera
    images = tmp_path / "images"
    shutil.copytree(root / "images", images)
    img = cv2.imread(str(images / "frame_000004.png"), cv2.IMREAD_GRAYSCALE)
    img[300, 320] ^= 1  # one grey level of one pixel
    cv2.imwrite(str(images / "frame_000004.png"), img)
    frames = read_frames(images, log.t, cam)
    assert load_tracks(frames, cam, TrackParams(), log.odometry) == (None, "inputs differ")
    tr = track_features(frames, cam, odometry=log.odometry)
    assert tr.source == "tracked (stored tracks: inputs differ)"
    (images / TRACKS_FILE).write_bytes(b"PK\x03\x04 truncated")
    assert load_tracks(frames, cam, TrackParams(), log.odometry) == (None, "unreadable")
    (images / TRACKS_FILE).unlink()
    assert load_tracks(frames, cam, TrackParams(), log.odometry) == (None, "no stored tracks")


def test_reused_tracks_carry_the_frame_skips_counted_when_they_were_made(run, tmp_path):
    """Skips counted while frames are read (an unreadable file) were 0 when the stored
    tracks were reused, since no frame is read then: the report said nothing was skipped."""
    import shutil

    from factorgraph.vision.track_cache import save_tracks

    r, root = run
    log = read_log(root / "log")
    cam = log.sensors.camera
    images = tmp_path / "images"
    shutil.copytree(root / "images", images)
    (images / "frame_000005.png").write_bytes(b"not a PNG")
    first = read_frames(images, log.t, cam)
    tr = track_features(first, cam, odometry=log.odometry)
    assert tr.source.startswith("tracked") and first.skipped["unreadable"] == 1
    save_tracks(images, tr, first, cam, log.odometry)
    again = read_frames(images, log.t, cam)
    reused = track_features(again, cam, odometry=log.odometry)
    assert reused.source.startswith("reused") and _same(reused, tr)
    assert dict(again.skipped) == dict(first.skipped)  # {"unreadable": 1}, as when tracked


def test_a_distorting_lens_is_undistorted_inside_the_front_end(run, tmp_path):
    """Frames through a barrel lens (k1 = -0.3: the image corner is 76 px out of the pinhole
    frame), tracked with the lens's coefficients: the tracks are in the pinhole camera's
    pixels (against the renderer's truth as on the undistorted frames), the RANSAC sees
    pinhole geometry, and the coefficients are part of the stored tracks' digest.
    Measured on 20 keyframes (docs/field-format.md): 544 tracks against 505 when the
    tracks were undistorted after a pinhole RANSAC on the recorded pixels."""
    import cv2

    from factorgraph.vision import track_truth

    r, root = run
    log = read_log(root / "log")
    cam = log.sensors.camera
    dist = np.array([-0.3, 0.0225, 0.0, 0.0, 0.0])
    K = np.array([[cam.fx_px, 0, cam.cx_px], [0, cam.fy_px, cam.cy_px], [0, 0, 1.0]])
    W, H = int(cam.width_px), int(cam.height_px)
    uu, vv = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    grid = np.stack([uu, vv], -1).reshape(-1, 1, 2)
    und = cv2.undistortPoints(grid, K, dist, P=K).reshape(H, W, 2).astype(np.float32)
    lens = tmp_path / "lens"
    lens.mkdir()
    (lens / "timestamps.csv").write_text((root / "images" / "timestamps.csv").read_text())
    for p in sorted((root / "images").glob("frame_*.png")):
        img = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
        cv2.imwrite(str(lens / p.name), cv2.remap(img, und[..., 0], und[..., 1], cv2.INTER_LINEAR))
    frames = read_frames(lens, log.t, cam)
    tr = track_features(frames, cam, odometry=log.odometry, reuse=False, distortion=dist)
    _, err = track_truth(r.renderer, tr, r.renderer.poses)
    _, err0 = track_truth(r.renderer, r.tracks, r.renderer.poses)
    ok, ok0 = np.isfinite(err), np.isfinite(err0)
    assert tr.n_tracks >= 0.8 * r.tracks.n_tracks
    assert np.median(err[ok]) < 1.0 and np.median(err[ok]) < np.median(err0[ok0]) + 0.3
    base = inputs_digest(frames, cam, TrackParams(), log.odometry)
    assert inputs_digest(frames, cam, TrackParams(), log.odometry, dist) != base
    with pytest.raises(InputError, match="klt"):
        track_features(frames, cam, TrackParams(detector="klt"), distortion=dist)
    with pytest.raises(InputError, match="distortion"):
        track_features(frames, cam, distortion=[0.1, 0.2])
