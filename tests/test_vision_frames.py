"""Frames on disk: PNG + timestamps round trip through OpenCV, skips counted by reason."""

import numpy as np
import pytest

from factorgraph.sensors import CameraModel
from factorgraph.vision import read_frames, write_frames
from terrain.errors import InputError

CAM = CameraModel(width_px=64, height_px=48, fx_px=60.0, fy_px=60.0, cx_px=32.0, cy_px=24.0)


def frames(n, seed=0):
    rng = np.random.default_rng(seed)
    return [(k, rng.integers(0, 256, (48, 64), dtype=np.uint8)) for k in range(n)]


def test_round_trip_is_lossless_and_streams(tmp_path):
    src = frames(5)
    t = np.arange(5) * 2.0
    passed = list(write_frames(tmp_path, iter(src), t))
    assert [k for k, _ in passed] == list(range(5))
    got = list(read_frames(tmp_path, t, CAM))
    for (k, a), (j, b) in zip(src, got, strict=True):
        assert k == j and b is not None and np.array_equal(a, b)
    assert not list(tmp_path.glob(".*"))  # no temporary file left behind


def test_skips_are_counted_by_reason(tmp_path):
    t = np.arange(6) * 2.0
    list(write_frames(tmp_path, iter(frames(6)), t))
    (tmp_path / "frame_000001.png").unlink()  # missing
    (tmp_path / "frame_000002.png").write_bytes(b"not a png")  # unreadable
    import cv2

    cv2.imwrite(str(tmp_path / "frame_000003.png"), np.zeros((10, 10), np.uint8))  # wrong size
    table = (tmp_path / "timestamps.csv").read_text().splitlines()
    table = [line for line in table if not line.startswith("4,")]  # keyframe 4 has no frame
    table.append("9,7.1,frame_000005.png")  # 7.1 s: no keyframe within 0.5 s
    (tmp_path / "timestamps.csv").write_text("\n".join(table) + "\n")
    folder = read_frames(tmp_path, t, CAM)
    got = dict(folder)
    assert [k for k, v in got.items() if v is not None] == [0, 5]
    s = folder.skipped
    assert s["missing_file"] == 1 and s["unreadable"] == 1 and s["wrong_size"] == 1
    assert s["keyframe_without_frame"] == 1 and s["no_matching_keyframe"] == 1


def test_frames_match_keyframes_by_time_not_name(tmp_path):
    import cv2

    img = frames(1)[0][1]
    cv2.imwrite(str(tmp_path / "IMG_7.png"), img)
    (tmp_path / "timestamps.csv").write_text("t_s,file\n4.05,IMG_7.png\n")
    got = dict(read_frames(tmp_path, np.arange(4) * 2.0, CAM))  # 0, 2, 4, 6 s
    assert got[2] is not None and np.array_equal(got[2], img)
    assert got[0] is None and got[1] is None and got[3] is None


def test_missing_table_or_columns_are_input_errors(tmp_path):
    with pytest.raises(InputError, match="timestamps.csv"):
        read_frames(tmp_path, np.arange(3.0))
    (tmp_path / "timestamps.csv").write_text("time,name\n0,a.png\n")
    with pytest.raises(InputError, match="columns"):
        read_frames(tmp_path, np.arange(3.0))


def test_frames_on_another_clock_are_an_input_error_naming_both_ranges(tmp_path):
    """Frame times in UTC beside keyframes on the rover clock match nothing: one clear error
    (both time ranges, the fix), not a front-end that finds 'no usable frame'."""
    t = np.arange(4) * 2.0
    list(write_frames(tmp_path, iter(frames(4)), t))
    rows = (tmp_path / "timestamps.csv").read_text().splitlines()
    shifted = [rows[0]] + [
        ",".join([k, str(float(ts) + 1.78e9), f]) for k, ts, f in (r.split(",") for r in rows[1:])
    ]
    (tmp_path / "timestamps.csv").write_text("\n".join(shifted) + "\n")
    with pytest.raises(InputError, match="t_s") as err:
        read_frames(tmp_path, t, CAM)
    msg = str(err.value)
    assert "4 frames at 1780000000.000-1780000006.000 s" in msg and "0.000-6.000 s" in msg
    assert "clock_offset_s" in msg


def test_a_sequence_without_a_usable_frame_names_the_skips():
    from collections import Counter

    from factorgraph.vision import track_features
    from factorgraph.vision.camera_frames import ImageFolder

    folder = ImageFolder({}, 3, CAM, Counter())
    with pytest.raises(InputError, match="keyframe_without_frame") as err:
        track_features(folder, CAM, reuse=False)
    assert "64 x 48 px" in str(err.value)


def test_a_video_rate_camera_gives_each_keyframe_its_nearest_frame(tmp_path):
    """Frames at 5 Hz beside keyframes every 2 s: the frame nearest each keyframe's time is
    its view (not the first within the tolerance, 0.4 s and ~0.4 m of driving away)."""
    import cv2

    t = np.arange(3) * 2.0  # keyframes 0, 2, 4 s; tolerance 0.5 s
    rows = ["t_s,file"]
    for i, ts in enumerate(np.arange(-0.4, 4.5, 0.2)):
        cv2.imwrite(str(tmp_path / f"v{i:03d}.png"), np.full((48, 64), i, np.uint8))
        rows.append(f"{ts:.1f},v{i:03d}.png")
    (tmp_path / "timestamps.csv").write_text("\n".join(rows) + "\n")
    folder = read_frames(tmp_path, t, CAM)
    assert {k: p.name for k, p in folder.files.items()} == {
        0: "v002.png",
        1: "v012.png",
        2: "v022.png",
    }
    # 5 frames within 0.5 s of each keyframe: 1 used, 4 duplicates; 10 frames between them
    assert folder.skipped["duplicate_keyframe"] == 12
    assert folder.skipped["no_matching_keyframe"] == 10


def test_sixteen_bit_frames_are_scaled_by_their_data_depth(tmp_path):
    """A 12-bit camera's frames in 16-bit PNGs (0-4095): divided by 16 (OpenCV's own 8-bit
    read divides by 256 and leaves them nearly black); the depth only grows."""
    import cv2

    rng = np.random.default_rng(0)
    twelve = rng.integers(0, 4096, (48, 64)).astype(np.uint16)
    dark = (twelve // 8).astype(np.uint16)  # a dark frame of the same camera: max < 1024
    fourteen = rng.integers(0, 16384, (48, 64)).astype(np.uint16)
    for name, img in (("a", twelve), ("b", dark), ("c", fourteen)):
        cv2.imwrite(str(tmp_path / f"{name}.png"), img)
    (tmp_path / "timestamps.csv").write_text("t_s,file\n0,a.png\n2,b.png\n4,c.png\n")
    got = dict(read_frames(tmp_path, np.arange(3) * 2.0, CAM))
    assert got[0].dtype == np.uint8 and np.array_equal(got[0], (twelve >> 4).astype(np.uint8))
    assert np.array_equal(got[1], (dark >> 4).astype(np.uint8))  # not re-stretched to 10 bits
    assert np.array_equal(got[2], (fourteen >> 6).astype(np.uint8))
    assert cv2.imread(str(tmp_path / "a.png"), cv2.IMREAD_GRAYSCALE).max() <= 15
