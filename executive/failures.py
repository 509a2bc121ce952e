"""How a step of a task run fails: the exceptions the runner raises inside states, and the Failure record that
the recovery rules (executive/recovery_rules.py, docs/executive.md) branch on."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from kitchenbot.drivers.errors import (
    DeviceNotConnectedError,
    DriverError,
    DriverTimeoutError,
    EmergencyStopError,
    HardwareError,
    LimitViolation,
    ProtectiveStopError,
)


class Stopped(Exception):
    """A stop was requested; unwinds the current state at once."""


class StateTimeout(Exception):
    """A state visit took longer than its table timeout."""


class StepFailed(Exception):
    """A step did not achieve its goal (grasp missed, object slipped, verify failed, planning failed)."""

    def __init__(self, kind: str, message: str, **details: Any):
        super().__init__(message)
        self.kind, self.details = kind, details


@dataclass
class Failure:
    kind: str  # camera_timeout | bad_depth | arm_disconnected | protective_stop | estop | gripper_hardware |
    #            grasp_missed | slip | planning | no_path | verify_failed | limit_violation | timeout | no_target |
    #            contact (a guarded lowering met something well above the item's support) | error
    message: str
    state: str
    details: dict = field(default_factory=dict)


def classify(exc: BaseException, state: str) -> Failure:
    """Map an exception to a failure kind the recovery rules branch on."""
    if isinstance(exc, StepFailed):
        return Failure(exc.kind, str(exc), state, exc.details)
    if isinstance(exc, StateTimeout):
        return Failure("timeout", str(exc), state)
    if isinstance(exc, EmergencyStopError):
        return Failure("estop", str(exc), state)
    if isinstance(exc, ProtectiveStopError):
        return Failure("protective_stop", str(exc), state)
    if isinstance(exc, DeviceNotConnectedError):
        return Failure("arm_disconnected" if "arm" in str(exc).lower() else "device_disconnected", str(exc), state)
    if isinstance(exc, LimitViolation):
        return Failure("limit_violation", str(exc), state)
    if isinstance(exc, HardwareError):
        return Failure("gripper_hardware", str(exc), state)
    if isinstance(exc, DriverTimeoutError):
        return Failure("camera_timeout" if state in ("scan", "verify") else "timeout", str(exc), state)
    if isinstance(exc, DriverError):
        return Failure("driver", str(exc), state)
    return Failure("error", f"{type(exc).__name__}: {exc}", state)
