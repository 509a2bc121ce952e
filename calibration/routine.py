"""The eye-in-hand capture routine: look at the board once, plan N varied viewpoints around it that the arm can
reach without touching the cell, visit each through the Arm interface (so the safety limits apply), detect the
board, then solve with Park–Martin and report residuals.

Steps:
1. First look from where the arm stands: the board pose there and the nominal mount (config) give a rough
   ``T_base_board``.
2. Viewpoints: camera poses on a cone around the board's normal (distance, tilt and roll ranges), each turned
   into joints by a local IK seeded at the start pose; kept when the whole board projects inside the image with
   a margin, the joints are inside the limits, the TCP inside the workspace, and the arm's capsules clear the
   cell boxes. A greedy farthest-point pick in orientation keeps the rotations (and so their axes) varied,
   which is what conditions the rotation solve.
3. Visit in nearest-neighbour order, checking the straight joint path for clearance, capture, detect (gated).
4. Park–Martin on all pairs with MAD outlier rejection, then (by default) a refinement of X and the board pose
   on the corner pixels of the retained views (calibration/refine.py); residuals and board spread of the result.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from kitchenbot.calibration.board import BoardDetectionError, BoardDetector, CharucoSpec
from kitchenbot.calibration.park_martin import DegenerateSetError
from kitchenbot.calibration.refine import Refinement, refine_reprojection
from kitchenbot.calibration.residuals import HandEyeResult, evaluate, solve_robust
from kitchenbot.drivers.arm import Arm
from kitchenbot.drivers.camera import Camera, Frame
from kitchenbot.drivers.errors import LimitViolation
from kitchenbot.drivers.safety import SafetyLimits
from kitchenbot.drivers.ur_kinematics import URModel, fk_flange, fk_frames, link_segments
from kitchenbot.transforms import inv, make_T, transform_points


@dataclass
class RoutineSettings:
    samples: int = 15
    distance_m: tuple[float, float] = (0.33, 0.50)  # camera to board centre
    tilt_deg: tuple[float, float] = (15.0, 45.0)  # optical axis vs. the board's normal
    roll_deg: float = 90.0  # +- rotation about the optical axis
    image_margin_px: float = 20.0
    candidates: int = 150
    max_joint_offset: float = 1.6  # rad from the start pose per joint: stay in the start's IK branch
    clearance_m: float = 0.02  # arm capsules to cell boxes
    speed: float = 0.6  # rad/s, fastest joint
    accel: float = 1.2  # rad/s^2
    min_corners: int = 12
    max_rms_px: float = 1.0
    refine: bool = True  # refine Park–Martin's X on the corner pixels (calibration/refine.py)


# ---- geometry -------------------------------------------------------------------------------------------------
def look_at(eye: np.ndarray, target: np.ndarray, roll: float = 0.0) -> np.ndarray:
    """T_base_cam of an OpenCV camera (z forward, y down) at `eye` looking at `target`, rolled about its axis."""
    z = np.asarray(target, float) - np.asarray(eye, float)
    z /= np.linalg.norm(z)
    helper = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.column_stack([x, y, z]) @ Rotation.from_euler("z", roll).as_matrix()
    return make_T(R, eye)


def ik_flange(model: URModel, T_base_flange: np.ndarray, q_seed: np.ndarray, lower: np.ndarray,
              upper: np.ndarray, tol_m: float = 1e-5, tol_rad: float = 1e-4, iters: int = 60) -> np.ndarray | None:
    """Joints reaching `T_base_flange` near `q_seed` within [lower, upper], or None.

    Damped least squares on the geometric Jacobian of the DH chain, clipped to the bounds each step. A local
    solver is all the routine needs (viewpoints stay in the start pose's IK branch) and it keeps calibration
    depending on the drivers' kinematics only, like the arrows in DESIGN.md.
    """
    R_t, p_t = T_base_flange[:3, :3], T_base_flange[:3, 3]
    q = np.clip(np.asarray(q_seed, float), lower, upper)
    lam2 = 1e-4
    checkpoint = np.inf
    for it in range(iters):
        F = fk_frames(model, q)
        T = F[-1]
        ep = p_t - T[:3, 3]
        er = Rotation.from_matrix(R_t @ T[:3, :3].T).as_rotvec()
        if np.linalg.norm(ep) < tol_m and np.linalg.norm(er) < tol_rad:
            return q
        if it % 10 == 0:  # every 10 steps the error must at least halve, else the target is out of reach
            err = float(np.linalg.norm(ep) + 0.2 * np.linalg.norm(er))
            if it >= 20 and err > 0.5 * checkpoint:
                return None
            checkpoint = err
        z = np.array([f[:3, 2] for f in F[:6]])
        o = np.array([f[:3, 3] for f in F[:6]])
        J = np.vstack([np.cross(z, T[:3, 3] - o).T, z.T])
        dq = J.T @ np.linalg.solve(J @ J.T + lam2 * np.eye(6), np.concatenate([ep, er]))
        n = np.abs(dq).max()
        if n > 0.5:  # trust region: large steps jump between IK branches
            dq *= 0.5 / n
        q = np.clip(q + dq, lower, upper)
    return None


def clears_cell(model: URModel, q: np.ndarray, boxes: Sequence, clearance: float,
                extra: Sequence[tuple[np.ndarray, float]] = ()) -> bool:
    """True when the arm's capsules (links 2..6, plus `extra` (point-in-flange, radius) spheres such as the
    camera and gripper) keep `clearance` from every axis-aligned cell box. The base column is skipped: it
    stands on the counter."""
    segs = link_segments(model, q)[1:]
    pts, rad = [], []
    for a, b, r in segs:
        n = max(2, int(np.linalg.norm(b - a) / 0.03) + 1)
        s = np.linspace(0.0, 1.0, n)[:, None]
        pts.append(a + s * (b - a))
        rad.append(np.full(n, r))
    if extra:
        F = fk_flange(model, q)
        pts.append(transform_points(F, np.array([p for p, _ in extra])))
        rad.append(np.array([r for _, r in extra]))
    P, Rr = np.concatenate(pts), np.concatenate(rad) + clearance
    for box in boxes:
        d = np.maximum(np.maximum(box.lower - P, P - box.upper), 0.0)
        if np.any(np.linalg.norm(d, axis=1) < Rr):
            return False
    return True


def tool_spheres(T_flange_tcp: np.ndarray, T_flange_cam: np.ndarray, radius: float = 0.075,
                 camera_radius: float = 0.045) -> list[tuple[np.ndarray, float]]:
    """Conservative spheres (point in flange, radius) along the tool from the flange to 1 cm past the TCP, and
    one around the camera, for :func:`clears_cell`."""
    tip = T_flange_tcp[:3, 3] * (1.0 + 0.01 / max(np.linalg.norm(T_flange_tcp[:3, 3]), 1e-9))
    n = max(2, int(np.linalg.norm(tip) / (radius / 2)) + 1)
    out = [(s * tip, radius) for s in np.linspace(0.0, 1.0, n)]
    out.append((np.asarray(T_flange_cam, float)[:3, 3], camera_radius))
    return out


def path_clears_cell(model: URModel, q0: np.ndarray, q1: np.ndarray, boxes: Sequence, clearance: float,
                     extra: Sequence[tuple[np.ndarray, float]] = (), step: float = 0.05,
                     limits: SafetyLimits | None = None) -> bool:
    """Clearance (and, given `limits`, the TCP workspace) along the straight joint-space path that
    move_joints executes, every `step` rad."""
    n = max(2, int(np.max(np.abs(q1 - q0)) / step) + 1)
    for s in np.linspace(0, 1, n):
        q = q0 + s * (q1 - q0)
        if limits is not None and not limits.workspace.contains((fk_flange(model, q) @ limits.T_flange_tcp)[:3, 3]):
            return False
        if not clears_cell(model, q, boxes, clearance, extra):
            return False
    return True


def board_in_view(T_cam_board: np.ndarray, spec: CharucoSpec, K: np.ndarray, size: tuple[int, int],
                  margin_px: float) -> bool:
    """The whole board (outer corners) in front of the camera and inside the image with a margin."""
    w, h = spec.size_m
    corners = transform_points(T_cam_board, np.array([[0, 0, 0], [w, 0, 0], [w, h, 0], [0, h, 0.0]]))
    if np.any(corners[:, 2] < 0.05):
        return False
    uv = (K @ corners.T).T
    uv = uv[:, :2] / uv[:, 2:]
    return bool(np.all(uv >= margin_px) and np.all(uv[:, 0] <= size[0] - margin_px)
                and np.all(uv[:, 1] <= size[1] - margin_px))


def _select_diverse(cands: list[tuple[np.ndarray, np.ndarray]], n: int, rng: np.random.Generator) -> list[int]:
    """Greedy farthest-point selection on camera orientation (geodesic angle) with a little position."""
    if len(cands) <= n:
        return list(range(len(cands)))
    R = Rotation.from_matrix(np.array([T[:3, :3] for _, T in cands]))
    p = np.array([T[:3, 3] for _, T in cands])
    chosen = [int(rng.integers(len(cands)))]
    dmin = np.full(len(cands), np.inf)
    while len(chosen) < n:
        last = chosen[-1]
        ang = np.linalg.norm((R[last].inv() * R).as_rotvec(), axis=1)
        d = ang + 0.5 * np.linalg.norm(p - p[last], axis=1)
        dmin = np.minimum(dmin, d)
        dmin[chosen] = -1.0
        chosen.append(int(np.argmax(dmin)))
    return chosen


@dataclass
class Viewpoint:
    q: np.ndarray
    T_base_cam: np.ndarray  # planned (with the nominal mount)


def plan_viewpoints(
    model: URModel,
    limits: SafetyLimits,
    q_start: np.ndarray,
    T_flange_cam: np.ndarray,
    T_base_board: np.ndarray,
    spec: CharucoSpec,
    K: np.ndarray,
    size: tuple[int, int],
    settings: RoutineSettings,
    rng: np.random.Generator,
    boxes: Sequence = (),
    extra: Sequence[tuple[np.ndarray, float]] = (),
) -> list[Viewpoint]:
    """Up to `settings.samples` reachable, collision-free viewpoints that see the whole board, in visiting
    order from `q_start`. `T_flange_cam` is the nominal mount (the routine's guess, not the answer)."""
    w, h = spec.size_m
    centre = transform_points(T_base_board, np.array([[w / 2, h / 2, 0.0]]))[0]
    normal = -T_base_board[:3, 2]  # board z points into the board; its front faces -z
    lower = np.maximum(limits.joint_lower, q_start - settings.max_joint_offset)
    upper = np.minimum(limits.joint_upper, q_start + settings.max_joint_offset)
    X_inv = inv(T_flange_cam)
    cands: list[tuple[np.ndarray, np.ndarray]] = []
    q_seed = np.asarray(q_start, float)
    t_lo, t_hi = np.deg2rad(settings.tilt_deg)
    for _ in range(settings.candidates):
        # A direction on the cone band around the normal, uniform in azimuth.
        tilt = rng.uniform(t_lo, t_hi)
        az = rng.uniform(0, 2 * np.pi)
        a = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0])
        a /= np.linalg.norm(a)
        b = np.cross(normal, a)
        d = np.cos(tilt) * normal + np.sin(tilt) * (np.cos(az) * a + np.sin(az) * b)
        eye = centre + rng.uniform(*settings.distance_m) * d
        # Aim near (not exactly at) the centre so the board also moves across the image.
        aim = centre + rng.normal(0.0, 0.015, 3)
        T_base_cam = look_at(eye, aim, rng.uniform(-1, 1) * np.deg2rad(settings.roll_deg))
        if not board_in_view(inv(T_base_cam) @ T_base_board, spec, K, size, settings.image_margin_px):
            continue
        q = ik_flange(model, T_base_cam @ X_inv, q_seed, lower, upper)
        if q is None:
            continue
        try:
            limits.check_configuration(model, q, "calibration viewpoint")
        except LimitViolation:
            continue
        if boxes and not clears_cell(model, q, boxes, settings.clearance_m, extra):
            continue
        cands.append((q, T_base_cam))
    picked = [cands[k] for k in _select_diverse(cands, settings.samples, rng)]
    # Visit order: nearest neighbour in joint space, keeping only hops whose straight path clears the cell.
    order: list[Viewpoint] = []
    cur = np.asarray(q_start, float)
    left = list(picked)
    while left:
        dist = [np.max(np.abs(q - cur)) for q, _ in left]
        for k in np.argsort(dist):
            q, T = left[k]
            if path_clears_cell(model, cur, q, boxes, settings.clearance_m, extra, limits=limits):
                order.append(Viewpoint(q, T))
                cur = q
                left.pop(int(k))
                break
        else:
            break  # the rest cannot be reached by a straight joint move from here: drop them
    return order


