"""FakeArm: a UR5e-like arm on the SimWorld. Honest about time, limits and contact; no dynamics.

- Motions take simulated time (``world.clock``): joint moves follow a synchronised trapezoidal velocity
  profile (the joint with the longest travel runs at `speed`/`accel`, the others scaled so all arrive
  together); linear moves interpolate the TCP pose (lerp + slerp) with a trapezoid in arc length and solve
  the joints along the line by damped least squares on the DH kinematics; timed trajectories are followed
  with linear interpolation.
- Motions are asynchronous underneath: a motion is a function of time started at ``t0``; queries evaluate it
  at ``world.clock.now()`` and move the world's arm there. ``wait`` advances the clock to the end, ``step(dt)``
  advances it a little (controller loops poll with it), ``stop(decel)`` decelerates along the path.
- Before a motion starts its whole path is sampled (<= 5 mm of Cartesian travel of any link, gripper or held
  object point between samples) and checked: joint limits, TCP workspace, collisions (fakes/collision.py),
  and for linear moves IK failure and joint speed. The first bad sample becomes a protective stop just before
  it: the arm runs there and stops; ``wait`` raises ProtectiveStopError until ``unlock_protective_stop()``.
- Faults from ``world.faults``: ``arm_disconnect`` (link down until ``connect()``), ``arm_disconnect_after``
  (the link drops that many seconds into the next motion; the arm stops there), ``protective_stop`` (next N
  motions stop halfway), ``slip_probability`` (per grasp: in one of the next motions while holding, the object
  drops at a random point of its path, placed by path and not by time so a retimed motion drops it at the same
  spot, and the gripper closes on nothing).
- ``log`` records what happened (motions, protective stops, predicted collisions, refused commands, slips,
  simulated motion time) so tests and the executive can audit a run.

The limit checks on commands themselves live in drivers/safety.py through the Arm base class.
"""

from __future__ import annotations

import math
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from kitchenbot.drivers.arm import Arm, ArmState, SafetyState
from kitchenbot.drivers.errors import (
    DeviceNotConnectedError,
    DriverError,
    DriverTimeoutError,
    LimitViolation,
    ProtectiveStopError,
)
from kitchenbot.drivers.safety import SafetyLimits
from kitchenbot.drivers.ur_kinematics import URModel, fk_flange, fk_frames
from kitchenbot.fakes.collision import SimCollision, sample_path

PATH_STEP = 0.005  # m, max Cartesian travel between collision samples
IK_STEP = 0.004  # m (and IK_STEP / ROT_RADIUS rad) between IK solutions along a linear move
ROT_RADIUS = 0.2  # m: a linear move's rotation counts as angle * ROT_RADIUS of arc length


# ---- profiles ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Trapezoid:
    """Trapezoidal (or triangular, if too short to cruise) velocity profile over `distance`."""

    distance: float
    v: float
    a: float

    @property
    def t_acc(self) -> float:
        return min(self.v / self.a, math.sqrt(max(self.distance, 0.0) / self.a))

    @property
    def duration(self) -> float:
        if self.distance <= 0:
            return 0.0
        if self.distance >= self.v * self.v / self.a:
            return self.distance / self.v + self.v / self.a
        return 2.0 * math.sqrt(self.distance / self.a)

    def s(self, t: float) -> float:
        """Distance covered at time t."""
        T, ta, a = self.duration, self.t_acc, self.a
        if t <= 0 or T == 0:
            return 0.0
        if t >= T:
            return self.distance
        vp = a * ta
        if t < ta:
            return 0.5 * a * t * t
        if t <= T - ta:
            return 0.5 * a * ta * ta + vp * (t - ta)
        r = T - t
        return self.distance - 0.5 * a * r * r

    def t_of_s(self, d: float) -> float:
        """Time at which distance `d` is covered (inverse of s)."""
        T, ta, a = self.duration, self.t_acc, self.a
        if d <= 0 or T == 0:
            return 0.0
        if d >= self.distance:
            return T
        d_acc = 0.5 * a * ta * ta
        if d < d_acc:
            return math.sqrt(2 * d / a)
        if d <= self.distance - d_acc:
            return ta + (d - d_acc) / (a * ta)
        return T - math.sqrt(2 * (self.distance - d) / a)


