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


def fk_flange_batch(model: URModel, Q: np.ndarray) -> np.ndarray:
    """T_base_flange (N, 4, 4) for N configurations at once (the same DH chain as drivers.ur_kinematics)."""
    Q = np.atleast_2d(np.asarray(Q, float))
    T = np.broadcast_to(np.eye(4), (len(Q), 4, 4)).copy()
    for i in range(6):
        ct, st = np.cos(Q[:, i]), np.sin(Q[:, i])
        ca, sa = np.cos(model.alpha[i]), np.sin(model.alpha[i])
        A = np.zeros((len(Q), 4, 4))
        A[:, 0, 0], A[:, 0, 1], A[:, 0, 2], A[:, 0, 3] = ct, -st * ca, st * sa, model.a[i] * ct
        A[:, 1, 0], A[:, 1, 1], A[:, 1, 2], A[:, 1, 3] = st, ct * ca, -ct * sa, model.a[i] * st
        A[:, 2, 1], A[:, 2, 2], A[:, 2, 3] = sa, ca, model.d[i]
        A[:, 3, 3] = 1.0
        T = T @ A
    return T


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
