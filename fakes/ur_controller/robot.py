"""The emulated arm: joint state, the motions the controller executes, the active TCP/payload and contact.

No dynamics: motions are kinematic with the limits a UR controller enforces (joint speed and acceleration,
a trapezoidal profile along the path, deceleration on stop). Forward kinematics from the shared DH table
(drivers/ur_kinematics.py); inverse kinematics for linear moves by damped least squares from the current
joints, solved every control cycle as the controller does along a movel.
"""

from __future__ import annotations

import math

import numpy as np

from kitchenbot.drivers.ur_kinematics import URModel, fk_flange

# Safety modes (RTDE safety_mode) and status bits (safety_status_bits)
SAFETY_MODE_NORMAL = 1
SAFETY_MODE_PROTECTIVE_STOP = 3
SAFETY_MODE_ROBOT_EMERGENCY_STOP = 7
BIT_NORMAL_MODE = 0
BIT_PROTECTIVE_STOPPED = 2
BIT_ROBOT_EMERGENCY_STOPPED = 6
BIT_EMERGENCY_STOPPED = 7
BIT_STOPPED_DUE_TO_SAFETY = 10

# Robot modes (RTDE robot_mode, dashboard "robotmode")
ROBOT_MODES = {3: "POWER_OFF", 5: "IDLE", 7: "RUNNING"}


def rotvec_to_matrix(r) -> np.ndarray:
    r = np.asarray(r, float)
    th = float(np.linalg.norm(r))
    if th < 1e-12:
        return np.eye(3)
    k = r / th
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(th) * K + (1 - math.cos(th)) * K @ K


def matrix_to_rotvec(R: np.ndarray) -> np.ndarray:
    c = max(-1.0, min(1.0, (np.trace(R) - 1) / 2))
    th = math.acos(c)
    if th < 1e-9:
        return np.zeros(3)
    if th > math.pi - 1e-6:  # near pi: axis from the diagonal
        ax = np.sqrt(np.maximum((np.diag(R) + 1) / 2, 0.0))
        i = int(np.argmax(ax))
        ax[(i + 1) % 3] *= np.sign(R[i, (i + 1) % 3] + R[(i + 1) % 3, i]) or 1.0
        ax[(i + 2) % 3] *= np.sign(R[i, (i + 2) % 3] + R[(i + 2) % 3, i]) or 1.0
        return ax / np.linalg.norm(ax) * th
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]]) / (2 * math.sin(th))
    return w * th


def pose_to_T(p) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = rotvec_to_matrix(p[3:6])
    T[:3, 3] = p[:3]
    return T


def T_to_pose(T: np.ndarray) -> list[float]:
    return [*T[:3, 3].tolist(), *matrix_to_rotvec(T[:3, :3]).tolist()]


def _slerp(R0: np.ndarray, R1: np.ndarray, u: float) -> np.ndarray:
    return R0 @ rotvec_to_matrix(u * matrix_to_rotvec(R0.T @ R1))


class PathMotion:
    """A motion along a path parameter s in [0, length]: trapezoid with speed v and acceleration a, or
    braking with a given deceleration once stopped. Subclasses map s to joints."""

    def __init__(self, length: float, v: float, a: float):
        self.length, self.v, self.a = float(length), float(v), float(a)
        self.s = 0.0
        self.sd = 0.0
        self.t = 0.0  # time along the profile
        self.brake: float | None = None
        self.done = self.length <= 1e-12
        self.failed: str | None = None
        v_peak = min(self.v, math.sqrt(max(self.length, 0.0) * self.a))
        self.t_acc = v_peak / self.a
        self.t_flat = (self.length - v_peak * self.t_acc) / self.v if v_peak >= self.v else 0.0
        self.v_peak = v_peak

    def _profile(self, t: float) -> tuple[float, float]:
        a, ta, tf, vp = self.a, self.t_acc, self.t_flat, self.v_peak
        if t < ta:
            return 0.5 * a * t * t, a * t
        if t < ta + tf:
            return 0.5 * a * ta * ta + vp * (t - ta), vp
        td = min(t - ta - tf, ta)
        return 0.5 * a * ta * ta + vp * tf + vp * td - 0.5 * a * td * td, vp - a * td

    def step_s(self, dt: float) -> None:
        if self.brake is None:  # the trapezoid in closed form
            self.t += dt
            self.s, self.sd = self._profile(self.t)
            if self.t >= 2 * self.t_acc + self.t_flat:
                self.s, self.sd, self.done = self.length, 0.0, True
            return
        self.sd = max(0.0, self.sd - self.brake * dt)  # braking from wherever we are
        self.s = min(self.length, self.s + self.sd * dt)
        if self.s >= self.length or self.sd == 0.0:
            self.sd, self.done = 0.0, True


