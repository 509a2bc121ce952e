"""Closed-form inverse kinematics of the UR e-Series (all eight solution branches).

Written by hand: Pinocchio (used everywhere else) only solves IK numerically, which returns the one branch its
seed converges to; grasp selection needs every branch (shoulder left/right, elbow up/down, wrist flipped),
because the branch closest to the current configuration is often the one whose forearm hits the sink wall.
No maintained pip package ships a UR closed form for Python (ur_ikfast needs a compiler and generated code).

Derivation (standard DH, ``alpha = (pi/2, 0, 0, pi/2, -pi/2, 0)``, see drivers.ur_kinematics):
- Joints 2, 3 and 4 are parallel to frame 1's z axis, so the wrist centre (frame 5's origin,
  ``p05 = T06 @ (0, 0, -d6)``) lies at height d4 along that axis: ``px sin q1 - py cos q1 = d4`` -> two q1.
- With q1 known, ``R16 = R01^T R06 = Rz(q2+q3+q4) Ry(-q5) Rz(q6)`` (a ZYZ decomposition) -> two q5 (+-acos of
  R16[2,2]), then q6 and q2+q3+q4.
- Frame 4's origin in frame 1 is ``(a2 c2 + a3 c23, a2 s2 + a3 s23, d4)``: a planar two-link arm -> two q3,
  then q2 and q4.
Every candidate is checked by forward kinematics before it is returned.
"""

from __future__ import annotations

import numpy as np

from kitchenbot.drivers.ur_kinematics import URModel, dh_transform
from kitchenbot.drivers.ur_kinematics import fk_flange_batch as _fk_flange_batch


def fk_flange_batch(model: URModel, Q: np.ndarray) -> np.ndarray:
    """T_base_flange (N, 4, 4) for N configurations at once (drivers.ur_kinematics.fk_flange_batch)."""
    return _fk_flange_batch(model, np.atleast_2d(np.asarray(Q, float)))


def _planar_two_link(x: float, y: float, a2: float, a3: float) -> list[tuple[float, float]]:
    c3 = (x * x + y * y - a2 * a2 - a3 * a3) / (2 * a2 * a3)
    if abs(c3) > 1.0 + 1e-9:
        return []
    c3 = float(np.clip(c3, -1.0, 1.0))
    out = []
    for q3 in {float(np.arccos(c3)), float(-np.arccos(c3))}:
        q2 = float(np.arctan2(y, x) - np.arctan2(a3 * np.sin(q3), a2 + a3 * np.cos(q3)))
        out.append((q2, q3))
    return out


def ik_flange(model: URModel, T_base_flange: np.ndarray, tol: float = 1e-6) -> list[np.ndarray]:
    """Every joint solution (angles in (-pi, pi]) whose flange pose is `T_base_flange`; [] if out of reach.

    Wrist-singular poses (q5 ~ 0, joint 6 parallel to joints 2-4) have infinitely many solutions and are not
    returned: callers fall back to numerical IK there."""
    T = np.asarray(T_base_flange, float)
    d1, _, _, d4, d5, d6 = model.d
    a2, a3 = model.a[1], model.a[2]
    p05 = T @ np.array([0.0, 0.0, -d6, 1.0])
    r = float(np.hypot(p05[0], p05[1]))
    if r < abs(d4) + 1e-9:
        return []
    psi, phi = float(np.arctan2(p05[1], p05[0])), float(np.arcsin(d4 / r))
    cands: list[np.ndarray] = []
    for q1 in (psi + phi, psi + np.pi - phi):
        T01 = dh_transform(q1, d1, 0.0, model.alpha[0])
        T16 = np.linalg.inv(T01) @ T
        R = T16[:3, :3]
        c5 = float(np.clip(R[2, 2], -1.0, 1.0))
        for q5 in (float(np.arccos(c5)), float(-np.arccos(c5))):
            s5 = np.sin(q5)
            if abs(s5) < 1e-6:
                continue  # wrist singularity
            q6 = float(np.arctan2(-R[2, 1] / s5, R[2, 0] / s5))
            sb = -s5  # Ry(-q5)
            q234 = float(np.arctan2(R[1, 2] / sb, R[0, 2] / sb))
            T45 = dh_transform(q5, d5, 0.0, model.alpha[4])
            T56 = dh_transform(q6, d6, 0.0, model.alpha[5])
            T14 = T16 @ np.linalg.inv(T45 @ T56)
            for q2, q3 in _planar_two_link(T14[0, 3], T14[1, 3], a2, a3):
                q4 = q234 - q2 - q3
                q = np.array([q1, q2, q3, q4, q5, q6])
                cands.append((q + np.pi) % (2 * np.pi) - np.pi)
    if not cands:
        return []
    Q = np.array(cands)
    Tq = fk_flange_batch(model, Q)
    ok = (np.linalg.norm(Tq[:, :3, 3] - T[:3, 3], axis=1) < tol) & \
         (np.linalg.norm((Tq[:, :3, :3] - T[:3, :3]).reshape(len(Q), -1), axis=1) < 1e-5)
    return [q for q, good in zip(Q, ok) if good]