# ---- capture ----------------------------------------------------------------------------------------------------
@dataclass
class CaptureRecord:
    index: int
    q: np.ndarray
    T_base_flange: np.ndarray
    T_cam_board: np.ndarray | None
    n_corners: int = 0
    rms_px: float = float("nan")
    error: str | None = None
    object_points: np.ndarray | None = field(default=None, repr=False)  # (N, 3) board frame
    image_points: np.ndarray | None = field(default=None, repr=False)  # (N, 2) px
    K: np.ndarray | None = field(default=None, repr=False)


@dataclass
class RoutineReport:
    records: list[CaptureRecord]
    result: HandEyeResult
    T_base_board_guess: np.ndarray
    viewpoints_planned: int
    notes: list[str] = field(default_factory=list)
    park_martin: HandEyeResult | None = None  # before refinement (the same as `result` without it)
    refinement: Refinement | None = None

    @property
    def samples(self) -> tuple[list[np.ndarray], list[np.ndarray]]:
        ok = [r for r in self.records if r.T_cam_board is not None]
        return [r.T_base_flange for r in ok], [r.T_cam_board for r in ok]


def capture_here(arm: Arm, camera: Camera, detector: BoardDetector, index: int,
                 dist: np.ndarray | None = None) -> tuple[CaptureRecord, Frame]:
    """Capture once where the arm stands and detect the board (failures are recorded, not raised)."""
    q = arm.joint_positions()
    F = arm.flange_pose()
    frame = camera.capture()
    try:
        pose = detector.pose(frame.rgb, frame.K, dist)
    except BoardDetectionError as e:
        return CaptureRecord(index, q, F, None, error=str(e)), frame
    return CaptureRecord(index, q, F, pose.T_cam_board, pose.n_corners, pose.rms_px, None, pose.object_points,
                         pose.image_points, frame.K), frame


