"""The simulator's own collision checker (python-fcl), independent of the planner's (coal via Pinocchio).

FakeArm asks it, before a motion starts, whether the swept path would hit something; a hit becomes a
protective stop just before the contact, like a real UR detecting the impact. Geometry:

- arm links: the capsules of :func:`drivers.ur_kinematics.link_segments` (the base column is fixed to the
  counter and is only used for self-collision);
- the gripper (world.gripper.FINGERS, TCP frame): a palm box from the flange and two finger boxes whose
  inner faces (the pads) sit at +-opening/2 along y; the wrist camera's housing at ``world.T_flange_cam``;
- the held object: its mesh (BVH) at ``T_base_tcp @ T_tcp_held``;
- the world: the cell's boxes and every other object's mesh.

Allowed contacts (so that grasping and lifting are possible; documented choice, no explicit allow-list):
- the fingers may touch an object while the TCP is within ``grasp_contact_radius`` (3 cm) of that object's
  surface: the pads close around what they are about to grasp, or open away from what they just released;
- the fingers and the held object may stay in the contacts they already had at the start of a motion while
  the contact lasts without a break, for at most ``start_contact_travel`` (10 cm) of their travel: lifting an
  object off, or out of, the one it rests on or is nested in (resting meshes touch or overlap slightly); once
  a pair separates, touching again is a collision;
- self-collision is checked between non-adjacent links only; the gripper and camera (rigid with the flange)
  are checked against the links up to wrist 1 (wrist 2 and 3 carry them).

Why hand-written: FCL does the geometry; what it does not do is the robot-specific bookkeeping (which part is
what, adjacency, the contact rules above, path sampling at a bounded Cartesian step).
"""

from __future__ import annotations

from dataclasses import dataclass

import fcl
import numpy as np

from kitchenbot.drivers.ur_kinematics import URModel, fk_frames, link_segments
from kitchenbot.world.gripper import FINGERS, FingerGeometry

LINK_NAMES = ("base", "shoulder", "upper_arm", "forearm", "wrist1", "wrist2", "wrist3")


@dataclass
class Contact:
    """First disallowed contact found along a path."""

    index: int  # sample index
    part: str  # robot part: a link name, palm, finger_pos/neg, held
    other: str  # cell box name, object 'obj:<uid>', or a link name (self-collision)

    def __str__(self) -> str:
        return f"{self.part} hits {self.other}"


@dataclass
class _Env:
    name: str
    obj: fcl.CollisionObject
    lo: np.ndarray
    hi: np.ndarray
    uid: int | None  # object uid, None for cell boxes


