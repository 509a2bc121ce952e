"""Luxonis OAK-D (depthai 3.x) as a wrist RGB-D camera: colour from CAM_A, stereo depth from CAM_B/CAM_C aligned
to the colour image, both paired by a Sync node so every Frame holds one moment.

Pipeline: ``Camera(CAM_A).requestOutput((w, h), BGR888i, fps)`` -> Sync["rgb"] and StereoDepth.inputAlignTo;
``Camera(CAM_B/C)`` -> StereoDepth (ROBOTICS preset, left-right check, subpixel) -> depth (uint16 mm, aligned to
CAM_A at (w, h)) -> Sync["depth"] -> host queue. RVC4 devices align with an ImageAlign node instead.
Intrinsics: from each frame's own ``ImgFrame.getTransformation().getIntrinsicMatrix()`` (the aligned depth's, else
the colour's): it follows every crop/scale depthai applied to produce that output, so K matches the pixels even
when the sensor mode is cropped; ``readCalibration().getCameraIntrinsics(CAM_A, w, h)`` only until the first frame.

Unplugged: automatic reconnection is off (``setMaxReconnectionAttempts(0)``) and the pipeline stops on device
loss, so the host queue closes at once and depthai 3 raises ``MessageQueue.QueueException``; that becomes
DeviceNotConnectedError ("disconnected"), not a misleading timeout after the queue waited for a reconnect.
No device -> DeviceNotConnectedError saying what to check; no synchronised frame in time -> DriverTimeoutError.
The message-to-Frame conversion is a pure function (:func:`frame_from_messages`) so it is tested without a device.
"""

from __future__ import annotations

import datetime
import logging
from typing import Any

import cv2
import numpy as np

from kitchenbot.drivers.camera import Camera, Frame
from kitchenbot.drivers.errors import DeviceNotConnectedError, DriverError, DriverTimeoutError
from kitchenbot.drivers.recording import depth_mm_to_m

log = logging.getLogger(__name__)

STEREO_SIZE = (640, 400)  # OV9282 mono pair at 400p: enough for a 640x480 depth map at kitchen range


def frame_from_messages(rgb_bgr: np.ndarray, depth_mm: np.ndarray, K: np.ndarray, stamp: float) -> Frame:
    """Build a Frame from a BGR colour image and a uint16 depth image in mm (0 = invalid).

    Depth arrives aligned to the colour camera; if its size still differs (a device that cannot output the
    exact size) it is resized with nearest-neighbour so no invalid/valid pixels are blended into fake depths.
    """
    rgb_bgr = np.asarray(rgb_bgr)
    if rgb_bgr.ndim != 3 or rgb_bgr.shape[2] != 3 or rgb_bgr.dtype != np.uint8:
        raise DriverError(f"OAK-D: expected a (H, W, 3) uint8 colour frame, got {rgb_bgr.shape} {rgb_bgr.dtype}")
    depth_mm = np.asarray(depth_mm)
    if depth_mm.dtype != np.uint16 or depth_mm.ndim != 2:
        raise DriverError(f"OAK-D: expected a (H, W) uint16 depth frame in mm, got {depth_mm.shape} {depth_mm.dtype}")
    h, w = rgb_bgr.shape[:2]
    if depth_mm.shape != (h, w):
        depth_mm = cv2.resize(depth_mm, (w, h), interpolation=cv2.INTER_NEAREST)
    return Frame(
        rgb=np.ascontiguousarray(rgb_bgr[:, :, ::-1]),
        depth=depth_mm_to_m(depth_mm),
        K=np.asarray(K, dtype=np.float64).reshape(3, 3),
        stamp=float(stamp),
    )


def frame_intrinsics(rgb: Any, depth: Any, fallback: np.ndarray) -> np.ndarray:
    """K of the pixels in this frame pair: the aligned depth's ImgTransformation (depthai 3 carries the
    intrinsics through every crop/scale/alignment), else the colour frame's, else `fallback` (the calibration
    at the requested size). The Frame's K describes the colour image's pixels, so depth of another size (resized
    to the colour image later) does not give it; nor does a transformation whose size is not its frame's."""
    same_size = (depth.getWidth(), depth.getHeight()) == (rgb.getWidth(), rgb.getHeight())
    for msg in ((depth, rgb) if same_size else (rgb,)):
        t = msg.getTransformation()
        if t.isValid() and tuple(t.getSize()) == (msg.getWidth(), msg.getHeight()):
            K = np.asarray(t.getIntrinsicMatrix(), dtype=np.float64).reshape(3, 3)
            if np.all(np.isfinite(K)) and K[0, 0] > 0 and K[1, 1] > 0:
                return K
    return fallback


def _no_device_message(device_id: str | None, available: list[str]) -> str:
    if device_id and available:
        return f"OAK-D camera: device {device_id!r} not found; available: {', '.join(available)}"
    return (
        "OAK-D camera: no device found (depthai lists none). Check the USB3 cable and power; on Linux install "
        "the udev rule (80-movidius.rules); in a container pass /dev/bus/usb; a PoE model must be on this subnet."
    )


