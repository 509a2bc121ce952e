"""Safety limits: the one place where every arm command is checked before it is sent.

``Arm`` (drivers/arm.py) calls :meth:`SafetyLimits.check_*` in its public methods before handing a command
to any implementation (the UR driver, the fake), so tasks and planners cannot bypass it. A refused command
raises :class:`LimitViolation` naming the joint/axis, the value and the limit; the robot does not move.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from kitchenbot.drivers.errors import LimitViolation
from kitchenbot.drivers.ur_kinematics import URModel, fk_flange, fk_flange_batch


@dataclass
class Workspace:
    """Axis-aligned box (base frame, metres) the TCP must stay inside."""

    lower: np.ndarray
    upper: np.ndarray

    def contains(self, p: np.ndarray) -> bool:
        return bool(np.all(p >= self.lower) and np.all(p <= self.upper))


@dataclass
class SafetyLimits:
    joint_lower: np.ndarray  # rad
    joint_upper: np.ndarray  # rad
    max_joint_speed: np.ndarray  # rad/s
    max_joint_accel: np.ndarray  # rad/s^2
    max_tcp_speed: float  # m/s
    workspace: Workspace
    T_flange_tcp: np.ndarray = field(default_factory=lambda: np.eye(4))

    # ---- single commands -------------------------------------------------------------------------
    def check_joints(self, q: np.ndarray, what: str = "target") -> np.ndarray:
        q = np.asarray(q, dtype=np.float64)
        if q.shape != (6,):
            raise LimitViolation(f"{what}: expected 6 joint values, got shape {q.shape}")
        if not np.all(np.isfinite(q)):
            raise LimitViolation(f"{what}: joint values must be finite, got {q.tolist()}")
        for i in range(6):
            if q[i] < self.joint_lower[i] - 1e-9 or q[i] > self.joint_upper[i] + 1e-9:
                raise LimitViolation(
                    f"{what}: joint {i} = {q[i]:.4f} rad is outside "
                    f"[{self.joint_lower[i]:.4f}, {self.joint_upper[i]:.4f}]"
                )
        return q

    def check_speed(self, speed: float, accel: float) -> None:
        """`speed`/`accel` of a joint move: the fastest joint's rad/s and rad/s^2."""
        if not (np.isfinite(speed) and speed > 0 and speed <= float(np.min(self.max_joint_speed)) + 1e-9):
            raise LimitViolation(
                f"joint speed {speed} rad/s: expected 0 < speed <= {float(np.min(self.max_joint_speed)):.3f}"
            )
        if not (np.isfinite(accel) and accel > 0 and accel <= float(np.min(self.max_joint_accel)) + 1e-9):
            raise LimitViolation(
                f"joint acceleration {accel} rad/s^2: expected 0 < accel <= {float(np.min(self.max_joint_accel)):.3f}"
            )

    def check_tcp_speed(self, speed: float, accel: float) -> None:
        if not (np.isfinite(speed) and 0 < speed <= self.max_tcp_speed + 1e-9):
            raise LimitViolation(f"TCP speed {speed} m/s: expected 0 < speed <= {self.max_tcp_speed}")
        if not (np.isfinite(accel) and accel > 0):
            raise LimitViolation(f"TCP acceleration {accel} m/s^2: expected a positive number")

    def check_tcp_pose(self, T_base_tcp: np.ndarray, what: str = "TCP target") -> None:
        p = np.asarray(T_base_tcp)[:3, 3]
        if not self.workspace.contains(p):
            raise LimitViolation(
                f"{what}: position {np.round(p, 4).tolist()} m is outside the workspace "
                f"{self.workspace.lower.tolist()} .. {self.workspace.upper.tolist()}"
            )

    def check_configuration(self, model: URModel, q: np.ndarray, what: str = "target") -> None:
        """Joint limits and the TCP workspace for one configuration."""
        q = self.check_joints(q, what)
        self.check_tcp_pose(fk_flange(model, q) @ self.T_flange_tcp, f"{what} (TCP)")

    # ---- timed trajectories ----------------------------------------------------------------------
    def check_trajectory(self, model: URModel, times: np.ndarray, q: np.ndarray) -> None:
        """Every waypoint inside the limits; finite-difference velocity/acceleration within limits."""
        times = np.asarray(times, dtype=np.float64)
        q = np.asarray(q, dtype=np.float64)
        if q.ndim != 2 or q.shape[1] != 6 or len(times) != len(q) or len(q) < 2:
            raise LimitViolation(
                f"trajectory: expected N>=2 times and an (N, 6) joint array, got {times.shape} and {q.shape}"
            )
        dt = np.diff(times)
        if not np.all(np.isfinite(times)) or np.any(dt <= 0):
            raise LimitViolation("trajectory: times must be finite and strictly increasing")
        # every waypoint's joints and TCP at once (forward kinematics vectorised over the rows); the waypoints
        # found bad are checked again one by one, in order, for the error that names the first (the same checks)
        bad = ~np.all(np.isfinite(q), axis=1)
        bad |= np.any((q < self.joint_lower - 1e-9) | (q > self.joint_upper + 1e-9), axis=1)
        ok = np.flatnonzero(~bad)
        p = (fk_flange_batch(model, q[ok]) @ np.asarray(self.T_flange_tcp, float)[:, 3])[:, :3]
        bad[ok[~np.all((p >= self.workspace.lower) & (p <= self.workspace.upper), axis=1)]] = True
        for k in np.flatnonzero(bad):
            self.check_configuration(model, q[k], what=f"trajectory waypoint {k}")
        vel = np.diff(q, axis=0) / dt[:, None]
        tol = 1.02  # 2 % for the finite-difference estimate
        over = np.abs(vel) > self.max_joint_speed * tol
        if np.any(over):
            k, j = np.argwhere(over)[0]
            raise LimitViolation(
                f"trajectory segment {k}: joint {j} speed {vel[k, j]:.3f} rad/s exceeds {self.max_joint_speed[j]:.3f}"
            )
        # the TCP's speed between waypoints (all are valid here, so p holds every row's TCP position)
        tcp_v = np.linalg.norm(np.diff(p, axis=0), axis=1) / dt
        over_tcp = np.flatnonzero(tcp_v > self.max_tcp_speed * tol)
        if len(over_tcp):
            k = int(over_tcp[0])
            raise LimitViolation(
                f"trajectory segment {k}: TCP speed {tcp_v[k]:.3f} m/s exceeds {self.max_tcp_speed:.3f}"
            )
        if len(q) >= 3:
            acc = np.diff(vel, axis=0) / ((dt[1:] + dt[:-1]) / 2)[:, None]
            over = np.abs(acc) > self.max_joint_accel * tol
            if np.any(over):
                k, j = np.argwhere(over)[0]
                raise LimitViolation(
                    f"trajectory waypoint {k + 1}: joint {j} acceleration {acc[k, j]:.3f} rad/s^2 exceeds "
                    f"{self.max_joint_accel[j]:.3f}"
                )
