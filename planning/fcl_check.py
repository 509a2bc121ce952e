"""Independent re-check of planned paths with python-fcl.

Built from the same geometry *descriptions* as the planner (link capsules from ``planning.collision
.link_capsules``, the gripper boxes, the cell boxes, the object meshes, voxel centres) but with its own
kinematics (the numpy DH code in ``drivers.ur_kinematics``, not Pinocchio), its own collision library (FCL,
not coal), its own sampling bound, and zero margin: it answers "does anything actually touch?" along every
trajectory, sampled so that no point moves more than ``step`` (2 mm) between checks.

Allowed contacts mirror what a grasp needs: named (part, other) pairs (e.g. the pads and the grasped
object), and contacts present at the start of a segment, which may persist for its first ``start_travel``
metres of TCP travel (lifting an object off what it rests on). Used by the tests and ``kitchenbot bench
planning``.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import fcl
import numpy as np

from kitchenbot.drivers.ur_kinematics import URModel, fk_frames
from kitchenbot.planning.collision import GripperGeometry, link_capsules
from kitchenbot.transforms import make_T, rot_z
from kitchenbot.world.cell import Cell
from kitchenbot.world.inventory import ObjectModel

TOOL = ("palm", "pad_a", "pad_b", "camera")


@dataclass
class CheckResult:
    ok: bool
    index: int = -1  # dense sample index of the first contact
    pair: tuple[str, str] | None = None
    samples: int = 0

    def __str__(self) -> str:
        return "collision-free" if self.ok else f"contact {self.pair} at sample {self.index}"


def _tf(T: np.ndarray) -> fcl.Transform:
    return fcl.Transform(np.asarray(T[:3, :3], float), np.asarray(T[:3, 3], float))


def _capsule_local(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    d = b - a
    L = float(np.linalg.norm(d))
    z = d / L if L > 1e-9 else np.array([0.0, 0.0, 1.0])
    h = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(h, z)
    x /= np.linalg.norm(x)
    return make_T(np.stack([x, np.cross(z, x), z], axis=1), (a + b) / 2)


class FclChecker:
    """Zero-margin path checker over capsules, boxes and meshes (python-fcl)."""

    def __init__(self, robot, cell: Cell, T_flange_cam: np.ndarray | None, gripper: GripperGeometry | None = None):
        # `robot` is used only for its DH parameters, tool transform and capsule list, not its Pinocchio model
        self.ur: URModel = robot.ur
        self.T_flange_tcp = np.asarray(robot.T_flange_tcp, float)
        self.T_flange_cam = None if T_flange_cam is None else np.asarray(T_flange_cam, float)
        self.gripper = gripper or GripperGeometry()
        self.cell = cell
        self.parts: list[tuple[str, int, fcl.CollisionGeometry, np.ndarray]] = []  # name, joint, geom, T_joint_geom
        for c in link_capsules(robot):
            a, b = np.asarray(c.a, float), np.asarray(c.b, float)
            self.parts.append((c.name, c.joint, fcl.Capsule(c.radius, float(np.linalg.norm(b - a))), _capsule_local(a, b)))
        self.env_static = [(f"cell:{b.name}", fcl.Box(*b.size), make_T(t=b.centre)) for b in cell.boxes]
        self._bvh: dict[int, fcl.BVHModel] = {}
        ur = self.ur
        tool_reach = float(np.linalg.norm(self.T_flange_tcp[:3, 3])) + 0.05
        self._chain = [abs(ur.a[k]) + abs(ur.d[k]) for k in range(6)]
        self._tool_reach = tool_reach

    def _mesh(self, model: ObjectModel) -> fcl.BVHModel:
        key = id(model.mesh)
        if key not in self._bvh:
            V = np.asarray(model.mesh.vertices, float)
            F = np.asarray(model.mesh.triangles, np.int32)
            m = fcl.BVHModel()
            m.beginModel(len(V), len(F))
            m.addSubModel(V, F)
            m.endModel()
            self._bvh[key] = m
        return self._bvh[key]

    # ---- kinematics (numpy DH) ---------------------------------------------------------------------------------
    def _joint_frames(self, q: np.ndarray) -> list[np.ndarray]:
        """T_base_joint_i for i = 1..6: DH frame i-1 turned by q_i (the convention of the capsule list)."""
        F = fk_frames(self.ur, q)
        return [F[i] @ rot_z(float(q[i])) for i in range(6)], F[6]

    def _reach(self, held_extent: float) -> np.ndarray:
        tail = np.cumsum(self._chain[::-1])[::-1]
        return tail + self._tool_reach + held_extent + 0.14  # + shoulder/elbow offsets

    # ---- checking ------------------------------------------------------------------------------------------------
    def check_path(
        self,
        Q: np.ndarray,
        *,
        objects: Sequence[tuple[str, ObjectModel, np.ndarray]] = (),
        voxels: np.ndarray | None = None,
        voxel_size: float = 0.02,
        held: tuple[ObjectModel, np.ndarray] | None = None,
        opening: float = 0.1,
        allowed: Iterable[tuple[str, str]] = (),
        start_travel: float = 0.0,
        step: float = 0.002,
        boxes: Sequence = (),
    ) -> CheckResult:
        """Check the joint polyline Q (rows) densely. `objects`: (name, model, T_base_obj), named like the
        planner's ``obj:<name>``; `held`: (model, T_tcp_obj); `allowed`: (part, other) pairs never reported."""
        Q = np.asarray(Q, float)
        allowed = {tuple(p) for p in allowed} | {(b, a) for a, b in allowed}
        env = list(self.env_static) + [(f"cell:{b.name}", fcl.Box(*b.size), make_T(t=b.centre)) for b in boxes]
        for name, model, T in objects:
            env.append((f"obj:{name}", self._mesh(model), np.asarray(T, float)))
        if voxels is not None and len(voxels):
            for k, c in enumerate(np.asarray(voxels, float)):
                env.append((f"voxel:{k}", fcl.Box(voxel_size, voxel_size, voxel_size), make_T(t=c)))
        env_objs = [(n, fcl.CollisionObject(g, _tf(T))) for n, g, T in env]
        tool = [(tb.name, fcl.Box(*tb.size), tb.T_flange_box)
                for tb in self.gripper.tool_boxes(self.T_flange_tcp, self.T_flange_cam, opening)]
        held_geom = None
        held_extent = 0.0
        if held is not None:
            hm, T_tcp_obj = held
            held_geom = (self._mesh(hm), self.T_flange_tcp @ np.asarray(T_tcp_obj, float))
            held_extent = float(np.linalg.norm(T_tcp_obj[:3, 3])) + hm.diameter / 2
        r = self._reach(held_extent)
        # dense samples
        dense = [Q[:1]]
        for k in range(len(Q) - 1):
            n = max(1, int(np.ceil(float(np.sum(r * np.abs(Q[k + 1] - Q[k]))) / step)))
            dense.append(Q[k] + (np.arange(1, n + 1)[:, None] / n) * (Q[k + 1] - Q[k]))
        D = np.vstack(dense)
        req = fcl.CollisionRequest()
        start_contacts: set[tuple[str, str]] = set()
        p_start = None
        for idx, q in enumerate(D):
            J, T_flange = self._joint_frames(q)
            robot_objs = [(n, j, fcl.CollisionObject(g, _tf(J[j - 1] @ T))) for n, j, g, T in self.parts]
            robot_objs += [(n, 7, fcl.CollisionObject(g, _tf(T_flange @ T))) for n, g, T in tool]
            if held_geom is not None:
                robot_objs.append(("held", 7, fcl.CollisionObject(held_geom[0], _tf(T_flange @ held_geom[1]))))
            tcp = (T_flange @ self.T_flange_tcp)[:3, 3]
            if p_start is None:
                p_start = tcp
            in_start_window = start_travel > 0 and np.linalg.norm(tcp - p_start) <= start_travel
            contacts = self._contacts(robot_objs, env_objs, req, allowed)
            if idx == 0 and start_travel > 0:
                start_contacts = set(contacts)
                continue
            for c in contacts:
                if in_start_window and c in start_contacts:
                    continue
                return CheckResult(False, idx, c, len(D))
        return CheckResult(True, -1, None, len(D))

    @staticmethod
    def _self_pair_checked(na: str, ja: int, nb: str, jb: int) -> bool:
        """Self-collision rules (as in planning.collision): links 2+ joints apart, tool/held (joint 7 here) vs
        links 1..4, minus the structurally separated wrist pairs."""
        if ja == 7 and jb == 7:
            return False
        if abs(ja - jb) < 2:
            return False
        if 7 in (ja, jb):
            return min(ja, jb) <= 4
        return {ja, jb} not in ({3, 5}, {4, 6})

    def _contacts(self, robot_objs, env_objs, req, allowed) -> list[tuple[str, str]]:
        out = []
        for na, ja, oa in robot_objs:
            if na in ("link1", "link2_housing"):
                pass  # fixed above the base: checked for self-collision only
            else:
                for ne, oe in env_objs:
                    if (na, ne) in allowed:
                        continue
                    if fcl.collide(oa, oe, req, fcl.CollisionResult()):
                        out.append((na, ne))
        for i in range(len(robot_objs)):
            na, ja, oa = robot_objs[i]
            for j in range(i + 1, len(robot_objs)):
                nb, jb, ob = robot_objs[j]
                if not self._self_pair_checked(na, ja, nb, jb) or (na, nb) in allowed:
                    continue
                if fcl.collide(oa, ob, req, fcl.CollisionResult()):
                    out.append((na, nb))
        return out


