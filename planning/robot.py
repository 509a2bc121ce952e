"""The arm as a Pinocchio model built from the official UR DH table, with FK and damped-least-squares IK.

The kinematic tree is written in code from ``drivers.ur_kinematics`` (one source of the geometry): joint i is a
revolute-z joint placed at ``Tz(d) Tx(a) Rx(alpha)`` of the previous DH row, the ``flange`` frame follows the
last row and ``tcp`` adds the configured tool transform. No URDF is needed (the example-robot-data wheel is
414 MB, and its UR model is the CB3 UR5); ``tests/planning/test_robot.py`` cross-checks FK against the numpy DH
code. No UR URDF is installed here, so there is no URDF cross-check.

IK: Pinocchio's frame Jacobian + ``log6`` in a damped least-squares loop (the standard Pinocchio recipe),
started from the current configuration first and then from a fixed spread of seeds; each converged solution is
wrapped joint by joint to the 2*pi-equivalent closest to the current configuration that the limits allow
(so +-pi where limits allow it, never a needless full turn), and the closest one is returned.
"""

from __future__ import annotations

import math

from dataclasses import dataclass

import numpy as np
import pinocchio as pin
from scipy.linalg.lapack import dgesv as _dgesv

from kitchenbot.drivers.safety import SafetyLimits
from kitchenbot.drivers.ur_kinematics import URModel, ur_model
from kitchenbot.planning.ur_ik import ik_flange, ik_flange_batch, surely_unreachable

_TURNS = np.array([0.0, -1.0, 1.0, -2.0, 2.0])  # the 2*pi turns wrap_near tries, nearest first
_TURNS_LIST = _TURNS.tolist()
_TWO_PI = 2 * np.pi  # as wrap_near_rows computes it: (2 * pi) * (k0 + turn)
JOINT_NAMES = (
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
)
LINK_NAMES = ("shoulder_link", "upper_arm_link", "forearm_link", "wrist_1_link", "wrist_2_link", "wrist_3_link")


def _dh_fixed(d: float, a: float, alpha: float) -> pin.SE3:
    """The constant part Tz(d) Tx(a) Rx(alpha) of a standard DH row."""
    ca, sa = np.cos(alpha), np.sin(alpha)
    R = np.array([[1.0, 0.0, 0.0], [0.0, ca, -sa], [0.0, sa, ca]])
    return pin.SE3(R, np.array([a, 0.0, d]))


def build_pinocchio_model(model: URModel, T_flange_tcp: np.ndarray, limits: SafetyLimits | None = None) -> pin.Model:
    """A 6-joint Pinocchio model with frames ``flange`` and ``tcp``."""
    m = pin.Model()
    m.name = model.name
    parent = 0
    placement = pin.SE3.Identity()
    lo = np.asarray(limits.joint_lower if limits is not None else model.joint_lower, float)
    hi = np.asarray(limits.joint_upper if limits is not None else model.joint_upper, float)
    vmax = np.asarray(limits.max_joint_speed if limits is not None else model.max_joint_speed, float)
    for i in range(6):
        jid = m.addJoint(
            parent,
            pin.JointModelRZ(),
            placement,
            JOINT_NAMES[i],
            np.array([100.0]),  # effort: unused by planning
            np.array([vmax[i]]),
            np.array([lo[i]]),
            np.array([hi[i]]),
        )
        m.appendBodyToJoint(jid, pin.Inertia.Random(), pin.SE3.Identity())
        m.addBodyFrame(LINK_NAMES[i], jid, pin.SE3.Identity(), len(m.frames) - 1)
        parent = jid
        placement = _dh_fixed(model.d[i], model.a[i], model.alpha[i])
    flange = m.addFrame(pin.Frame("flange", parent, placement, pin.FrameType.OP_FRAME))
    T_tcp = pin.SE3(np.asarray(T_flange_tcp, float))
    m.addFrame(pin.Frame("tcp", parent, placement * T_tcp, pin.FrameType.OP_FRAME))
    assert flange > 0
    return m


@dataclass
class IKResult:
    q: np.ndarray | None  # None: no solution
    iterations: int
    seeds_tried: int
    error: float  # final twist error norm of the best attempt