class JointMove(PathMotion):
    """movej: the joint with the longest travel runs at v/a, the others scaled so all arrive together."""

    kind = "movej"

    def __init__(self, q0, q1, v: float, a: float):
        self.q0, self.q1 = np.asarray(q0, float), np.asarray(q1, float)
        d = self.q1 - self.q0
        length = float(np.max(np.abs(d)))
        self.dir = d / length if length > 0 else np.zeros(6)
        super().__init__(length, v, a)

    def step(self, robot: Robot, dt: float) -> np.ndarray:
        self.step_s(dt)
        return self.q0 + self.dir * self.s


class LinearMove(PathMotion):
    """movel: the TCP on a straight line (orientation slerped) with a trapezoid in metres; joints by IK."""

    kind = "movel"

    def __init__(self, robot: Robot, T_base_tcp_goal: np.ndarray, v: float, a: float):
        self.T0 = robot.tcp_T()
        self.T1 = T_base_tcp_goal
        self.tcp = robot.tcp.copy()
        dist = float(np.linalg.norm(self.T1[:3, 3] - self.T0[:3, 3]))
        ang = float(np.linalg.norm(matrix_to_rotvec(self.T0[:3, :3].T @ self.T1[:3, :3])))
        super().__init__(max(dist, 0.1 * ang), v, a)  # pure rotations move at v rad/s about a 0.1 m arm

    def step(self, robot: Robot, dt: float) -> np.ndarray:
        self.step_s(dt)
        u = self.s / self.length if self.length > 0 else 1.0
        T = np.eye(4)
        T[:3, 3] = (1 - u) * self.T0[:3, 3] + u * self.T1[:3, 3]
        T[:3, :3] = _slerp(self.T0[:3, :3], self.T1[:3, :3], u)
        q, err = robot.ik(T @ np.linalg.inv(self.tcp), robot.q)
        if err > 1e-3:
            self.failed = f"movel: no joint solution near the line ({err * 1000:.1f} mm off)"
            self.done = True
            return robot.q
        return q


class ServoTrack:
    """servoj: the controller tracks the latest target; lookahead smooths (a lag of ~lookahead*300/gain
    seconds), joint speed and acceleration are limited."""

    kind = "servoj"

    def __init__(self, target, t: float, lookahead: float, gain: float):
        self.update(target, t, lookahead, gain)
        self.done = False
        self.failed = None

    def update(self, target, t: float, lookahead: float, gain: float) -> None:
        self.target = np.asarray(target, float)
        self.tau = max(float(t), lookahead * 300.0 / max(gain, 1.0))

    def step(self, robot: Robot, dt: float) -> np.ndarray:
        vmax = np.asarray(robot.model.max_joint_speed)
        want = np.clip((self.target - robot.q) / self.tau, -vmax, vmax)
        dv = np.clip(want - robot.qd, -robot.max_joint_accel * dt, robot.max_joint_accel * dt)
        return robot.q + (robot.qd + dv) * dt


class Brake:
    """stopj/servo stop/protective stop: every joint decelerates so the fastest stops at `decel` rad/s^2."""

    kind = "stop"

    def __init__(self, decel: float):
        self.decel = float(decel)
        self.done = False
        self.failed = None

    def step(self, robot: Robot, dt: float) -> np.ndarray:
        top = float(np.max(np.abs(robot.qd)))
        if top <= self.decel * dt:
            self.done = True
            return robot.q.copy()
        return robot.q + robot.qd * (top - self.decel * dt) / top * dt


