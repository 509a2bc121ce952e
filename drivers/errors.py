"""Errors every driver raises, real or fake. Tasks and the executive catch these, never vendor errors."""

from __future__ import annotations


class DriverError(RuntimeError):
    """Base class: something went wrong talking to, or inside, a device."""


class DeviceNotConnectedError(DriverError):
    """The device was never connected, or the link dropped. Reconnect before commanding it."""


class DriverTimeoutError(DriverError):
    """The device did not answer, or a motion/capture did not finish, within the allowed time."""


class ProtectiveStopError(DriverError):
    """The arm stopped itself (collision, limit, or safety system). Needs an explicit unlock."""


class EmergencyStopError(DriverError):
    """An emergency stop is active. Only a person can clear it."""


class HardwareError(DriverError):
    """The device reports a hardware fault (overload, overheating, voltage...)."""


class LimitViolation(DriverError, ValueError):
    """A command was refused before it was sent: joint, speed, acceleration or workspace limit.

    Raised by ``drivers.safety``; the robot does not move.
    """
