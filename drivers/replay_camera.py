"""A Camera that serves a recording (``drivers.recording``) back in order: for offline debugging of perception
on frames captured in the real cell, and for tests. The pose each frame was captured at is kept in
:attr:`ReplayCamera.last_T_base_cam` (None when the recording has no pose)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from kitchenbot.drivers.camera import Camera, Frame
from kitchenbot.drivers.errors import DeviceNotConnectedError, DriverTimeoutError
from kitchenbot.drivers.recording import Capture, RecordingError, list_captures, load_capture


class ReplayCamera(Camera):
    def __init__(self, folder: str | Path, loop: bool = False):
        self.folder = Path(folder)
        self.loop = loop
        self._files: list[Path] | None = None
        self._next = 0
        self._K: np.ndarray | None = None
        self.last_capture: Capture | None = None

    def connect(self) -> None:
        try:
            files = list_captures(self.folder)
        except RecordingError as e:
            raise DeviceNotConnectedError(f"replay camera: {e}") from None
        first = load_capture(files[0])  # fail early on a broken recording, and know K
        self._files, self._next, self._K = files, 0, first.frame.K

    def disconnect(self) -> None:
        self._files = None

    @property
    def is_connected(self) -> bool:
        return self._files is not None

    def __len__(self) -> int:
        return len(self._files or [])

    def capture(self, timeout: float = 2.0) -> Frame:
        """The next recorded frame. At the end: wraps around with `loop`, else DriverTimeoutError (no frame
        will ever come). A broken file raises RecordingError naming it."""
        if self._files is None:
            raise DeviceNotConnectedError(f"replay camera ({self.folder}): not connected; call connect() first")
        if self._next >= len(self._files):
            if not self.loop:
                raise DriverTimeoutError(
                    f"replay camera: all {len(self._files)} captures in {self.folder} served (loop is off)"
                )
            self._next = 0
        cap = load_capture(self._files[self._next])
        self._next += 1
        self.last_capture = cap
        self._K = cap.frame.K
        return cap.frame

    @property
    def last_T_base_cam(self) -> np.ndarray | None:
        return None if self.last_capture is None else self.last_capture.T_base_cam

    def intrinsics(self) -> np.ndarray:
        if self._K is None:
            raise DeviceNotConnectedError(f"replay camera ({self.folder}): not connected; call connect() first")
        return self._K.copy()
