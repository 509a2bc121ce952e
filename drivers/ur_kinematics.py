"""Universal Robots e-Series kinematics from the official DH tables.

Forward kinematics of the 6-axis arm in plain numpy: the drivers need it to check the workspace before a
command leaves the computer, and the simulator to know where the links are. Planning builds its Pinocchio
model from the same table (``planning.robot``), so there is a single source of the geometry.

Standard DH: ``T_{i-1,i} = Rz(theta_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``. Frame 0 is ``base`` (UR's base frame,
z up); frame 6 is ``flange`` (tool0: z out of the flange).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

PI = np.pi


@dataclass(frozen=True)
class URModel:
    name: str
    d: tuple[float, ...]
    a: tuple[float, ...]
    alpha: tuple[float, ...]
    # Per-joint limits from the data sheets (rad, rad/s). The elbow is kept to +-pi by default because
    # past that the forearm folds into the upper arm; configs may narrow any of these further.
    joint_lower: tuple[float, ...]
    joint_upper: tuple[float, ...]
    max_joint_speed: tuple[float, ...]
    reach: float  # metres
    payload: float  # kg
    # Link radii (m) for the capsule collision model, base..wrist3.
    link_radius: tuple[float, ...]


_UR_ALPHA = (PI / 2, 0.0, 0.0, PI / 2, -PI / 2, 0.0)
_LIM_LO = (-2 * PI, -2 * PI, -PI, -2 * PI, -2 * PI, -2 * PI)
_LIM_HI = (2 * PI, 2 * PI, PI, 2 * PI, 2 * PI, 2 * PI)

UR_MODELS: dict[str, URModel] = {
    "ur3e": URModel(
        "ur3e",
        d=(0.15185, 0.0, 0.0, 0.13105, 0.08535, 0.0921),
        a=(0.0, -0.24355, -0.2132, 0.0, 0.0, 0.0),
        alpha=_UR_ALPHA,
        joint_lower=_LIM_LO,
        joint_upper=_LIM_HI,
        max_joint_speed=(PI, PI, PI, 2 * PI, 2 * PI, 2 * PI),
        reach=0.5,
        payload=3.0,
        link_radius=(0.045, 0.045, 0.038, 0.032, 0.032, 0.032),
    ),
    "ur5e": URModel(
        "ur5e",
        d=(0.1625, 0.0, 0.0, 0.1333, 0.0997, 0.0996),
        a=(0.0, -0.425, -0.3922, 0.0, 0.0, 0.0),
        alpha=_UR_ALPHA,
        joint_lower=_LIM_LO,
        joint_upper=_LIM_HI,
        max_joint_speed=(PI,) * 6,
        reach=0.85,
        payload=5.0,
        link_radius=(0.06, 0.055, 0.045, 0.04, 0.04, 0.04),
    ),
    "ur10e": URModel(
        "ur10e",
        d=(0.1807, 0.0, 0.0, 0.17415, 0.11985, 0.11655),
        a=(0.0, -0.6127, -0.57155, 0.0, 0.0, 0.0),
        alpha=_UR_ALPHA,
        joint_lower=_LIM_LO,
        joint_upper=_LIM_HI,
        max_joint_speed=(2 * PI / 3, 2 * PI / 3, PI, PI, PI, PI),
        reach=1.3,
        payload=12.5,
        link_radius=(0.08, 0.075, 0.06, 0.045, 0.045, 0.045),
    ),
}


def ur_model(name: str) -> URModel:
    try:
        return UR_MODELS[name.lower()]
    except KeyError:
        raise ValueError(f"robot model {name!r}: expected one of {sorted(UR_MODELS)}") from None


def dh_transform(theta: float, d: float, a: float, alpha: float) -> np.ndarray:
    ct, st, ca, sa = np.cos(theta), np.sin(theta), np.cos(alpha), np.sin(alpha)
    return np.array(
        [
            [ct, -st * ca, st * sa, a * ct],
            [st, ct * ca, -ct * sa, a * st],
            [0.0, sa, ca, d],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )


def fk_frames(model: URModel, q: np.ndarray) -> list[np.ndarray]:
    """Poses of DH frames 0..6 in the base frame (7 transforms; the last is the flange)."""
    T = np.eye(4)
    frames = [T]
    for i in range(6):
        T = T @ dh_transform(float(q[i]), model.d[i], model.a[i], model.alpha[i])
        frames.append(T)
    return frames


def fk_flange(model: URModel, q: np.ndarray) -> np.ndarray:
    """T_base_flange for joint angles q (radians)."""
    return fk_frames(model, q)[-1]


def fk_flange_batch(model: URModel, Q: np.ndarray) -> np.ndarray:
    """T_base_flange (N, 4, 4) for joint rows Q (N, 6): the DH chain of fk_frames, vectorised over the rows."""
    Q = np.asarray(Q, float).reshape(-1, 6)
    n = len(Q)
    T = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
    for i in range(6):
        ct, st = np.cos(Q[:, i]), np.sin(Q[:, i])
        ca, sa = np.cos(model.alpha[i]), np.sin(model.alpha[i])
        A = np.zeros((n, 4, 4))
        A[:, 0, 0], A[:, 0, 1], A[:, 0, 2], A[:, 0, 3] = ct, -st * ca, st * sa, model.a[i] * ct
        A[:, 1, 0], A[:, 1, 1], A[:, 1, 2], A[:, 1, 3] = st, ct * ca, -ct * sa, model.a[i] * st
        A[:, 2, 1], A[:, 2, 2], A[:, 2, 3] = sa, ca, model.d[i]
        A[:, 3, 3] = 1.0
        T = T @ A
    return T


def link_segments(model: URModel, q: np.ndarray) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """Capsules (start, end, radius) in the base frame that cover the arm's links.

    UR links are offset from the DH origins (shoulder and elbow offsets along the joint axes), so each
    segment runs between points on the real link axes: enough for a conservative collision model.
    """
    F = fk_frames(model, q)
    p = [f[:3, 3] for f in F]
    z = [f[:3, 2] for f in F]
    r = model.link_radius
    sh = model.d[3] + 0.0  # lateral offset of the shoulder/elbow link axes (approximately d4)
    segs = [
        (p[0], p[1], r[0]),  # base column
        (p[1], p[1] + z[1] * sh, r[1]),  # shoulder housing
        (p[1] + z[1] * sh, p[2] + z[1] * sh, r[1]),  # upper arm
        (p[2] + z[2] * sh * 0.3, p[3] + z[2] * sh * 0.3, r[2]),  # forearm
        (p[3], p[4], r[3]),  # wrist 1
        (p[4], p[5], r[4]),  # wrist 2
        (p[5], p[6], r[5]),  # wrist 3
    ]
    return segs
