"""OakDCamera without a device: the no-device error, the conversions, and capture() on real depthai message
objects (ImgFrame/MessageGroup) sent through a host-side depthai MessageQueue."""

from __future__ import annotations

import datetime
import time

import numpy as np
import pytest

dai = pytest.importorskip("depthai")

from kitchenbot.drivers.errors import DeviceNotConnectedError, DriverTimeoutError  # noqa: E402
from kitchenbot.drivers.oakd_camera import OakDCamera, frame_from_messages  # noqa: E402

K = np.array([[450.0, 0, 320.0], [0, 450.0, 240.0], [0, 0, 1]])


def test_no_device_gives_a_clear_error_quickly():
    if dai.Device.getAllAvailableDevices():
        pytest.skip("an OAK device is attached")
    cam = OakDCamera()
    t0 = time.monotonic()
    with pytest.raises(DeviceNotConnectedError, match="OAK-D camera: no device found"):
        cam.connect()
    assert time.monotonic() - t0 < 5.0  # not depthai's 10 s implicit-device search
    assert not cam.is_connected
    with pytest.raises(DeviceNotConnectedError, match="not connected"):
        cam.capture()


def test_frame_conversion_mm_to_metres_and_bgr_to_rgb():
    bgr = np.zeros((4, 6, 3), np.uint8)
    bgr[..., 0] = 200  # blue
    depth = np.array([[0, 1000, 65535, 1, 2, 3]] * 4, np.uint16)
    f = frame_from_messages(bgr, depth, K, 3.25)
    assert f.rgb[0, 0].tolist() == [0, 0, 200]
    assert f.depth.dtype == np.float32
    np.testing.assert_allclose(f.depth[0, :3], [0.0, 1.0, 65.535], rtol=1e-6)
    assert f.stamp == 3.25 and f.K.dtype == np.float64


def test_depth_of_another_size_is_resized_without_blending():
    bgr = np.zeros((4, 4, 3), np.uint8)
    depth = np.array([[0, 1000], [2000, 0]], np.uint16)
    f = frame_from_messages(bgr, depth, K, 0.0)
    assert f.depth.shape == (4, 4)
    assert set(np.unique(f.depth).tolist()) == {0.0, 1.0, 2.0}


def test_bad_message_types_are_refused():
    from kitchenbot.drivers.errors import DriverError

    with pytest.raises(DriverError, match="uint16 depth"):
        frame_from_messages(np.zeros((4, 4, 3), np.uint8), np.zeros((4, 4), np.float32), K, 0.0)


def _group(rgb_bgr: np.ndarray, depth_mm: np.ndarray, stamp_s: float):
    rgb = dai.ImgFrame()
    rgb.setCvFrame(rgb_bgr, dai.ImgFrame.Type.BGR888i)
    depth = dai.ImgFrame()
    depth.setCvFrame(depth_mm, dai.ImgFrame.Type.RAW16)
    for m in (rgb, depth):
        m.setTimestamp(datetime.timedelta(seconds=stamp_s))
    g = dai.MessageGroup()
    g["rgb"], g["depth"] = rgb, depth
    return g


def test_capture_reads_synchronised_groups_and_times_out(rng):
    cam = OakDCamera(width=64, height=48)
    # What connect() sets up on a device: the Sync node's host queue and K at the requested size.
    cam._queue, cam._K = dai.MessageQueue("sync", 4, False), K
    bgr = rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)
    depth = rng.integers(0, 4000, (48, 64)).astype(np.uint16)
    cam._queue.send(_group(bgr, depth, 7.5))
    f = cam.capture(timeout=0.5)
    np.testing.assert_array_equal(f.rgb, bgr[:, :, ::-1])
    np.testing.assert_allclose(f.depth, depth / 1000.0, rtol=1e-6)
    assert f.stamp == pytest.approx(7.5)
    t0 = time.monotonic()
    with pytest.raises(DriverTimeoutError, match="no synchronised RGB-D frame within 0.20 s"):
        cam.capture(timeout=0.2)
    assert 0.15 < time.monotonic() - t0 < 5.0


# ---- issue 15: unplugged device, intrinsics from the frames -------------------------------------------------
def _connected(cam, queue, device=None):
    """What connect() leaves behind on a device: the Sync node's host queue, K from the calibration."""
    cam._queue, cam._K, cam._device = queue, K, device


def test_a_closed_queue_is_a_disconnect_not_a_leaked_queue_exception():
    """depthai 3 closes the host queue when the device is lost and raises MessageQueue.QueueException (not a
    RuntimeError) from get(); also when it closes while capture() waits."""
    import threading

    cam = OakDCamera(width=64, height=48)
    q = dai.MessageQueue("sync", 4, False)
    _connected(cam, q)
    threading.Timer(0.1, q.close).start()  # unplugged while waiting
    with pytest.raises(DeviceNotConnectedError, match="disconnected"):
        cam.capture(timeout=60.0)  # returns when the queue closes, not after the timeout
    assert not cam.is_connected
    with pytest.raises(DeviceNotConnectedError, match="not connected"):
        cam.capture()


def test_a_closed_device_with_an_idle_queue_is_a_disconnect_not_a_timeout():
    class ClosedDevice:  # only what capture() asks of a dai.Device after an empty wait
        def isClosed(self):
            return True

    cam = OakDCamera(width=64, height=48)
    _connected(cam, dai.MessageQueue("sync", 4, False), ClosedDevice())
    with pytest.raises(DeviceNotConnectedError, match="disconnected"):
        cam.capture(timeout=0.05)


def test_intrinsics_come_from_the_aligned_frames_transformation(rng):
    cam = OakDCamera(width=64, height=48)
    _connected(cam, dai.MessageQueue("sync", 4, False))
    g = _group(rng.integers(0, 256, (48, 64, 3), dtype=np.uint8), np.full((48, 64), 1000, np.uint16), 1.0)
    K_sensor = [[900.0, 0.0, 640.0], [0.0, 900.0, 400.0], [0.0, 0.0, 1.0]]
    for name in ("rgb", "depth"):  # the sensor at 1280x800, scaled to 64x40 and padded/cropped to 64x48
        t = dai.ImgTransformation(1280, 800)
        t.setIntrinsicMatrix(K_sensor)
        t.addScale(0.05, 0.05)
        t.addCrop(0, -4, 64, 48)
        g[name].setTransformation(t)
    cam._queue.send(g)
    f = cam.capture(timeout=5.0)
    expected = np.asarray(g["depth"].getTransformation().getIntrinsicMatrix())
    np.testing.assert_allclose(f.K, expected)
    assert f.K[0, 0] == pytest.approx(45.0) and f.K[1, 2] == pytest.approx(24.0)  # 400 * 0.05 + 4
    np.testing.assert_allclose(cam.intrinsics(), f.K)
    # A frame without a transformation keeps the last good K.
    cam._queue.send(_group(np.zeros((48, 64, 3), np.uint8), np.zeros((48, 64), np.uint16), 2.0))
    np.testing.assert_allclose(cam.capture(timeout=5.0).K, f.K)
