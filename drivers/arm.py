"""The Arm interface. Implementations: ``drivers.ur_rtde_arm.URArm`` (real), ``fakes.arm.FakeArm``.

Public methods validate every command through :class:`SafetyLimits` and then call the implementation's
``_``-prefixed hook, so no implementation can skip the checks. Motions may be asynchronous: start with
``asynchronous=True``, poll :meth:`is_moving`, :meth:`stop` at any time, or :meth:`wait`.
"""

from __future__ import annotations

import enum
from abc import abstractmethod
from dataclasses import dataclass

import numpy as np

from kitchenbot.drivers.device import Device
from kitchenbot.drivers.errors import (
    DeviceNotConnectedError,
    EmergencyStopError,
    LimitViolation,
    ProtectiveStopError,
)
from kitchenbot.drivers.safety import SafetyLimits
from kitchenbot.drivers.ur_kinematics import URModel, fk_flange


class SafetyState(enum.Enum):
    NORMAL = "normal"
    PROTECTIVE_STOP = "protective_stop"
    EMERGENCY_STOP = "emergency_stop"
    FAULT = "fault"


@dataclass
class ArmState:
    q: np.ndarray  # joint positions, rad
    qd: np.ndarray  # joint velocities, rad/s
    T_base_tcp: np.ndarray
    safety: SafetyState
    moving: bool
    stamp: float  # seconds (driver clock)


class Arm(Device):
    """A 6-axis arm. Units: radians, metres, seconds."""

    # A guarded motion ends at the first contact whose force at the TCP exceeds this (N): set-down moves.
    CONTACT_FORCE = 15.0

    def __init__(self, model: URModel, limits: SafetyLimits):
        self.model = model
        self.limits = limits
        self.stopped_on_contact = False  # the last motion was guarded and ended at a contact, before its end

    # ---- state ------------------------------------------------------------------------------------
    @abstractmethod
    def joint_positions(self) -> np.ndarray: ...

    @abstractmethod
    def state(self) -> ArmState: ...

    @abstractmethod
    def safety_state(self) -> SafetyState: ...

    def tcp_pose(self) -> np.ndarray:
        """T_base_tcp from the measured joints and the configured tool."""
        return self.flange_pose() @ self.limits.T_flange_tcp

    def flange_pose(self) -> np.ndarray:
        return fk_flange(self.model, self.joint_positions())

    # ---- motion (validated here, executed by the implementation) -----------------------------------
    def move_joints(self, q: np.ndarray, speed: float = 1.0, accel: float = 1.4, asynchronous: bool = False) -> None:
        """Joint-space move to q; `speed`/`accel` bound the fastest joint (rad/s, rad/s^2)."""
        self._require_ready()
        q = self.limits.check_joints(q)
        self.limits.check_configuration(self.model, q)
        self.limits.check_speed(speed, accel)
        self.stopped_on_contact = False
        self._move_joints(q, speed, accel, asynchronous)

    def move_linear(
        self, T_base_tcp: np.ndarray, speed: float = 0.1, accel: float = 0.5, asynchronous: bool = False
    ) -> None:
        """Straight-line TCP move (m/s, m/s^2). The path itself is checked by the implementation."""
        self._require_ready()
        T = np.asarray(T_base_tcp, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise ValueError(f"T_base_tcp: expected a finite 4x4 transform, got shape {T.shape}")
        self.limits.check_tcp_pose(T)
        self.limits.check_tcp_speed(speed, accel)
        self.stopped_on_contact = False
        self._move_linear(T, speed, accel, asynchronous)

    def execute_trajectory(self, times: np.ndarray, q: np.ndarray, asynchronous: bool = False,
                           guarded: bool = False) -> None:
        """Follow a timed joint trajectory (times from 0, seconds; q (N, 6)). It must start where we are.

        `guarded`: a set-down move. The first contact the tool or what it holds makes (TCP force past
        CONTACT_FORCE) ends it early and normally, and `stopped_on_contact` says so: the item reached its support
        sooner than planned. Any other contact still ends in a protective stop."""
        self._require_ready()
        self.limits.check_trajectory(self.model, times, q)
        start_error = float(np.max(np.abs(np.asarray(q)[0] - self.joint_positions())))
        if start_error > 0.01:
            raise LimitViolation(
                f"trajectory starts {start_error:.3f} rad away from the current joint positions (max 0.01)"
            )
        self.stopped_on_contact = False
        self._execute_trajectory(np.asarray(times, float), np.asarray(q, float), asynchronous, guarded)

    @abstractmethod
    def is_moving(self) -> bool: ...

    @abstractmethod
    def wait(self, timeout: float | None = None) -> None:
        """Block until the current motion ends; raise ProtectiveStopError if it ended in a stop."""

    @abstractmethod
    def stop(self, decel: float = 3.0) -> None:
        """Stop now (joint deceleration rad/s^2). Always allowed, even with no motion running."""

    def unlock_protective_stop(self) -> None:
        """Clear a protective stop. Only call on an explicit request (a person or the recovery policy)."""
        self._unlock_protective_stop()

    # ---- implementation hooks ----------------------------------------------------------------------
    @abstractmethod
    def _move_joints(self, q: np.ndarray, speed: float, accel: float, asynchronous: bool) -> None: ...

    @abstractmethod
    def _move_linear(self, T_base_tcp: np.ndarray, speed: float, accel: float, asynchronous: bool) -> None: ...

    @abstractmethod
    def _execute_trajectory(self, times: np.ndarray, q: np.ndarray, asynchronous: bool,
                            guarded: bool = False) -> None: ...

    @abstractmethod
    def _unlock_protective_stop(self) -> None: ...

    def _require_ready(self) -> None:
        if not self.is_connected:
            raise DeviceNotConnectedError(f"{type(self).__name__}: not connected; call connect() first")
        s = self.safety_state()
        if s is SafetyState.PROTECTIVE_STOP:
            raise ProtectiveStopError("arm is in a protective stop; unlock it before moving")
        if s is SafetyState.EMERGENCY_STOP:
            raise EmergencyStopError("emergency stop is active; a person must release it")