# ---- kinematics (the simulator's own; it must not depend on planning/) -----------------------------------
def _tcp_and_jacobian(model: URModel, q: np.ndarray, T_flange_tcp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    F = fk_frames(model, q)
    T = F[-1] @ T_flange_tcp
    Z = np.array([f[:3, 2] for f in F[:6]])
    O = np.array([f[:3, 3] for f in F[:6]])
    J = np.empty((6, 6))
    J[:3] = np.cross(Z, T[:3, 3] - O).T
    J[3:] = Z.T
    return T, J


def _rotation_error(R_target: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Rotation vector of R_target R^T (world frame)."""
    E = R_target @ R.T
    w = 0.5 * np.array([E[2, 1] - E[1, 2], E[0, 2] - E[2, 0], E[1, 0] - E[0, 1]])
    c = np.clip((np.trace(E) - 1.0) / 2.0, -1.0, 1.0)
    angle = math.acos(c)
    if angle < 1e-9:
        return w
    if angle > 3.0:  # near pi the skew part vanishes: let scipy handle it
        return Rotation.from_matrix(E).as_rotvec()
    return w * (angle / math.sin(angle))


def ik_dls(model: URModel, T_target: np.ndarray, q_seed: np.ndarray, T_flange_tcp: np.ndarray,
           tol_p: float = 1e-5, tol_r: float = 1e-4, iters: int = 30, damping: float = 1e-3) -> np.ndarray | None:
    """Damped least-squares IK from a nearby seed (small steps along a line). None if it does not converge.

    Hand-written on purpose: the simulator keeps its own few-line solver so it is independent of planning/.
    """
    q = np.array(q_seed, float)
    lam2 = damping * damping
    for _ in range(iters):
        T, J = _tcp_and_jacobian(model, q, T_flange_tcp)
        ep = T_target[:3, 3] - T[:3, 3]
        er = _rotation_error(T_target[:3, :3], T[:3, :3])
        if np.linalg.norm(ep) < tol_p and np.linalg.norm(er) < tol_r:
            return q
        e = np.concatenate([ep, er])
        q = q + J.T @ np.linalg.solve(J @ J.T + lam2 * np.eye(6), e)
    return None


def _at_path_fraction(us: np.ndarray, qs: np.ndarray, q_of_u, end_u: float, fraction: float) -> float:
    """The time at which a motion sampled at (`us`, `qs`) has covered `fraction` of its joint-space path up to
    `end_u`. A random event placed by path, not by time, happens at the same place however the motion is timed:
    a retimed motion (same path, other times) drops a slipping item at the same spot, so a change of timing
    changes only when things happen, not what happens."""
    keep = us < end_u
    u = np.append(us[keep], end_u)
    q = np.vstack([qs[keep].reshape(-1, 6), np.asarray(q_of_u(end_u), float)[None]])
    s = np.concatenate([[0.0], np.cumsum(np.abs(np.diff(q, axis=0)).sum(axis=1))])
    if len(u) < 2 or s[-1] < 1e-9:  # a motion that does not move: by time
        return fraction * end_u
    return float(np.interp(fraction * s[-1], s, u))


# ---- records -------------------------------------------------------------------------------------------
@dataclass
class ArmEvent:
    t: float  # simulated seconds
    kind: str  # motion | done | contact | protective_stop | collision | stopped | refused | slip | disconnected | unlock
    detail: str = ""


@dataclass
class ArmLog:
    """What the fake arm did. A correct run has ``collisions == 0``."""

    motions: int = 0
    completed: int = 0
    protective_stops: int = 0
    collisions: int = 0  # motions whose path would have hit something (stopped just before the contact)
    contact_stops: int = 0  # guarded (set-down) motions that ended on the contact of the held item or a pad
    refused: int = 0  # commands refused by the safety limits (LimitViolation) before anything moved
    stops: int = 0  # stop() calls that cut a motion short
    slips: int = 0
    disconnects: int = 0
    motion_time: float = 0.0  # simulated seconds spent moving
    events: list[ArmEvent] = field(default_factory=list)

    def as_dict(self) -> dict:
        """The counters (no events), for run reports."""
        return {k: v for k, v in self.__dict__.items() if k != "events"}


@dataclass
class _Motion:
    kind: str
    t0: float
    duration: float  # nominal
    q_of_u: Callable[[float], np.ndarray]
    end_u: float  # nominal time where the motion ends (duration, or a stop point)
    outcome: str  # done | contact | protective_stop | disconnected | stopped
    detail: str = ""
    slip_u: float | None = None
    dragged: int | None = None  # uid of an object the pressing fingers drag along (see FakeArm._press_drag)
    drag_end_u: float | None = None  # where it stops being pressed (it is left there) before the motion ends
    stop_e: float | None = None  # elapsed time at which stop() started decelerating
    tau: float = 0.0  # deceleration time

    def u(self, e: float) -> float:
        """Nominal path time reached after `e` seconds of actual time."""
        if self.stop_e is None or e <= self.stop_e:
            ub = e
        else:
            d = min(e - self.stop_e, self.tau)
            ub = self.stop_e + d - (d * d / (2 * self.tau) if self.tau > 0 else 0.0)
        return min(max(ub, 0.0), self.end_u)

    @property
    def e_end(self) -> float:
        if self.stop_e is None or self.end_u <= self.stop_e:
            return self.end_u
        if self.tau <= 0:
            return self.stop_e
        x = min(self.end_u - self.stop_e, self.tau / 2)
        return self.stop_e + self.tau * (1.0 - math.sqrt(max(0.0, 1.0 - 2.0 * x / self.tau)))


class FakeArm(Arm):
    """Simulated UR arm acting on a SimWorld (see the module docstring)."""

    def __init__(self, world, limits: SafetyLimits, model: URModel | None = None, poll_dt: float = 0.0):
        """`poll_dt` > 0: every is_moving() that finds a motion running lets that many simulated seconds pass,
        so a polling loop written for a real arm (poll, sleep, poll) makes progress in simulation."""
        super().__init__(model or world.robot, limits)
        if not (np.isfinite(poll_dt) and poll_dt >= 0):
            raise ValueError(f"FakeArm: poll_dt {poll_dt} s: expected a finite number >= 0")
        self.poll_dt = float(poll_dt)
        if not np.allclose(np.asarray(limits.T_flange_tcp), world.T_flange_tcp, atol=1e-6):
            raise ValueError(
                "FakeArm: limits.T_flange_tcp (the configured tool) differs from world.T_flange_tcp (the simulated "
                "tool); build the world with world_kwargs={'T_flange_tcp': cfg.robot.tool.T_flange_tcp.matrix()}"
            )
        self.world = world
        self.collision = SimCollision(world, self.model)
        self.log = ArmLog()
        self._connected = False
        self._safety = SafetyState.NORMAL
        self._motion: _Motion | None = None
        self._pending: DriverError | None = None

    # ---- connection -----------------------------------------------------------------------------------
    def connect(self) -> None:
        self._sync()  # a motion cut by a dropped link ends where the link dropped
        self.world.faults.arm_disconnect = False
        self._connected = True
        if isinstance(self._pending, DeviceNotConnectedError):  # already reported by whichever call hit it
            self._pending = None

    def disconnect(self) -> None:
        self._sync()
        if self._motion is not None:  # a real controller stops the program when the client goes away
            self._cut(self._now_e(), "stopped", "disconnect() during a motion")
            self.world.clock.advance(max(self._motion.e_end - self._now_e(), 0.0))
            self._sync()
        self._connected = False

    @property
    def is_connected(self) -> bool:
        return self._connected and not self.world.faults.arm_disconnect

    def _require_connected(self) -> None:
        if not self.is_connected:
            why = "link dropped (fault)" if self._connected else "not connected"
            raise DeviceNotConnectedError(f"FakeArm: {why}; call connect()")

    # ---- state ----------------------------------------------------------------------------------------
    def joint_positions(self) -> np.ndarray:
        self._sync()
        self._require_connected()
        return self.world.q.copy()

    def state(self) -> ArmState:
        self._sync()
        self._require_connected()
        q = self.world.q.copy()
        qd = np.zeros(6)
        m = self._motion
        if m is not None:
            e, h = self._now_e(), 1e-3
            qd = (m.q_of_u(m.u(e + h)) - m.q_of_u(m.u(max(e - h, 0.0)))) / (e + h - max(e - h, 0.0))
        return ArmState(q=q, qd=qd, T_base_tcp=fk_flange(self.model, q) @ self.limits.T_flange_tcp,
                        safety=self._safety, moving=m is not None, stamp=self.world.clock.now())

    def safety_state(self) -> SafetyState:
        self._sync()
        self._require_connected()
        return self._safety

    def is_moving(self) -> bool:
        self._sync()
        self._require_connected()
        if self._motion is not None and self.poll_dt > 0:
            self.world.clock.advance(self.poll_dt)
            self._sync()
        return self._motion is not None

    # ---- public commands: count refusals, then the base class validates ---------------------------------
    def move_joints(self, q, speed: float = 1.0, accel: float = 1.4, asynchronous: bool = False) -> None:
        with self._counting_refusals():
            super().move_joints(q, speed, accel, asynchronous)

    def move_linear(self, T_base_tcp, speed: float = 0.1, accel: float = 0.5, asynchronous: bool = False) -> None:
        with self._counting_refusals():
            super().move_linear(T_base_tcp, speed, accel, asynchronous)

    def execute_trajectory(self, times, q, asynchronous: bool = False, guarded: bool = False) -> None:
        with self._counting_refusals():
            super().execute_trajectory(times, q, asynchronous, guarded)

    @contextmanager
    def _counting_refusals(self):
        try:
            yield
        except LimitViolation as e:
            self.log.refused += 1
            self._event("refused", str(e))
            raise

    # ---- timing -----------------------------------------------------------------------------------------
    def wait(self, timeout: float | None = None) -> None:
        self._sync()
        m = self._motion
        if m is not None:
            self._require_connected()
            remaining = m.e_end - self._now_e()
            if timeout is not None and remaining > timeout + 1e-12:
                self.world.clock.advance(max(timeout, 0.0))
                self._sync()
                raise DriverTimeoutError(
                    f"FakeArm: motion still running after {timeout} s ({remaining - timeout:.3f} s left)"
                )
            self.world.clock.advance(max(remaining, 0.0))
            self._sync()
        self._raise_pending()
        self._require_connected()

    def step(self, dt: float) -> bool:
        """Advance the simulated clock by dt seconds (a controller loop's tick); returns is_moving()."""
        self.world.clock.advance(dt)
        self._sync()
        self._require_connected()
        return self._motion is not None

    def stop(self, decel: float = 3.0) -> None:
        """Decelerate along the path at `decel` (fastest joint, rad/s^2) and block until stopped."""
        if not (np.isfinite(decel) and decel > 0):
            raise ValueError(f"stop: decel {decel} rad/s^2: expected a positive number")
        self._sync()
        self._require_connected()
        m = self._motion
        if m is None:
            return
        e = self._now_e()
        if m.stop_e is None:  # not already stopping
            u, h = m.u(e), 1e-3
            u0, u1 = max(u - h, 0.0), u + h
            qd = (m.q_of_u(u1) - m.q_of_u(u0)) / (u1 - u0)
            self._cut(e, "stopped", f"stop(decel={decel})", float(np.max(np.abs(qd))) / decel)
        self.world.clock.advance(max(m.e_end - e, 0.0))
        self._sync()

    def _cut(self, e: float, outcome: str, detail: str, tau: float = 0.0) -> None:
        """End the running motion after `tau` seconds of linear deceleration from elapsed time `e`
        (tau = 0: right where it is at `e`)."""
        m = self._motion
        if tau > 0 and m.stop_e is None:
            m.stop_e, m.tau = e, tau
            new_end = m.u(e) + tau / 2
        else:
            new_end = m.u(e)
        if new_end < m.end_u - 1e-12:
            m.end_u, m.outcome, m.detail = new_end, outcome, detail
            if outcome == "stopped":
                self.log.stops += 1

    # ---- motion hooks -----------------------------------------------------------------------------------
    def _move_joints(self, q: np.ndarray, speed: float, accel: float, asynchronous: bool) -> None:
        q0 = self.world.q.copy()
        dq = q - q0
        D = float(np.max(np.abs(dq)))
        prof = Trapezoid(D, speed, accel)

        def q_of_u(u: float) -> np.ndarray:
            return q0 + dq * (prof.s(u) / D if D > 0 else 1.0)

        self._start("move_joints", prof.duration, q_of_u, None, asynchronous)

    def _move_linear(self, T_base_tcp: np.ndarray, speed: float, accel: float, asynchronous: bool) -> None:
        q0 = self.world.q.copy()
        T0 = fk_flange(self.model, q0) @ self.limits.T_flange_tcp
        p0, p1 = T0[:3, 3], T_base_tcp[:3, 3]
        rots = Rotation.from_matrix(np.stack([T0[:3, :3], T_base_tcp[:3, :3]]))
        angle = float((rots[0].inv() * rots[1]).magnitude())
        dist = float(np.linalg.norm(p1 - p0))
        L = max(dist, angle * ROT_RADIUS)
        prof = Trapezoid(L, speed, accel)
        n = max(2, int(math.ceil(L / IK_STEP)) + 1)
        s_grid = np.linspace(0.0, 1.0, n)
        slerp = Slerp([0.0, 1.0], rots)
        R_grid = slerp(s_grid).as_matrix()
        qs = [q0]
        bad: str | None = None
        lo, hi = self.limits.joint_lower, self.limits.joint_upper
        t_grid = np.array([prof.t_of_s(si * L) for si in s_grid])  # when the TCP passes each IK point
        for i in range(1, n):
            T = np.eye(4)
            T[:3, :3], T[:3, 3] = R_grid[i], p0 + (p1 - p0) * s_grid[i]
            qi = ik_dls(self.model, T, qs[-1], self.limits.T_flange_tcp)
            if qi is None:
                bad = f"no joint solution along the line at {s_grid[i] * 100:.0f} % (singularity or out of reach)"
            elif np.any(qi < lo - 1e-9) or np.any(qi > hi + 1e-9):
                bad = f"joint limit along the line at {s_grid[i] * 100:.0f} %"
            elif np.any(np.abs(qi - qs[-1]) > self.limits.max_joint_speed * 1.05 * (t_grid[i] - t_grid[i - 1]) + 1e-4):
                bad = f"joint speed limit along the line at {s_grid[i] * 100:.0f} % (near a singularity)"
            if bad:
                break
            qs.append(qi)
        Q = np.asarray(qs)
        s_ok = s_grid[len(qs) - 1]
        s_table = s_grid[: len(qs)]

        def q_of_u(u: float) -> np.ndarray:
            s = prof.s(u) / L if L > 0 else 1.0
            s = min(s, s_ok)
            return np.array([np.interp(s, s_table, Q[:, j]) for j in range(6)])

        stop_u = None
        if bad is not None:  # the path is only defined up to s_ok: find the time it gets there
            stop_u = prof.t_of_s(s_ok * L)
        self._start("move_linear", prof.duration, q_of_u, (stop_u, bad) if bad else None, asynchronous)

    def _execute_trajectory(self, times: np.ndarray, q: np.ndarray, asynchronous: bool, guarded: bool = False) -> None:
        t = times - times[0]

        def q_of_u(u: float) -> np.ndarray:
            return np.array([np.interp(u, t, q[:, j]) for j in range(6)])

        self._start("execute_trajectory", float(t[-1]), q_of_u, None, asynchronous, guarded)

    def _unlock_protective_stop(self) -> None:
        self._sync()
        self._require_connected()
        if self._motion is not None:
            raise DriverError("FakeArm: cannot unlock while the arm is still stopping")
        self._safety = SafetyState.NORMAL
        self._pending = None
        self._event("unlock", "protective stop cleared")

    # ---- motion machinery ---------------------------------------------------------------------------------
    # Parts whose contact a guarded (set-down) motion feels and stops on: what the tool holds and the finger pads.
    # A palm, camera or link meeting something is a collision in any motion.
    GUARDED_PARTS = ("held", "finger_pos", "finger_neg")

    def _start(self, kind: str, duration: float, q_of_u, preset_stop, asynchronous: bool,
               guarded: bool = False) -> None:
        if self._motion is not None:
            raise DriverError(f"FakeArm: {kind} while a motion is running; stop() or wait() first")
        self._pending = None
        end_u, outcome, detail = duration, "done", ""
        if preset_stop is not None:
            end_u, outcome, detail = preset_stop[0], "protective_stop", preset_stop[1]
        # Fingers pressing down on an item while the TCP moves sideways drag it along (it follows the TCP for the
        # path check and settles where the motion ends).
        dragged, refused = self._press_drag(q_of_u, end_u)
        drag_end_u = None
        if refused:
            end_u, outcome, detail = 0.0, "protective_stop", refused
        elif dragged is not None:
            self.world.attach(dragged, slip=False)
            jam_u, drag_end_u, why = self._drag_profile(dragged, q_of_u, end_u)
            if jam_u is not None:
                end_u, outcome, detail = jam_u, "protective_stop", why
        # Check the path: limits and collisions, sample by sample.
        opening = float(self.world.gripper_opening)
        us, qs = sample_path(q_of_u, end_u, lambda qq: self.collision.keypoints(qq, opening), PATH_STEP)
        k_bad, why = self._first_limit_violation(qs)
        contact = self.collision.check_path(qs[: k_bad if k_bad is not None else len(qs)], opening,
                                            sliding=dragged is not None)
        collided = False
        if contact is not None and guarded and contact.part in self.GUARDED_PARTS:
            # the controller feels the contact force and ends the motion there (just before the contact sample)
            end_u, outcome, detail = (us[contact.index - 1] if contact.index > 0 else 0.0), "contact", str(contact)
        elif contact is not None:
            k_bad, why, collided = contact.index, f"collision: {contact}", True
        if k_bad is not None:
            end_u, outcome, detail = (us[k_bad - 1] if k_bad > 0 else 0.0), "protective_stop", why
        f = self.world.faults
        if f.protective_stop > 0:
            f.protective_stop -= 1
            if duration / 2 < end_u:
                end_u, outcome, detail, collided = duration / 2, "protective_stop", "injected protective stop", False
        if f.arm_disconnect_after is not None:
            after, f.arm_disconnect_after = float(f.arm_disconnect_after), None
            if after < end_u:
                end_u, outcome, collided = after, "disconnected", False
                detail = f"link dropped {after:.3f} s into the motion"
        m = _Motion(kind, self.world.clock.now(), duration, q_of_u, end_u, outcome, detail)
        m.dragged, m.drag_end_u = dragged, drag_end_u
        if self.world.held_uid is not None and self.world.slip_in_motions is not None:
            if self.world.slip_in_motions == 0:  # this hold's slip (drawn once per grasp, see SimWorld.attach)
                m.slip_u = _at_path_fraction(us, qs, q_of_u, end_u, float(self.world.rng.uniform(0.2, 0.8)))
                self.world.slip_in_motions = None
            else:
                self.world.slip_in_motions -= 1
        self._motion = m
        self.log.motions += 1
        if collided:
            self.log.collisions += 1
        plan = f"; will stop at {end_u:.3f} s ({detail})" if outcome != "done" else ""
        self._event("motion", f"{kind}: {duration:.3f} s{plan}")
        if not asynchronous:
            self.wait()

    def _first_limit_violation(self, qs: np.ndarray) -> tuple[int | None, str]:
        lo, hi = self.limits.joint_lower - 1e-6, self.limits.joint_upper + 1e-6
        ws = self.limits.workspace
        for k, q in enumerate(qs):
            if np.any(q < lo) or np.any(q > hi):
                return k, "joint limit along the path"
            p = (fk_flange(self.model, q) @ self.limits.T_flange_tcp)[:3, 3]
            if np.any(p < ws.lower - 1e-6) or np.any(p > ws.upper + 1e-6):
                return k, f"TCP leaves the workspace along the path at {np.round(p, 3).tolist()}"
        return None, ""

    def _now_e(self) -> float:
        return self.world.clock.now() - self._motion.t0 if self._motion is not None else 0.0

    def _sync(self) -> None:
        """Bring the world's arm to where the running motion is at the current simulated time."""
        m = self._motion
        if m is None:
            return
        e = self._now_e()
        if self.world.faults.arm_disconnect and e < m.e_end:  # the link dropped: the arm stops where it is
            m.end_u = m.u(e)
            m.outcome, m.detail = "disconnected", "link dropped during the motion"
        if m.drag_end_u is not None and m.dragged is not None and m.u(e) >= m.drag_end_u:
            self.world.set_joints(m.q_of_u(m.drag_end_u))
            if self.world.held_uid == m.dragged:
                self._let_go_dragged()
            m.dragged = None
        if m.slip_u is not None and m.u(e) >= m.slip_u:
            self.world.set_joints(m.q_of_u(m.slip_u))
            self._slip()
            m.slip_u = None
        if e >= m.e_end - 1e-12:
            self.world.set_joints(m.q_of_u(m.end_u))
            self._finish(m)
        else:
            self.world.set_joints(m.q_of_u(m.u(e)))

    def _finish(self, m: _Motion) -> None:
        self._motion = None
        if m.dragged is not None and self.world.held_uid == m.dragged:
            self._let_go_dragged()
        self.log.motion_time += m.e_end
        t = m.t0 + m.e_end
        if m.outcome == "protective_stop":
            self._safety = SafetyState.PROTECTIVE_STOP
            self.log.protective_stops += 1
            self._pending = ProtectiveStopError(f"FakeArm: protective stop in {m.kind}: {m.detail}")
            self._event("protective_stop", m.detail, t)
        elif m.outcome == "disconnected":
            self.world.faults.arm_disconnect = True
            self.log.disconnects += 1
            self._pending = DeviceNotConnectedError(f"FakeArm: {m.detail}; the arm stopped; call connect()")
            self._event("disconnected", m.detail, t)
        elif m.outcome == "stopped":
            self._event("stopped", m.detail, t)
        elif m.outcome == "contact":
            self.stopped_on_contact = True
            self.log.contact_stops += 1
            self._event("contact", f"{m.kind} ended on contact: {m.detail}", t)
        else:
            self.log.completed += 1
            self._event("done", m.kind, t)

    # ---- pressing and dragging ------------------------------------------------------------------------------
    def _press_drag(self, q_of_u, end_u: float) -> tuple[int | None, str]:
        """(uid, "") of the item the closed fingers press on from above during a sideways motion, which it then
        follows (the fingers' friction on it beats its friction on what it rests on: a plate slid off the one
        below); (None, why) when something rests on that item (a loaded item is not pushed: protective stop);
        (None, "") otherwise.

        Physics-free rule: gripper closed (< 1 cm), approach within 14 degrees of straight down, the TCP moves
        >= 5 mm sideways while staying level (<= 4 mm up or down), and a finger tip is 0-6 mm into the top
        surface of an item (the Fin-Ray fingers' compliance presses it)."""
        w = self.world
        if w.held_uid is not None or w.gripper_opening > 0.01 or end_u <= 0:
            return None, ""
        Ts = [fk_flange(self.model, q_of_u(u)) @ self.limits.T_flange_tcp for u in np.linspace(0.0, end_u, 9)]
        if Ts[0][2, 2] > -0.97:
            return None, ""
        P = np.array([T[:3, 3] for T in Ts])
        side = float(np.linalg.norm(P[-1, :2] - P[0, :2]))
        if side < 0.005 or abs(P[-1, 2] - P[0, 2]) > 0.004 + 0.4 * side:  # mostly sideways (<~22 deg up/down)
            return None, ""
        from kitchenbot.fakes.geometry import build_scene

        g = self.collision.gripper
        half = w.gripper_opening / 2 + g.finger_thickness / 2
        tips = np.array([(Ts[0] @ np.array([0.0, y, g.tip_z, 1.0]))[:3] for y in (half, -half)])
        scene, labelled = build_scene(w, include_cell=False)
        if not labelled.kinds:
            return None, ""
        origins = tips + np.array([0.0, 0.0, 0.03])
        rays = np.hstack([origins, np.tile([0.0, 0.0, -1.0], (len(tips), 1))]).astype(np.float32)
        import open3d as o3d

        ans = scene.cast_rays(o3d.core.Tensor(rays))
        t, gid = ans["t_hit"].numpy(), ans["geometry_ids"].numpy()
        if any(np.isfinite(ti) and ti < 0.024 for ti in t):
            return None, "fingers pressed more than 6 mm into an item while moving sideways"
        pressed = [int(labelled.kinds[int(i)][1]) for ti, i in zip(t, gid) if np.isfinite(ti) and 0.024 <= ti <= 0.031]
        if not pressed:
            return None, ""
        uid = pressed[0]
        o = w.objects[uid]
        V = np.asarray(o.model.mesh.vertices) @ o.T_base_obj[:3, :3].T + o.T_base_obj[:3, 3]
        lo, hi = V.min(0) - 0.003, V.max(0) + 0.003
        for v, other in w.objects.items():
            if v == uid:
                continue
            W = np.asarray(other.model.mesh.vertices) @ other.T_base_obj[:3, :3].T + other.T_base_obj[:3, 3]
            above = other.T_base_obj[2, 3] > o.T_base_obj[2, 3] + 0.005
            # higher up, its bounding box overlapping, and touching it (within 3 mm): an item standing beside
            # the plate (a cup whose box overlaps the plate's corner, 4 cm away) or a neighbour the plate itself
            # leans on without touching it does not load it
            if above and np.all(W.min(0) <= hi) and np.all(W.max(0) >= lo) and self._touching(o, other, 0.003):
                return None, f"pushing object {uid} with object {v} resting on it"
        return uid, ""

    def _touching(self, a, b, within: float) -> bool:
        """Whether two world objects' meshes come within `within` metres of each other (python-fcl)."""
        import fcl

        col = self.collision
        objs = [fcl.CollisionObject(col._mesh_bvh(x.model), fcl.Transform(x.T_base_obj[:3, :3], x.T_base_obj[:3, 3]))
                for x in (a, b)]
        return fcl.distance(objs[0], objs[1], fcl.DistanceRequest(), fcl.DistanceResult()) <= within

    def _drag_profile(self, uid: int, q_of_u, end_u: float) -> tuple[float | None, float | None, str]:
        """(jam_u, release_u, why) of a drag: the item rides on what is under it while the fingers carry it
        rigidly, so where its resting height (dropped onto the world without it) is more than 6 mm above the
        carried pose, the fingers would have to push it through its support: a jam (protective stop at the last
        good sample); where the resting height is more than 2 mm below, it falls away from the fingers and
        stays (released there)."""
        from kitchenbot.fakes.geometry import build_scene
        from kitchenbot.fakes.placement import _Body, _drop

        w = self.world
        body = _Body.of(w.objects[uid].model.mesh)
        scene, _ = build_scene(w, exclude=(uid,))
        T_tcp_held = w.T_tcp_held
        T0 = fk_flange(self.model, q_of_u(0.0)) @ self.limits.T_flange_tcp
        T1 = fk_flange(self.model, q_of_u(end_u)) @ self.limits.T_flange_tcp
        n = max(2, int(np.ceil(np.linalg.norm(T1[:3, 3] - T0[:3, 3]) / 0.005)) + 1)
        last = 0.0
        for u in np.linspace(0.0, end_u, n)[1:]:
            T = fk_flange(self.model, q_of_u(u)) @ self.limits.T_flange_tcp @ T_tcp_held
            T_rest, _ = _drop(body, T, scene, -1.0)
            dz = T[2, 3] - T_rest[2, 3]
            if dz < -0.006:
                return last, None, f"dragged object {uid} jams against what it rests on"
            if dz > 0.002:
                return None, u, ""
            last = float(u)
        return None, None, ""

    def _let_go_dragged(self) -> None:
        """The dragged item stays where the fingers left it, settled on what is under it."""
        from kitchenbot.fakes.placement import settle

        w = self.world
        uid = w.held_uid
        w.held_uid, w.T_tcp_held = None, None
        o = w.objects[uid]
        inside = w.cell.in_sink(o.T_base_obj[:3, 3])[0]
        o.T_base_obj = settle(w, uid, o.T_base_obj, keep_inside=w.cell.sink_interior if inside else None)
        w.version += 1
        self._event("dragged", f"object {uid} slid to {np.round(o.T_base_obj[:3, 3], 3).tolist()}")

    def _slip(self) -> None:
        uid = self.world.release()
        if uid is not None:
            self._topple(uid)
        self.world.gripper_opening = 0.0  # the fingers snap shut on nothing
        self.log.slips += 1
        self._event("slip", f"object {uid} slipped out of the gripper")

    def _topple(self, uid: int) -> None:
        """A slipped item falls in the attitude it was carried in; where that is on its edge (a plate carried
        upright for a rack slot) nothing balances it there: it tips over its support (`settle`) until it rests.
        In a rack's footprint the rack's tines (not modelled as collision geometry) hold it as it fell; in the
        sink it tips no further than the basin's walls."""
        from kitchenbot.fakes.placement import settle
        from kitchenbot.transforms import make_T

        w = self.world
        o = w.objects[uid]
        T = np.asarray(o.T_base_obj, float)
        dw = w.cell.spec.dishwasher
        for r in (dw.lower, dw.upper):
            lo, size = np.asarray(r.origin_xy, float), np.asarray(r.size_xy, float)
            if np.all(T[:2, 3] >= lo) and np.all(T[:2, 3] <= lo + size):
                return
        z_h = np.array([T[0, 2], T[1, 2], 0.0])
        if np.linalg.norm(z_h) > 0.5:  # its axis more than 30 degrees off vertical: on its edge or side
            # a carried item is never exactly balanced on its edge: a degree off, towards its top face up (the
            # exact balance of the model left a plate standing on its rim wherever it fell)
            a = np.cross(z_h / np.linalg.norm(z_h), [0.0, 0.0, 1.0])
            T = make_T(Rotation.from_rotvec(a * np.radians(1.0)).as_matrix(), (0.0, 0.0, 0.0)) @ T
            T[:3, 3] = o.T_base_obj[:3, 3]
        inside = w.cell.in_sink(T[:3, 3])[0]
        o.T_base_obj = settle(w, uid, T, max_deg=90.0, keep_inside=w.cell.sink_interior if inside else None)
        w.version += 1

    def _raise_pending(self) -> None:
        err, self._pending = self._pending, None
        if err is not None:
            raise err

    def _event(self, kind: str, detail: str = "", t: float | None = None) -> None:
        self.log.events.append(ArmEvent(self.world.clock.now() if t is None else t, kind, detail))