def run_routine(
    arm: Arm,
    camera: Camera,
    spec: CharucoSpec,
    T_flange_cam_nominal: np.ndarray,
    settings: RoutineSettings | None = None,
    seed: int = 0,
    boxes: Sequence = (),
    extra: Sequence[tuple[np.ndarray, float]] = (),
    dist: np.ndarray | None = None,
    progress: Callable[[CaptureRecord], None] | None = None,
) -> RoutineReport:
    """Eye-in-hand calibration from where the arm stands (the board must be in view there).

    `T_flange_cam_nominal` (the mechanical drawing or the config) only steers the viewpoints; the answer comes
    from the captures. `boxes` are the cell's obstacles (base frame); `extra` adds (point in flange, radius)
    spheres for the tool and camera. Returns to the start pose at the end.
    """
    settings = settings or RoutineSettings()
    rng = np.random.default_rng(seed)
    detector = BoardDetector(spec, settings.min_corners, settings.max_rms_px)
    q_start = arm.joint_positions()
    first, frame = capture_here(arm, camera, detector, 0, dist)
    if first.T_cam_board is None:
        raise BoardDetectionError(f"the board is not in view from the start pose: {first.error}")
    records = [first]
    if progress:
        progress(first)
    T_base_board = first.T_base_flange @ T_flange_cam_nominal @ first.T_cam_board
    views = plan_viewpoints(arm.model, arm.limits, q_start, T_flange_cam_nominal, T_base_board, spec, frame.K,
                            frame.size, settings, rng, boxes, extra)
    notes = []
    if len(views) < settings.samples:
        notes.append(f"planned {len(views)} of {settings.samples} viewpoints (the rest were unreachable, "
                     "out of view or too close to the cell)")
    for k, v in enumerate(views, start=1):
        arm.move_joints(v.q, speed=settings.speed, accel=settings.accel)
        rec, _ = capture_here(arm, camera, detector, k, dist)
        records.append(rec)
        if progress:
            progress(rec)
    # Back to the start: straight if that path is clear, else retracing the visited viewpoints.
    back = [q_start]
    if views and not path_clears_cell(arm.model, views[-1].q, q_start, boxes, settings.clearance_m, extra,
                                      limits=arm.limits):
        back = [v.q for v in reversed(views[:-1])] + [q_start]
    for q in back:
        arm.move_joints(q, speed=settings.speed, accel=settings.accel)
    ok = [r for r in records if r.T_cam_board is not None]
    if len(ok) < 3:
        raise DegenerateSetError(f"too few samples: only {len(ok)} of {len(records)} captures found the board")
    F, C = [r.T_base_flange for r in ok], [r.T_cam_board for r in ok]
    park_martin = solve_robust(F, C, "eye_in_hand")
    result, refinement = park_martin, None
    if settings.refine:
        used = [ok[k] for k in park_martin.samples_used]
        refinement = refine_reprojection(park_martin.X, park_martin.spread.mean, [r.T_base_flange for r in used],
                                         [r.object_points for r in used], [r.image_points for r in used],
                                         used[0].K, dist, "eye_in_hand")
        result = evaluate(refinement.X, F, C, "eye_in_hand", park_martin.pairs_used, park_martin.pairs_rejected,
                          method="park_martin_1994+reprojection")
    return RoutineReport(records, result, T_base_board, len(views), notes, park_martin, refinement)