# ---- plan-level helpers ---------------------------------------------------------------------------------------
def verify_pick(checker: FclChecker, planner, plan, objects, map_points=None, step: float = 0.002) -> list[tuple[str, CheckResult]]:
    """Re-check every segment of a PickPlan in its own situation; returns [(segment, result)]."""
    from kitchenbot.planning.grasps import object_name
    from kitchenbot.planning.pick_place import LIFT_CONTACT_TRAVEL

    g = plan.grasp
    named = [(object_name(o, k), planner.inventory[o.obj_id], o.T_base_obj) for k, o in enumerate(objects)
             if o.obj_id in planner.inventory.models]
    target = next(n for (n, _, _), o in zip(named, objects) if o is g.obj)
    others = [x for x in named if x[0] != target]
    known = [o for o in objects if o.obj_id in planner.inventory.models]
    vox = planner.world.unexplained_voxels(map_points, planner._scene_objects(known),
                                           instance_points=[o.points for o in known])
    pads = [(p, f"obj:{target}") for p in ("pad_a", "pad_b")]
    kw = dict(voxels=vox, voxel_size=planner.world.voxel_size, step=step)
    held = (planner.inventory[g.obj.obj_id], g.T_tcp_obj)
    return [
        ("approach", checker.check_path(plan.approach.q, objects=named, opening=g.spec.opening, **kw)),
        ("grasp_in", checker.check_path(plan.grasp_in.q, objects=named, opening=g.spec.opening, allowed=pads, **kw)),
        ("lift", checker.check_path(plan.lift.q, objects=others, held=held, opening=g.spec.width,
                                    start_travel=max(LIFT_CONTACT_TRAVEL, plan.lift_contact_travel), **kw)),
    ]


