"""What every device driver has: a connection that is opened, closed and can be asked about."""

from __future__ import annotations

from abc import ABC, abstractmethod


class Device(ABC):
    @abstractmethod
    def connect(self) -> None:
        """Open the link (idempotent); raise DeviceNotConnectedError with a clear message if it cannot."""

    @abstractmethod
    def disconnect(self) -> None:
        """Close the link; safe to call when not connected."""

    @property
    @abstractmethod
    def is_connected(self) -> bool: ...
