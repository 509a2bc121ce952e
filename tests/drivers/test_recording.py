"""Camera recording and replay: round trip, loop, and errors that name the broken file."""

from __future__ import annotations

import json

import numpy as np
import pytest

from kitchenbot.drivers.camera import Frame
from kitchenbot.drivers.errors import DeviceNotConnectedError, DriverTimeoutError
from kitchenbot.drivers.recording import CaptureRecorder, RecordingError, depth_m_to_mm, depth_mm_to_m
from kitchenbot.drivers.replay_camera import ReplayCamera
from kitchenbot.transforms import from_xyz_rpy

K = np.array([[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]])


def _frame(rng, stamp, h=48, w=64) -> Frame:
    rgb = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    depth = rng.uniform(0.3, 1.5, (h, w)).astype(np.float32)
    depth[0, :5] = 0.0
    depth[1, :5] = np.nan
    return Frame(rgb=rgb, depth=depth, K=K.copy(), stamp=stamp)


def test_depth_conversions():
    mm = np.array([[0, 1, 1234, 65535]], np.uint16)
    m = depth_mm_to_m(mm)
    assert m.dtype == np.float32
    np.testing.assert_allclose(m, [[0.0, 0.001, 1.234, 65.535]], rtol=1e-6)
    back = depth_m_to_mm(np.array([[np.nan, -1.0, 0.0004, 0.0006, 1.2344, np.inf, 70.0]]))
    assert back.dtype == np.uint16
    assert back.tolist() == [[0, 0, 0, 1, 1234, 0, 0]]
    with pytest.raises(ValueError, match="depth"):
        depth_mm_to_m(np.zeros((2, 2, 2), np.uint16))


def test_record_and_replay_round_trip(tmp_path, rng):
    rec = CaptureRecorder(tmp_path / "rec")
    frames = [_frame(rng, 10.0 + i) for i in range(3)]
    poses = [from_xyz_rpy((0.1 * i, 0.2, 0.5), (np.pi, 0.0, 0.1 * i)) for i in range(3)]
    for f, T in zip(frames, poses):
        rec.save(f, T)
    cam = ReplayCamera(tmp_path / "rec")
    cam.connect()
    assert len(cam) == 3
    np.testing.assert_allclose(cam.intrinsics(), K)
    for f, T in zip(frames, poses):
        got = cam.capture()
        np.testing.assert_array_equal(got.rgb, f.rgb)
        expected = np.nan_to_num(f.depth, nan=0.0)
        assert np.max(np.abs(got.depth - expected)) <= 0.0005 + 1e-6  # 1 mm quantisation
        assert got.depth[0, 0] == 0.0 and got.depth[1, 0] == 0.0  # invalid stays 0
        assert got.stamp == f.stamp
        np.testing.assert_allclose(cam.last_T_base_cam, T)
    with pytest.raises(DriverTimeoutError, match="all 3 captures"):
        cam.capture()


def test_loop_and_appending(tmp_path, rng):
    rec = CaptureRecorder(tmp_path)
    rec.save(_frame(rng, 1.0))
    rec2 = CaptureRecorder(tmp_path)  # continues the numbering
    assert rec2.save(_frame(rng, 2.0)).name == "000001.json"
    cam = ReplayCamera(tmp_path, loop=True)
    cam.connect()
    stamps = [cam.capture().stamp for _ in range(5)]
    assert stamps == [1.0, 2.0, 1.0, 2.0, 1.0]
    assert cam.last_T_base_cam is None


def test_missing_folder_is_named(tmp_path):
    cam = ReplayCamera(tmp_path / "nope")
    with pytest.raises(DeviceNotConnectedError, match=r"nope: recording folder does not exist"):
        cam.connect()
    (tmp_path / "empty").mkdir()
    with pytest.raises(DeviceNotConnectedError, match="no captures"):
        ReplayCamera(tmp_path / "empty").connect()


def test_broken_files_are_named(tmp_path, rng):
    rec = CaptureRecorder(tmp_path)
    rec.save(_frame(rng, 1.0))
    rec.save(_frame(rng, 2.0))
    (tmp_path / "000001_depth.png").unlink()
    cam = ReplayCamera(tmp_path)
    cam.connect()
    cam.capture()
    with pytest.raises(RecordingError, match=r"000001_depth\.png: missing"):
        cam.capture()

    (tmp_path / "000000.json").write_text("{not json")
    with pytest.raises(RecordingError, match=r"000000\.json: not valid JSON"):
        ReplayCamera(tmp_path).connect()

    meta = {"rgb": "000000_rgb.png", "depth": "000000_depth.png", "K": [[1, 2]], "stamp": 0.0}
    (tmp_path / "000000.json").write_text(json.dumps(meta))
    with pytest.raises(RecordingError, match="'K' must be a finite 3x3"):
        ReplayCamera(tmp_path).connect()

    # an 8-bit image where 16-bit depth is expected
    import cv2

    meta["K"] = K.tolist()
    (tmp_path / "000000.json").write_text(json.dumps(meta))
    cv2.imwrite(str(tmp_path / "000000_depth.png"), np.zeros((48, 64), np.uint8))
    with pytest.raises(RecordingError, match="000000_depth.png: expected a single-channel 16-bit PNG"):
        ReplayCamera(tmp_path).connect()


def test_recording_camera_records_what_it_passes_through(tmp_path, rng):
    from kitchenbot.drivers.recording import RecordingCamera

    src = CaptureRecorder(tmp_path / "src")
    for i in range(2):
        src.save(_frame(rng, float(i)))
    poses = iter([np.eye(4), from_xyz_rpy((0.1, 0, 0), (0, 0, 0))])
    cam = RecordingCamera(ReplayCamera(tmp_path / "src"), tmp_path / "copy", pose_fn=lambda: next(poses))
    cam.connect()
    passed = [cam.capture() for _ in range(2)]
    replay = ReplayCamera(tmp_path / "copy")
    replay.connect()
    for f in passed:
        got = replay.capture()
        np.testing.assert_array_equal(got.rgb, f.rgb)
        np.testing.assert_array_equal(got.depth, f.depth)  # already mm-quantised: exact
    np.testing.assert_allclose(replay.last_T_base_cam[:3, 3], [0.1, 0, 0])