class OakDCamera(Camera):
    def __init__(
        self,
        width: int = 640,
        height: int = 480,
        fps: float = 15.0,
        device_id: str | None = None,
        sync_threshold_s: float | None = None,
    ):
        self.width, self.height, self.fps = int(width), int(height), float(fps)
        self.device_id = device_id
        self.sync_threshold_s = sync_threshold_s if sync_threshold_s is not None else 0.5 / self.fps
        self._device: Any = None
        self._pipeline: Any = None
        self._queue: Any = None
        self._K: np.ndarray | None = None

    # ---- connection -------------------------------------------------------------------------------
    @staticmethod
    def available_devices() -> list[str]:
        import depthai as dai

        return [info.getDeviceId() for info in dai.Device.getAllAvailableDevices()]

    def connect(self) -> None:
        import depthai as dai

        infos = dai.Device.getAllAvailableDevices()  # ~0.5 s; dai.Device() alone waits ~10 s before failing
        ids = [i.getDeviceId() for i in infos]
        match = [i for i in infos if self.device_id in (None, i.getDeviceId(), i.name)]
        if not match:
            raise DeviceNotConnectedError(_no_device_message(self.device_id, ids))
        try:
            device = dai.Device(match[0])
        except RuntimeError as e:
            raise DeviceNotConnectedError(f"OAK-D camera {ids[0] if ids else ''}: cannot open the device: {e}") from None
        try:
            # An unplugged camera must end the capture at once (the caller decides to reconnect), not leave the
            # host queue idle while depthai retries in the background.
            device.setMaxReconnectionAttempts(0)
            pipeline = dai.Pipeline(device)
            pipeline.setStopOnDeviceLoss(True)
            self._queue = self._build(dai, pipeline, device)
            calib = device.readCalibration()
            self._K = np.array(
                calib.getCameraIntrinsics(dai.CameraBoardSocket.CAM_A, self.width, self.height), dtype=np.float64
            )
            pipeline.start()
        except RuntimeError as e:
            device.close()
            raise DriverError(f"OAK-D camera: could not start the RGB-D pipeline: {e}") from None
        self._device, self._pipeline = device, pipeline

    def _build(self, dai: Any, pipeline: Any, device: Any) -> Any:
        size = (self.width, self.height)
        colour = pipeline.create(dai.node.Camera).build(dai.CameraBoardSocket.CAM_A)
        rgb_out = colour.requestOutput(size, dai.ImgFrame.Type.BGR888i, fps=self.fps)
        left = pipeline.create(dai.node.Camera).build(dai.CameraBoardSocket.CAM_B)
        right = pipeline.create(dai.node.Camera).build(dai.CameraBoardSocket.CAM_C)
        stereo = pipeline.create(dai.node.StereoDepth)
        stereo.setDefaultProfilePreset(dai.node.StereoDepth.PresetMode.ROBOTICS)
        stereo.setLeftRightCheck(True)
        stereo.setSubpixel(True)
        left.requestOutput(STEREO_SIZE, fps=self.fps).link(stereo.left)
        right.requestOutput(STEREO_SIZE, fps=self.fps).link(stereo.right)
        sync = pipeline.create(dai.node.Sync)
        sync.setSyncThreshold(datetime.timedelta(seconds=self.sync_threshold_s))
        rgb_out.link(sync.inputs["rgb"])
        if device.getPlatform() == dai.Platform.RVC4:
            align = pipeline.create(dai.node.ImageAlign)
            stereo.depth.link(align.input)
            rgb_out.link(align.inputAlignTo)
            align.outputAligned.link(sync.inputs["depth"])
        else:
            stereo.setDepthAlign(dai.CameraBoardSocket.CAM_A)
            stereo.setOutputSize(self.width, self.height)
            rgb_out.link(stereo.inputAlignTo)
            stereo.depth.link(sync.inputs["depth"])
        return sync.out.createOutputQueue(maxSize=4, blocking=False)

    def disconnect(self) -> None:
        pipeline, device = self._pipeline, self._device
        self._pipeline = self._device = self._queue = None
        if pipeline is not None:
            try:
                pipeline.stop()
            except RuntimeError:
                pass
        if device is not None:
            device.close()

    @property
    def is_connected(self) -> bool:
        return self._queue is not None

    def describe(self) -> dict:
        """Device id, product name and USB speed (for `kitchenbot doctor`)."""
        if self._device is None:
            raise DeviceNotConnectedError("OAK-D camera: not connected")
        return {
            "device_id": self._device.getDeviceId(),
            "product": self._device.getProductName(),
            "usb_speed": str(self._device.getUsbSpeed()),
        }

    # ---- frames -----------------------------------------------------------------------------------
    def capture(self, timeout: float = 2.0) -> Frame:
        import depthai as dai

        if self._queue is None or self._K is None:
            raise DeviceNotConnectedError("OAK-D camera: not connected; call connect() first")
        try:
            group = self._queue.get(datetime.timedelta(seconds=timeout))
        except (dai.MessageQueue.QueueException, RuntimeError) as e:  # the queue closes when the device drops
            self._queue = None
            raise DeviceNotConnectedError(
                f"OAK-D camera: disconnected while waiting for a frame ({e}); check the USB cable, then connect() again"
            ) from None
        if group is None:
            if self._device is not None and self._device.isClosed():
                self._queue = None
                raise DeviceNotConnectedError("OAK-D camera: disconnected (the device closed); connect() again")
            raise DriverTimeoutError(
                f"OAK-D camera: no synchronised RGB-D frame within {timeout:.2f} s "
                f"(sync threshold {self.sync_threshold_s * 1000:.0f} ms at {self.fps:g} fps)"
            )
        rgb, depth = group["rgb"], group["depth"]
        self._K = frame_intrinsics(rgb, depth, self._K)
        return frame_from_messages(
            rgb.getCvFrame(), depth.getFrame(), self._K, rgb.getTimestamp().total_seconds()
        )

    def intrinsics(self) -> np.ndarray:
        if self._K is None:
            raise DeviceNotConnectedError("OAK-D camera: not connected; call connect() first")
        return self._K.copy()