class RobotModel:
    """FK/IK for one arm + tool. ``q`` are 6 joint angles in radians; poses are 4x4 ``T_base_*``."""

    def __init__(self, ur: URModel, T_flange_tcp: np.ndarray, limits: SafetyLimits):
        self.ur = ur
        self.limits = limits
        self.T_flange_tcp = np.asarray(T_flange_tcp, float)
        self._T_tcp_flange = np.linalg.inv(self.T_flange_tcp)
        self.model = build_pinocchio_model(ur, self.T_flange_tcp, limits)
        self.data = self.model.createData()
        self.lower = np.asarray(limits.joint_lower, float).copy()
        self.upper = np.asarray(limits.joint_upper, float).copy()
        # wrap_near's bounds as Python floats (the same values as the arrays' `lower - 1e-9` / `upper + 1e-9`)
        self._lo_list, self._hi_list = self.lower.tolist(), self.upper.tolist()
        self._lo_ok, self._hi_ok = (self.lower - 1e-9).tolist(), (self.upper + 1e-9).tolist()
        self.max_speed = np.asarray(limits.max_joint_speed, float).copy()
        self.max_accel = np.asarray(limits.max_joint_accel, float).copy()
        self.flange_id = self.model.getFrameId("flange")
        self.tcp_id = self.model.getFrameId("tcp")
        self.joint_ids = list(range(1, 7))
        # IK seeds beyond the current configuration: typical elbow-up, wrist-down postures over the
        # workspace (the cell is in front of the robot, x > 0), plus a few spread ones. Fixed: deterministic.
        base = [
            [0.0, -1.6, 1.6, -1.57, -1.57, 0.0],
            [0.0, -1.2, 1.9, -2.3, -1.57, 0.0],
            [-0.9, -1.3, 1.8, -2.1, -1.57, 0.0],
            [0.9, -1.3, 1.8, -2.1, -1.57, 0.0],
            [-1.5, -1.4, 1.6, -1.8, -1.57, 0.0],
            [1.5, -1.4, 1.6, -1.8, -1.57, 0.0],
            [0.0, -2.0, 2.4, -2.0, -1.57, 1.57],
            [0.0, -1.0, 1.2, -1.8, 1.57, 0.0],
        ]
        rng = np.random.default_rng(7)
        spread = rng.uniform(-np.pi, np.pi, size=(8, 6))
        self.seeds = np.clip(np.vstack([np.array(base), spread]), self.lower, self.upper)

    @classmethod
    def from_config(cls, cfg) -> "RobotModel":
        """From an executive CellConfig (duck-typed: robot.model, safety_limits())."""
        limits = cfg.safety_limits()
        return cls(ur_model(cfg.robot.model), limits.T_flange_tcp, limits)

    # ---- forward kinematics ----------------------------------------------------------------------------------
    def fk(self, q: np.ndarray, frame: str = "tcp") -> np.ndarray:
        """T_base_<frame> for frame in {tcp, flange} or a link name."""
        fid = self.model.getFrameId(frame)
        if fid >= len(self.model.frames):
            raise ValueError(f"fk: unknown frame {frame!r}")
        pin.framesForwardKinematics(self.model, self.data, np.asarray(q, float))
        return self.data.oMf[fid].homogeneous.copy()

    def fk_tcp(self, q: np.ndarray) -> np.ndarray:
        pin.framesForwardKinematics(self.model, self.data, np.asarray(q, float))
        return self.data.oMf[self.tcp_id].homogeneous.copy()

    def joint_placements(self, q: np.ndarray) -> list[np.ndarray]:
        """T_base_joint_i (i = 1..6) as 4x4 arrays."""
        pin.forwardKinematics(self.model, self.data, np.asarray(q, float))
        return [self.data.oMi[j].homogeneous.copy() for j in self.joint_ids]

    def within_limits(self, q: np.ndarray) -> bool:
        return bool(np.all(q >= self.lower - 1e-9) and np.all(q <= self.upper + 1e-9))

    # ---- inverse kinematics ----------------------------------------------------------------------------------
    def wrap_near(self, q: np.ndarray, ref: np.ndarray) -> np.ndarray | None:
        """Each joint moved by multiples of 2*pi to the value closest to `ref` inside the limits (None if none).

        wrap_near_rows's arithmetic on one row in Python floats (the same operations in the same order, the same
        values bitwise: tests/planning/test_robot.py): numpy's per-call overhead on (5, 6) arrays was ~90 % of
        its cost, and the straight lines' IK asks it at every step."""
        qs, rs = np.asarray(q, float).tolist(), np.asarray(ref, float).tolist()
        if len(qs) != 6 or len(rs) != 6 or not all(math.isfinite(x) for x in qs + rs):
            return self.wrap_near_rows(np.asarray(q, float)[None, :], ref)[0]
        out = []
        for x, r, lo, hi, lo_ok, hi_ok in zip(qs, rs, self._lo_list, self._hi_list, self._lo_ok, self._hi_ok):
            k0 = float(round((r - x) / _TWO_PI))  # half to even, as np.round
            best, best_d = None, math.inf
            for t in _TURNS_LIST:
                c = x + _TWO_PI * (k0 + t)
                if lo_ok <= c <= hi_ok:
                    d = abs(c - r)
                    if d < best_d:  # the first of equal distances, as argmin
                        best, best_d = c, d
            if best is None:
                return None
            out.append(lo if best < lo else hi if best > hi else best)  # np.clip
        return np.array(out)

    def wrap_near_rows(self, Q: np.ndarray, ref: np.ndarray) -> list[np.ndarray | None]:
        """wrap_near for each row of Q (N, 6) at once: each joint moved by multiples of 2*pi to the value closest to
        `ref` inside the limits; None for a row where some joint has no such value."""
        k0 = np.round((ref - Q) / (2 * np.pi))
        cand = Q[:, None, :] + 2 * np.pi * (k0[:, None, :] + _TURNS[None, :, None])  # (N, 5, 6)
        ok = (cand >= self.lower - 1e-9) & (cand <= self.upper + 1e-9)
        dist = np.where(ok, np.abs(cand - ref), np.inf)
        out = np.take_along_axis(cand, np.argmin(dist, axis=1)[:, None, :], axis=1)[:, 0, :]
        out = np.clip(out, self.lower, self.upper)
        good = ok.any(axis=1).all(axis=1)
        return [q if g else None for q, g in zip(out, good)]

    def wrap_round_trip(self, q: np.ndarray, ref: np.ndarray, rest: np.ndarray) -> np.ndarray:
        """`q` (inside the limits) with each joint turned by whole turns (2*pi, staying inside the limits) for the
        shortest way out from `ref` and back to `rest`: the value x with the least |x - ref| + |x - rest| (the
        nearest `ref` among equals, so `q` itself where `q` is already `wrap_near(q, ref)` and `ref` is `rest`).
        Every turn of a joint puts the links where they were: the same pose. Nearest `ref` alone (wrap_near), a
        wrist within ~pi of `ref` either way is turned the way that leaves it a whole turn from `rest`, and the
        way back (a re-scan's waypoint, whose value turned the other way is outside the limits) unwinds it."""
        return self.wrap_round_trip_rows(np.asarray(q, float)[None, :], ref, rest)[0]

    def wrap_round_trip_rows(self, Q: np.ndarray, ref: np.ndarray, rest: np.ndarray) -> np.ndarray:
        """wrap_round_trip for each row of Q (N, 6) at once."""
        Q, ref, rest = (np.asarray(a, float) for a in (Q, ref, rest))
        cand = Q[:, None, :] + 2 * np.pi * _TURNS[None, :, None]  # (N, 5, 6): each row itself first
        ok = (cand >= self.lower - 1e-9) & (cand <= self.upper + 1e-9)
        to_ref = np.abs(cand - ref)
        cost = np.where(ok, to_ref + np.abs(cand - rest), np.inf)
        best = cost.min(axis=1)
        # among the least costs (to rounding), the nearest ref; the row's own value where nothing else is inside
        pick = np.argmin(np.where(cost <= best[:, None, :] + 1e-9, to_ref, np.inf), axis=1)
        out = np.take_along_axis(cand, pick[:, None, :], axis=1)[:, 0, :]
        return np.where(np.isfinite(best), out, Q)

    def _dls(self, T_target: pin.SE3, q0: np.ndarray, max_iter: int, tol: float, damping: float) -> tuple[np.ndarray, float, int]:
        model, data, fid = self.model, self.data, self.tcp_id
        q = q0.copy()
        err = np.inf
        prev = np.inf
        stall = 0
        damp = damping * np.eye(6)
        for it in range(max_iter):
            pin.computeJointJacobians(model, data, q)  # forward kinematics + joint Jacobians
            oMf = pin.updateFramePlacement(model, data, fid)
            dM = oMf.actInv(T_target)
            e = pin.log6(dM).vector
            err = float(np.sqrt(e @ e))
            if err < tol:
                return q, err, it
            # unreachable targets converge to a non-zero error: stop once progress stalls
            stall = stall + 1 if err > 0.9 * prev else 0
            if stall >= 4 and err > 1e-3:
                return q, err, it
            prev = err
            J = pin.getFrameJacobian(model, data, fid, pin.LOCAL)
            Jl = pin.Jlog6(dM) @ J
            # LAPACK dgesv directly: numpy.linalg.solve's wrapper costs 5x the 6x6 solve itself
            x = _dgesv(Jl @ Jl.T + damp, e)[2]
            dq = Jl.T @ x
            n = np.abs(dq).max()
            if n > 0.6:  # trust region: big steps jump between IK branches erratically
                dq *= 0.6 / n
            q = q + dq
        return q, err, max_iter

    def ik(
        self,
        T_base_tcp: np.ndarray,
        q_current: np.ndarray,
        *,
        max_seeds: int | None = None,
        extra_solutions: int = 1,
        tol: float = 1e-5,
        max_iter: int = 60,
        damping: float = 1e-6,
    ) -> IKResult:
        """Joint angles reaching `T_base_tcp`, closest (max-abs joint distance) to `q_current`.

        Tries the current configuration first, then the seed spread, until `extra_solutions` solutions beyond the
        first have been found (more solutions = better choice of the closest, more time).
        """
        T_target = pin.SE3(np.asarray(T_base_tcp, float))
        q_current = np.asarray(q_current, float)
        seeds = [q_current] + list(self.seeds[: max_seeds if max_seeds is not None else len(self.seeds)])
        best_q, best_d, best_err = None, np.inf, np.inf
        found = 0
        iters = 0
        tried = 0
        for s in seeds:
            tried += 1
            q, err, it = self._dls(T_target, np.asarray(s, float), max_iter, tol, damping)
            iters += it
            best_err = min(best_err, err)
            if err >= tol:
                continue
            qw = self.wrap_near(q, q_current)
            if qw is None:
                continue
            d = float(np.max(np.abs(qw - q_current)))
            if d < best_d:
                best_q, best_d = qw, d
            found += 1
            if found > extra_solutions or d < 0.3:  # close to current: nothing will beat it by much
                break
        return IKResult(best_q, iters, tried, best_err)

    def ik_all(self, T_base_tcp: np.ndarray, q_ref: np.ndarray) -> list[np.ndarray]:
        """Every closed-form IK branch (planning.ur_ik) reaching `T_base_tcp` inside the joint limits, each joint
        wrapped to the value nearest `q_ref`; sorted by max-abs joint distance to `q_ref` (nearest first)."""
        q_ref = np.asarray(q_ref, float)
        T_base_flange = np.asarray(T_base_tcp, float) @ self._T_tcp_flange
        sols = ik_flange(self.ur, T_base_flange)
        if not sols:
            return []
        out = [qw for qw in self.wrap_near_rows(np.array(sols), q_ref) if qw is not None]
        out.sort(key=lambda q: float(np.max(np.abs(q - q_ref))))
        return out

    def ik_all_batch(self, T_base_tcp: np.ndarray, q_ref: np.ndarray) -> list[list[np.ndarray]]:
        """ik_all for N TCP poses (N, 4, 4) at once: per pose, every closed-form branch inside the joint limits,
        wrapped nearest `q_ref`, nearest first. One vectorised solve (planning.ur_ik.ik_flange_batch) and one
        wrap over all branches instead of N calls: grasp selection asks this of every candidate grasp at every
        bite. The batched closed form is the same derivation in array arithmetic: its angles agree with ik_flange's
        to ~1e-12 rad (tests/planning/test_robot.py), not bitwise."""
        q_ref = np.asarray(q_ref, float)
        T = np.asarray(T_base_tcp, float).reshape(-1, 4, 4)
        if not len(T):
            return []
        Q, ok = ik_flange_batch(self.ur, T @ self._T_tcp_flange)
        idx = np.argwhere(ok)  # (pose, branch), pose-major
        rows: list[list[tuple[float, np.ndarray]]] = [[] for _ in range(len(T))]
        if not len(idx):
            return [[] for _ in range(len(T))]
        W = self.wrap_near_rows(Q[ok], q_ref)
        kept = [k for k, qw in enumerate(W) if qw is not None]
        if kept:
            dist = np.max(np.abs(np.array([W[k] for k in kept]) - q_ref), axis=1).tolist()  # ik_all's sort key
            for k, d in zip(kept, dist):
                rows[idx[k, 0]].append((d, W[k]))
        # nearest first; equal distances keep the branches' order (a stable sort, as ik_all's)
        return [[q for _, q in sorted(r, key=lambda x: x[0])] for r in rows]

    def surely_unreachable(self, T_base_tcp: np.ndarray) -> bool:
        """Whether no joint configuration reaches the TCP pose, by a margin numerical IK cannot close
        (planning.ur_ik.surely_unreachable): callers skip the numerical fallback of ik_all there."""
        return bool(surely_unreachable(self.ur, np.asarray(T_base_tcp, float) @ self._T_tcp_flange)[0])

    def ik_q(self, T_base_tcp: np.ndarray, q_current: np.ndarray, **kw) -> np.ndarray | None:
        return self.ik(T_base_tcp, q_current, **kw).q


def make_robot(model_name: str, T_flange_tcp: np.ndarray, limits: SafetyLimits) -> RobotModel:
    return RobotModel(ur_model(model_name), T_flange_tcp, limits)