class Robot:
    def __init__(self, model: URModel, q0, installation_tcp=(0, 0, 0, 0, 0, 0), payload=0.0,
                 max_joint_accel: float = 15.0):
        self.model = model
        self.q = np.asarray(q0, float).copy()
        self.qd = np.zeros(6)
        self.max_joint_accel = max_joint_accel
        self.installation_tcp = pose_to_T(installation_tcp)
        self.installation_payload = (float(payload), [0.0, 0.0, 0.0])
        self.tcp = self.installation_tcp.copy()
        self.payload = self.installation_payload[0]
        self.payload_cog = list(self.installation_payload[1])
        self.motion = None
        self.mode = 7  # RUNNING
        self.safety_mode = SAFETY_MODE_NORMAL
        self.protective_since: float | None = None
        self.contact_z: float | None = None  # a rigid-ish horizontal surface at this height (base frame)
        self.contact_stiffness = 2.0e4  # N/m
        self.last_failure: str | None = None
        self.finished: list[str] = []  # kinds of motions that ended since the controller last looked

    # ---- kinematics ---------------------------------------------------------------------------------
    def tcp_T(self, q=None) -> np.ndarray:
        return fk_flange(self.model, self.q if q is None else q) @ self.tcp

    def ik(self, T_goal_flange: np.ndarray, q_seed: np.ndarray, iters: int = 8) -> tuple[np.ndarray, float]:
        q = np.asarray(q_seed, float).copy()
        err = 1.0
        for _ in range(iters):
            T = fk_flange(self.model, q)
            e = np.concatenate([T_goal_flange[:3, 3] - T[:3, 3],
                                matrix_to_rotvec(T_goal_flange[:3, :3] @ T[:3, :3].T)])
            err = float(np.linalg.norm(e[:3]) + 0.1 * np.linalg.norm(e[3:]))
            if err < 1e-6:
                break
            J = np.empty((6, 6))
            h = 1e-6
            for j in range(6):
                dq = q.copy()
                dq[j] += h
                Tj = fk_flange(self.model, dq)
                J[:3, j] = (Tj[:3, 3] - T[:3, 3]) / h
                J[3:, j] = matrix_to_rotvec(Tj[:3, :3] @ T[:3, :3].T) / h
            lam = 1e-4
            q = q + J.T @ np.linalg.solve(J @ J.T + lam * np.eye(6), e)
        T = fk_flange(self.model, q)
        err = float(np.linalg.norm(T_goal_flange[:3, 3] - T[:3, 3]))
        return q, err

    def within_safety_limits(self, pose) -> bool:
        """is_within_safety_limits(pose): inside the reach sphere around the shoulder, above the base plane."""
        p = np.asarray(pose[:3], float)
        shoulder = np.array([0.0, 0.0, self.model.d[0]])
        return bool(np.linalg.norm(p - shoulder) <= self.model.reach and p[2] > -0.1)

    # ---- state ------------------------------------------------------------------------------------
    def tcp_force(self) -> list[float]:
        if self.contact_z is None:
            return [0.0] * 6
        pen = self.contact_z - float(self.tcp_T()[2, 3])
        return [0.0, 0.0, self.contact_stiffness * pen if pen > 0 else 0.0, 0.0, 0.0, 0.0]

    def reset_program_settings(self) -> None:
        """TCP and payload set by a program hold only while it runs; afterwards the installation's apply."""
        self.tcp = self.installation_tcp.copy()
        self.payload, self.payload_cog = self.installation_payload[0], list(self.installation_payload[1])

    def step(self, dt: float) -> None:
        if self.motion is None:
            self.qd = np.zeros(6)
            return
        m = self.motion
        q = m.step(self, dt)
        self.qd = (q - self.q) / dt
        self.q = q
        if m.failed:
            self.last_failure = m.failed
        if m.done:
            self.qd = np.zeros(6) if not isinstance(m, ServoTrack) else self.qd
            self.motion = None
            self.finished.append(m.kind + (" braked" if getattr(m, "brake", None) is not None else ""))