def _dh_batch(theta: np.ndarray, d: float, a: float, alpha: float) -> np.ndarray:
    """dh_transform for an array of angles: (..., 4, 4)."""
    ct, st = np.cos(theta), np.sin(theta)
    ca, sa = np.cos(alpha), np.sin(alpha)
    T = np.zeros(theta.shape + (4, 4))
    T[..., 0, 0], T[..., 0, 1], T[..., 0, 2], T[..., 0, 3] = ct, -st * ca, st * sa, a * ct
    T[..., 1, 0], T[..., 1, 1], T[..., 1, 2], T[..., 1, 3] = st, ct * ca, -ct * sa, a * st
    T[..., 2, 1], T[..., 2, 2], T[..., 2, 3] = sa, ca, d
    T[..., 3, 3] = 1.0
    return T


def _rigid_inv(T: np.ndarray) -> np.ndarray:
    R = np.swapaxes(T[..., :3, :3], -1, -2)
    out = np.zeros_like(T)
    out[..., :3, :3] = R
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", R, T[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def ik_flange_batch(model: URModel, T_base_flange: np.ndarray, tol: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """ik_flange for N poses at once (the same derivation, vectorised over poses and branches): (Q, ok) with
    Q (N, 8, 6) joint solutions in [-pi, pi) and ok (N, 8) marking the real ones (checked by forward kinematics;
    wrist-singular and out-of-reach branches are not)."""
    T = np.asarray(T_base_flange, float).reshape(-1, 4, 4)
    n = len(T)
    d1, _, _, d4, d5, d6 = model.d
    a2, a3 = model.a[1], model.a[2]
    p05 = T[:, :3, 3] - d6 * T[:, :3, 2]
    r = np.hypot(p05[:, 0], p05[:, 1])
    reach = r >= abs(d4) + 1e-9
    psi = np.arctan2(p05[:, 1], p05[:, 0])
    phi = np.arcsin(np.clip(d4 / np.where(reach, r, 1.0), -1.0, 1.0))
    q1 = np.stack([psi + phi, psi + np.pi - phi], axis=1)  # (n, 2)
    T16 = _rigid_inv(_dh_batch(q1, d1, 0.0, model.alpha[0])) @ T[:, None]  # (n, 2, 4, 4)
    R = T16[..., :3, :3]
    c5 = np.clip(R[..., 2, 2], -1.0, 1.0)
    q5 = np.stack([np.arccos(c5), -np.arccos(c5)], axis=2)  # (n, 2, 2)
    s5 = np.sin(q5)
    regular = np.abs(s5) >= 1e-6
    s5s = np.where(regular, s5, 1.0)
    Rb = R[:, :, None]  # (n, 2, 1, 3, 3)
    q6 = np.arctan2(-Rb[..., 2, 1] / s5s, Rb[..., 2, 0] / s5s)
    q234 = np.arctan2(Rb[..., 1, 2] / -s5s, Rb[..., 0, 2] / -s5s)
    T46 = _dh_batch(q5, d5, 0.0, model.alpha[4]) @ _dh_batch(q6, d6, 0.0, model.alpha[5])
    T14 = T16[:, :, None] @ _rigid_inv(T46)  # (n, 2, 2, 4, 4)
    x, y = T14[..., 0, 3], T14[..., 1, 3]
    c3 = (x * x + y * y - a2 * a2 - a3 * a3) / (2 * a2 * a3)
    planar = np.abs(c3) <= 1.0 + 1e-9
    c3 = np.clip(c3, -1.0, 1.0)
    q3 = np.stack([np.arccos(c3), -np.arccos(c3)], axis=3)  # (n, 2, 2, 2)
    q2 = np.arctan2(y, x)[..., None] - np.arctan2(a3 * np.sin(q3), a2 + a3 * np.cos(q3))
    q4 = q234[..., None] - q2 - q3
    shape = q3.shape
    Q = np.stack([np.broadcast_to(q1[:, :, None, None], shape), q2, q3, q4,
                  np.broadcast_to(q5[..., None], shape), np.broadcast_to(q6[..., None], shape)], axis=-1)
    Q = ((Q + np.pi) % (2 * np.pi) - np.pi).reshape(n, 8, 6)
    ok = np.broadcast_to((reach[:, None, None] & regular & planar)[..., None], shape).reshape(n, 8)
    Tq = _fk_flange_batch(model, Q.reshape(-1, 6)).reshape(n, 8, 4, 4)
    ok = ok & (np.linalg.norm(Tq[..., :3, 3] - T[:, None, :3, 3], axis=-1) < tol) \
        & (np.linalg.norm((Tq[..., :3, :3] - T[:, None, :3, :3]).reshape(n, 8, 9), axis=-1) < 1e-5)
    return Q, ok


# Margins of surely_unreachable: a target more than ~1e-5 off every reachable pose cannot be reached by numerical IK
# (it stops only below a 1e-5 twist error), and a pose that close moves r, s5 and c3 by far less than these.
_R_MARGIN = 1e-3  # m: the wrist centre's distance from the base axis against d4
_S5_MARGIN = 1e-2  # |sin q5| below it: near the wrist singularity (q6, q2+q3+q4 sensitive), never sure
_C3_MARGIN = 0.05  # the elbow's cosine beyond +-1 by more than this (about a centimetre out of the arm's reach)


def surely_unreachable(model: URModel, T_base_flange: np.ndarray) -> np.ndarray:
    """(N,) True where no joint configuration reaches the flange pose, by a margin: the wrist centre is off the
    shoulder's circle (r < d4) or every branch's elbow is out of reach (|cos q3| > 1), each clearly, with no branch
    near the wrist singularity. Numerical IK (which accepts a 1e-5 twist error) cannot succeed there, so callers
    may skip it; where this is False and ik_flange_batch finds no branch, only numerical IK can tell."""
    T = np.asarray(T_base_flange, float).reshape(-1, 4, 4)
    d1, _, _, d4, d5, d6 = model.d
    a2, a3 = model.a[1], model.a[2]
    p05 = T[:, :3, 3] - d6 * T[:, :3, 2]
    r = np.hypot(p05[:, 0], p05[:, 1])
    off_circle = r < abs(d4) - _R_MARGIN
    clear = r > abs(d4) + _R_MARGIN
    psi = np.arctan2(p05[:, 1], p05[:, 0])
    phi = np.arcsin(np.clip(d4 / np.where(clear, r, 1.0), -1.0, 1.0))
    q1 = np.stack([psi + phi, psi + np.pi - phi], axis=1)
    T16 = _rigid_inv(_dh_batch(q1, d1, 0.0, model.alpha[0])) @ T[:, None]
    R = T16[..., :3, :3]
    c5 = np.clip(R[..., 2, 2], -1.0, 1.0)
    q5 = np.stack([np.arccos(c5), -np.arccos(c5)], axis=2)
    s5 = np.sin(q5)
    regular = np.abs(s5) >= _S5_MARGIN
    s5s = np.where(regular, s5, 1.0)
    Rb = R[:, :, None]
    q6 = np.arctan2(-Rb[..., 2, 1] / s5s, Rb[..., 2, 0] / s5s)
    T46 = _dh_batch(q5, d5, 0.0, model.alpha[4]) @ _dh_batch(q6, d6, 0.0, model.alpha[5])
    T14 = T16[:, :, None] @ _rigid_inv(T46)
    x, y = T14[..., 0, 3], T14[..., 1, 3]
    c3 = (x * x + y * y - a2 * a2 - a3 * a3) / (2 * a2 * a3)
    elbow_out = regular & (np.abs(c3) > 1.0 + _C3_MARGIN)  # (n, 2, 2): per shoulder and wrist branch
    return off_circle | (clear & elbow_out.reshape(len(T), 4).all(axis=1))
