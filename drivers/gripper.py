"""The Gripper interface: a parallel Fin-Ray gripper on one servo.

Implementations: ``drivers.dynamixel_gripper.DynamixelGripper`` (real), ``fakes.gripper.FakeGripper``.
Opening is the distance between the finger pads in metres; grasping closes under a current limit until the
fingers stall on the object (current-based position mode on a Dynamixel).
"""

from __future__ import annotations

from abc import abstractmethod
from dataclasses import dataclass

from kitchenbot.drivers.device import Device


@dataclass
class GripperStatus:
    opening: float  # m between the finger pads
    current: float  # A (signed: + closing)
    holding: bool  # stalled on an object before fully closed, with current near the limit
    moving: bool
    error: str | None  # hardware error text, None when healthy
    temperature_c: float | None = None
    voltage_v: float | None = None


@dataclass
class GraspResult:
    holding: bool
    opening: float  # m at the end of the grasp (object width when holding)
    current: float  # A


class Gripper(Device):
    max_opening: float  # m
    max_current: float  # A

    @abstractmethod
    def open(self, opening: float | None = None, timeout: float = 3.0) -> None:
        """Open to `opening` metres (default: fully) and wait until there."""

    @abstractmethod
    def grasp(self, current_limit: float, timeout: float = 3.0) -> GraspResult:
        """Close until contact or fully closed, never pushing harder than `current_limit` amperes."""

    @abstractmethod
    def status(self) -> GripperStatus: ...

    def opening(self) -> float:
        return self.status().opening

    def is_holding(self) -> bool:
        return self.status().holding

    def error(self) -> str | None:
        return self.status().error

    @abstractmethod
    def reboot(self) -> None:
        """Clear a hardware error (a Dynamixel needs a REBOOT after a shutdown). The gripper ends open-loop
        with torque off; call open() afterwards."""

    def _check_current(self, current_limit: float) -> float:
        if not (0.0 < current_limit <= self.max_current):
            raise ValueError(f"current_limit {current_limit} A: expected 0 < limit <= {self.max_current} A")
        return float(current_limit)