def _frame_from_segment(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """A rotation whose z axis runs from a to b, the midpoint, and the length (fcl capsules lie along z)."""
    d = b - a
    L = float(np.sqrt(d @ d))
    z = d / L if L > 1e-9 else np.array([0.0, 0.0, 1.0])
    # x = normalize(helper x z) with helper = e_x or e_y, written out (np.cross is slow on 3-vectors)
    if abs(z[0]) < 0.9:
        x = np.array([0.0, -z[2], z[1]])
    else:
        x = np.array([z[2], 0.0, -z[0]])
    x /= np.sqrt(x @ x)
    y = np.array([z[1] * x[2] - z[2] * x[1], z[2] * x[0] - z[0] * x[2], z[0] * x[1] - z[1] * x[0]])
    R = np.empty((3, 3))
    R[:, 0], R[:, 1], R[:, 2] = x, y, z
    return R, (a + b) / 2, L


def _aabb_of_points(P: np.ndarray, pad: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    return P.min(axis=0) - pad, P.max(axis=0) + pad


def _box_corners(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])


class SimCollision:
    """Collision queries on a SimWorld for arm configurations and paths."""

    def __init__(self, world, model: URModel | None = None, gripper: FingerGeometry | None = None,
                 grasp_contact_radius: float = 0.03, start_contact_travel: float = 0.10,
                 camera_size: tuple[float, float, float] | None = (0.091, 0.028, 0.025)):
        """`camera_size`: the wrist camera's housing (x along the stereo baseline, z along the view), placed
        at ``world.T_flange_cam`` behind the optical centre; None leaves the camera out."""
        self.world = world
        self.camera_size = None if camera_size is None else np.asarray(camera_size, float)
        self.model = model or world.robot
        self.gripper = gripper or FINGERS
        self.grasp_contact_radius = float(grasp_contact_radius)
        self.start_contact_travel = float(start_contact_travel)
        self._req = fcl.CollisionRequest()
        self._bvh: dict[int, tuple[object, fcl.BVHModel]] = {}
        self._cell: list[_Env] = []
        for b in world.cell.boxes:
            o = fcl.CollisionObject(fcl.Box(*b.size), fcl.Transform(np.eye(3), b.centre))
            self._cell.append(_Env(b.name, o, b.lower.copy(), b.upper.copy(), None))
        for name, fx in getattr(world, "fixtures", {}).items():  # faucet, drain, rack: fixed like the cell
            V = np.asarray(fx.mesh.vertices, float)
            bvh = fcl.BVHModel()
            bvh.beginModel(len(V), len(fx.mesh.triangles))
            bvh.addSubModel(V, np.asarray(fx.mesh.triangles, np.int32))
            bvh.endModel()
            o = fcl.CollisionObject(bvh, fcl.Transform(np.eye(3), np.zeros(3)))
            self._cell.append(_Env(f"fixture:{name}", o, V.min(0), V.max(0), None))

    # ---- geometry ----------------------------------------------------------------------------------
    def _mesh_bvh(self, model) -> fcl.BVHModel:
        hit = self._bvh.get(id(model))
        if hit is not None:
            return hit[1]
        V = np.asarray(model.mesh.vertices, float)
        F = np.asarray(model.mesh.triangles, np.int32)
        bvh = fcl.BVHModel()
        bvh.beginModel(len(V), len(F))
        bvh.addSubModel(V, F)
        bvh.endModel()
        self._bvh[id(model)] = (model, bvh)  # keeps the model alive so its id stays unique
        return bvh

    def _local_corners(self, model) -> np.ndarray:
        V = np.asarray(model.mesh.vertices)
        return _box_corners(V.min(0), V.max(0))

    def _environment(self, exclude: set[int]) -> list[_Env]:
        env = list(self._cell)
        for uid, o in self.world.objects.items():
            if uid in exclude:
                continue
            T = o.T_base_obj
            co = fcl.CollisionObject(self._mesh_bvh(o.model), fcl.Transform(T[:3, :3], T[:3, 3]))
            lo, hi = _aabb_of_points(self._local_corners(o.model) @ T[:3, :3].T + T[:3, 3])
            env.append(_Env(f"obj:{uid}", co, lo, hi, uid))
        return env

    def tool_boxes(self, opening: float) -> list[tuple[str, np.ndarray, np.ndarray]]:
        """(name, T_tcp_box (box centre), size) of the bodies rigid with the TCP: palm, fingers, camera."""
        out = []
        for name, lo, hi in self.gripper.boxes(opening):
            T = np.eye(4)
            T[:3, 3] = (lo + hi) / 2
            out.append((name, T, hi - lo))
        if self.camera_size is not None:
            T = np.linalg.inv(self.world.T_flange_tcp) @ self.world.T_flange_cam
            T = T.copy()
            T[:3, 3] -= T[:3, 2] * self.camera_size[2] / 2
            out.append(("camera", T, self.camera_size))
        return out

    def _tcp(self, frames: list[np.ndarray]) -> np.ndarray:
        return frames[-1] @ self.world.T_flange_tcp

    def keypoints(self, q: np.ndarray, opening: float, held: bool = True) -> np.ndarray:
        """Points whose motion bounds the motion of every collision body (segment ends, box corners)."""
        frames = fk_frames(self.model, q)
        pts = [p for s in link_segments(self.model, q) for p in s[:2]]
        T = self._tcp(frames)
        for _, Tb, size in self.tool_boxes(opening):
            Tw = T @ Tb
            pts.extend(_box_corners(-size / 2, size / 2) @ Tw[:3, :3].T + Tw[:3, 3])
        w = self.world
        if held and w.held_uid is not None:
            Th = T @ w.T_tcp_held
            pts.extend(self._local_corners(w.objects[w.held_uid].model) @ Th[:3, :3].T + Th[:3, 3])
        return np.asarray(pts)

    # ---- queries ---------------------------------------------------------------------------------
    def check_path(self, qs: np.ndarray, opening: float, sliding: bool = False) -> Contact | None:
        """First disallowed contact along consecutive configurations `qs` (N, 6), or None.

        The world's held object (if any) follows the TCP. Contacts at qs[0] of the fingers/held object are
        allowed while they last, up to `start_contact_travel` metres (see the module docstring).
        """
        w = self.world
        held = w.held_uid
        env = self._environment({held} if held is not None else set())
        env_box = self._env_aabb(env)
        held_co = held_corners = None
        if held is not None:
            hm = w.objects[held].model
            held_co = fcl.CollisionObject(self._mesh_bvh(hm), fcl.Transform())
            held_corners = self._local_corners(hm)
        g_boxes = self.tool_boxes(opening)
        g_objs = [fcl.CollisionObject(fcl.Box(*size), fcl.Transform()) for _, _, size in g_boxes]
        segs0 = link_segments(self.model, qs[0])
        caps = [fcl.CollisionObject(fcl.Capsule(r, float(np.linalg.norm(b - a))), fcl.Transform()) for a, b, r in segs0]

        start_contacts: set[tuple[str, str]] = set()
        start_pos: dict[str, np.ndarray] = {}
        for k, q in enumerate(qs):
            frames = fk_frames(self.model, q)
            T_tcp = self._tcp(frames)
            parts: list[tuple[str, fcl.CollisionObject, np.ndarray, np.ndarray]] = []
            # arm links
            for i, (a, b, r) in enumerate(link_segments(self.model, q)):
                R, c, _ = _frame_from_segment(a, b)
                caps[i].setTransform(fcl.Transform(R, c))
                lo, hi = _aabb_of_points(np.stack([a, b]), r)
                parts.append((LINK_NAMES[i], caps[i], lo, hi))
            # gripper boxes
            for (name, Tb, size), co in zip(g_boxes, g_objs):
                Tw = T_tcp @ Tb
                co.setTransform(fcl.Transform(Tw[:3, :3], Tw[:3, 3]))
                P = _box_corners(-size / 2, size / 2) @ Tw[:3, :3].T + Tw[:3, 3]
                parts.append((name, co, *_aabb_of_points(P)))
            if held_co is not None:
                Th = T_tcp @ w.T_tcp_held
                held_co.setTransform(fcl.Transform(Th[:3, :3], Th[:3, 3]))
                P = held_corners @ Th[:3, :3].T + Th[:3, 3]
                parts.append(("held", held_co, *_aabb_of_points(P)))

            if k == 0:
                start_pos = {p[0]: (p[2] + p[3]) / 2 for p in parts}
            seen: set[tuple[str, str]] = set()
            hit = self._first_hit(parts, env, env_box, T_tcp, k, (start_contacts, start_pos, seen))
            if hit is not None:
                return hit
            # a start contact that broke is no longer allowed; except, for an item slid along on what it rests
            # on (`sliding`, see FakeArm._press_drag), the held item's: it rides over its support's surface
            # (how deep it may go is FakeArm._drag_profile's rule)
            keep = {p for p in start_contacts if p[0] == "held"} if sliding else set()
            start_contacts &= seen | keep
        return None

    def _first_hit(self, parts, env, env_box, T_tcp, k, start) -> Contact | None:
        by_name = {p[0]: i for i, p in enumerate(parts)}
        plo = np.array([p[2] for p in parts])
        phi = np.array([p[3] for p in parts])
        # self-collision: non-adjacent links; gripper and held object against links 0..4
        ov = np.all((plo[:, None] <= phi[None]) & (plo[None] <= phi[:, None]), axis=2)
        for a, b in self._self_pairs(by_name):
            if ov[a, b] and fcl.collide(parts[a][1], parts[b][1], self._req, fcl.CollisionResult()):
                return Contact(k, parts[a][0], parts[b][0])
        # environment: every moving part except the base column (bolted to the counter)
        elo, ehi = env_box
        ov = np.all((plo[:, None] <= ehi[None]) & (elo[None] <= phi[:, None]), axis=2)
        ov[by_name["base"]] = False
        for i, j in zip(*np.nonzero(ov)):
            name, co = parts[i][0], parts[i][1]
            e = env[j]
            if not fcl.collide(co, e.obj, self._req, fcl.CollisionResult()):
                continue
            if self._allowed(name, e, T_tcp, k, start, parts[i]):
                continue
            return Contact(k, name, e.name)
        return None

    def _self_pairs(self, by_name: dict[str, int]) -> list[tuple[int, int]]:
        key = tuple(by_name)
        if getattr(self, "_pairs_key", None) != key:
            idx = [by_name[n] for n in LINK_NAMES]
            pairs = [(idx[i], idx[j]) for i in range(7) for j in range(i + 2, 7)]
            for g in ("palm", "finger_pos", "finger_neg", "camera", "held"):
                if g in by_name:
                    pairs.extend((by_name[g], idx[i]) for i in range(5))
            self._pairs_key, self._pairs = key, pairs
        return self._pairs

    @staticmethod
    def _env_aabb(env: list[_Env]) -> tuple[np.ndarray, np.ndarray]:
        return np.array([e.lo for e in env]), np.array([e.hi for e in env])

    def _allowed(self, part, e: _Env, T_tcp, k, start, this) -> bool:
        start_contacts, start_pos, seen = start
        if part in ("finger_pos", "finger_neg", "held"):
            pair = (part, e.name)
            if k == 0:
                start_contacts.add(pair)
                seen.add(pair)
                return True
            if pair in start_contacts:
                c = (this[2] + this[3]) / 2
                if np.linalg.norm(c - start_pos[part]) <= self.start_contact_travel:
                    seen.add(pair)
                    return True
        if part in ("finger_pos", "finger_neg") and e.uid is not None:
            probe = fcl.CollisionObject(fcl.Sphere(1e-4), fcl.Transform(np.eye(3), T_tcp[:3, 3]))
            res = fcl.DistanceResult()
            d = fcl.distance(probe, e.obj, fcl.DistanceRequest(), res)
            if d <= self.grasp_contact_radius:
                return True
        return False

    def check_config(self, q: np.ndarray, opening: float) -> Contact | None:
        """Disallowed contact at one configuration (start-contact allowances do not apply)."""
        saved = self.start_contact_travel
        self.start_contact_travel = -1.0
        try:
            # two identical samples: sample 0 records start contacts, sample 1 (travel 0 > -1) rejects them
            return self.check_path(np.stack([q, q]), opening)
        finally:
            self.start_contact_travel = saved


def sample_path(q_of_u, duration: float, keypoints_of_q, step: float = 0.005, max_passes: int = 4
                ) -> tuple[np.ndarray, np.ndarray]:
    """Times u in [0, duration] and configurations such that no keypoint moves more than ~`step` metres
    between consecutive samples. Refines intervals adaptively (Cartesian travel, not joint travel, bounds it).
    """
    n0 = 17
    us = list(np.linspace(0.0, duration, n0)) if duration > 0 else [0.0, 0.0]
    qs = [np.asarray(q_of_u(u), float) for u in us]
    kp = [keypoints_of_q(q) for q in qs]
    for _ in range(max_passes):
        new_us, new_qs, new_kp = [us[0]], [qs[0]], [kp[0]]
        refined = False
        for i in range(1, len(us)):
            d = float(np.max(np.linalg.norm(kp[i] - kp[i - 1], axis=1)))
            n = int(np.ceil(d / step))
            if n > 1:
                refined = True
                for j in range(1, n):
                    u = us[i - 1] + (us[i] - us[i - 1]) * j / n
                    q = np.asarray(q_of_u(u), float)
                    new_us.append(u)
                    new_qs.append(q)
                    new_kp.append(keypoints_of_q(q))
            new_us.append(us[i])
            new_qs.append(qs[i])
            new_kp.append(kp[i])
        us, qs, kp = new_us, new_qs, new_kp
        if not refined:
            break
    return np.asarray(us), np.asarray(qs)


__all__ = ["Contact", "SimCollision", "sample_path", "LINK_NAMES"]
