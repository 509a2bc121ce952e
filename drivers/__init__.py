"""Device interfaces (Arm, Gripper, Camera), their errors, and the safety limits every arm command passes.

Real implementations live beside them (UR over RTDE, Dynamixel gripper, OAK-D camera); the simulated ones in
``kitchenbot.fakes``.
"""

from kitchenbot.drivers.arm import Arm, ArmState, SafetyState
from kitchenbot.drivers.camera import Camera, Frame
from kitchenbot.drivers.device import Device
from kitchenbot.drivers.errors import (
    DeviceNotConnectedError,
    DriverError,
    DriverTimeoutError,
    EmergencyStopError,
    HardwareError,
    LimitViolation,
    ProtectiveStopError,
)
from kitchenbot.drivers.gripper import GraspResult, Gripper, GripperStatus
from kitchenbot.drivers.safety import SafetyLimits, Workspace

__all__ = [
    "Arm",
    "ArmState",
    "Camera",
    "Device",
    "DeviceNotConnectedError",
    "DriverError",
    "DriverTimeoutError",
    "EmergencyStopError",
    "Frame",
    "GraspResult",
    "Gripper",
    "GripperStatus",
    "HardwareError",
    "LimitViolation",
    "ProtectiveStopError",
    "SafetyLimits",
    "SafetyState",
    "Workspace",
]