def verify_place(checker: FclChecker, planner, plan, grasp, objects, step: float = 0.002) -> list[tuple[str, CheckResult]]:
    """Re-check every segment of a PlacePlan (objects: the others, the held one excluded)."""
    from kitchenbot.planning.grasps import object_name

    named = [(object_name(o, k), planner.inventory[o.obj_id], o.T_base_obj) for k, o in enumerate(objects)
             if o.obj_id in planner.inventory.models and o is not grasp.obj]
    model = planner.inventory[grasp.obj.obj_id]
    held = (model, grasp.T_tcp_obj)
    T_rest = plan.T_base_obj.copy()
    T_rest[2, 3] = min(T_rest[2, 3], float(plan.target.T_base_obj[2, 3]))  # it fell by the release drop
    placed = ("placed", model, T_rest)
    pads = [(p, "obj:placed") for p in ("pad_a", "pad_b")]
    return [
        ("transfer", checker.check_path(plan.transfer.q, objects=named, held=held, opening=grasp.spec.width, step=step)),
        ("lower", checker.check_path(plan.lower.q, objects=named, held=held, opening=grasp.spec.width, step=step)),
        ("retreat", checker.check_path(plan.retreat.q, objects=[*named, placed],
                                       opening=plan.release_opening if plan.release_opening is not None
                                       else grasp.spec.opening,
                                       allowed=pads, step=step)),
    ]
