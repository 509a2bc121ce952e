"""Shared fixtures for the planning tests: one Planner (robot + collision world) per session; a check that the
simulated gripper holds a model with its predefined grasps; a check of a selected grasp by the independent
python-fcl checker."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.executive.config import CellConfig
from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.fcl_check import FclChecker
from kitchenbot.planning.grasp_synthesis import ensure_grasps
from kitchenbot.planning.grasps import object_name
from kitchenbot.planning.pick_place import Planner
from kitchenbot.planning.placement import SlotBook
from kitchenbot.world.inventory import Inventory


@pytest.fixture(scope="session")
def cfg() -> CellConfig:
    return CellConfig()


@pytest.fixture(scope="session")
def inventory() -> Inventory:
    return ensure_grasps(Inventory.builtin())


@pytest.fixture(scope="session")
def planner(cfg, inventory) -> Planner:
    return Planner.from_config(cfg, inventory)


@pytest.fixture(scope="session")
def grasp_check(planner, inventory):
    """check(grasp, objects, target_index) -> the independent python-fcl checker's verdict on the grasp's pre-grasp
    and grasp at zero margin, the pads allowed to touch only objects[target_index]."""
    checker = FclChecker(planner.robot, planner.cell, planner.world.T_flange_cam)

    def check(g, objects, target_index):
        named = [(object_name(o, k), inventory[o.obj_id], o.T_base_obj) for k, o in enumerate(objects)]
        pads = [(p, f"obj:{named[target_index][0]}") for p in ("pad_a", "pad_b")]
        return checker.check_path(np.stack([g.q_pregrasp, g.q]), objects=named, opening=g.spec.opening, allowed=pads)

    return check


@pytest.fixture(scope="session")
def home(cfg) -> np.ndarray:
    return np.asarray(cfg.robot.home, float)


@pytest.fixture(scope="session")
def own_b(own_dishware_b, tmp_path_factory):
    """The second own dishware set with grasps synthesised from its meshes: (inventory, {name: model})."""
    folder, names = own_dishware_b
    inv = ensure_grasps(Inventory.load(folder), tmp_path_factory.mktemp("grasps_b"))
    return inv, {name: inv[i] for i, (name, _) in names.items()}


def _resting(planner: Planner, name: str, xy, instance_id: int, upside_down: bool = False, z_floor: float | None = None) -> ObjectPose:
    """An object of the builtin inventory standing on the sink floor (or `z_floor`) at `xy`."""
    from kitchenbot.transforms import make_T, rot_x

    m = planner.inventory.by_name(name)
    lo, _ = planner.cell.sink_interior
    zf = lo[2] if z_floor is None else z_floor
    T = make_T(t=(xy[0], xy[1], zf + m.extents[2] / 2 + 0.001))
    if upside_down:
        T = T @ rot_x(np.pi)
    return ObjectPose(m.obj_id, m.cls, T, 1.0, instance_id=instance_id)


@pytest.fixture(scope="session")
def resting(planner):
    """resting(name, xy, instance_id, upside_down=False, z_floor=None) -> ObjectPose on the sink floor."""
    return lambda *a, **k: _resting(planner, *a, **k)


def _translated(T0: np.ndarray, d: np.ndarray, length: float, n: int) -> list[np.ndarray]:
    """`n` base-frame poses of `T0` moved along the unit direction `d`, from 0 to `length` (m)."""
    out = []
    for s in np.linspace(0.0, length, n):
        T = np.array(T0, float)
        T[:3, 3] += s * np.asarray(d, float)
        out.append(T)
    return out


@pytest.fixture(scope="session")
def translated():
    return _translated


@pytest.fixture
def cup_for_the_upper_rack(planner, resting):
    """(cup, objects, targets): an upside-down cup in the sink with a side plate beside it, and the cup's first three
    upper-rack targets."""
    cup = resting("cup", (0.55, -0.05), 1, upside_down=True)
    plate = resting("side_plate", (0.40, 0.08), 2)
    return cup, [cup, plate], SlotBook(planner.cell).targets_for(planner.inventory[cup.obj_id])[:3]


def _straight_up(planner: Planner, q_grasp: np.ndarray, step: float, top: float) -> np.ndarray:
    """Configurations lifting the TCP straight up from `q_grasp` by `step` up to `top` (m), each the IK nearest
    the one before (no seeds), the grasp first."""
    T_grasp = planner.robot.fk_tcp(q_grasp)
    Q = [np.asarray(q_grasp, float)]
    for dz in np.arange(step, top, step):
        T = T_grasp.copy()
        T[2, 3] += dz
        Q.append(planner.robot.ik(T, Q[-1], max_seeds=0).q)
    return np.array(Q)


@pytest.fixture(scope="session")
def straight_up(planner):
    """straight_up(q_grasp, step, top) -> (N, 6) configurations lifting the TCP straight up from the grasp."""
    return lambda *a, **k: _straight_up(planner, *a, **k)


def _sim_contact_along(world, Q: np.ndarray, uids: dict) -> str | None:
    """The simulator's checker along the joint path `Q` (7 samples per segment) with what `world` holds: the
    first contact as "part hits name" (`uids`: name -> the world's uid), None where there is none."""
    from kitchenbot.fakes.collision import SimCollision

    Q = np.asarray(Q, float)
    dense = [Q[i] + (Q[i + 1] - Q[i]) * s for i in range(len(Q) - 1) for s in np.linspace(0.0, 1.0, 8)[:-1]]
    contact = SimCollision(world).check_path(np.asarray(dense + [Q[-1]]), world.gripper_opening)
    names = {f"obj:{u}": k for k, u in uids.items()}
    return None if contact is None else f"{contact.part} hits {names.get(contact.other, contact.other)}"


@pytest.fixture(scope="session")
def sim_contact_along():
    """sim_contact_along(world, Q, uids) -> the simulator's first contact along Q as "part hits name", or None."""
    return _sim_contact_along


def _lift_contact(world, pick, item) -> object | None:
    """The simulator's first contact (or None) along `pick`'s lift with `item` held in the fingers, the arm put
    at the lift's start; the world holds nothing afterwards."""
    from kitchenbot.fakes.collision import SimCollision

    world.set_joints(pick.lift.q[0])
    world.attach(item.instance_id, slip=False)
    try:
        return SimCollision(world).check_path(pick.lift.q, pick.grasp.spec.opening)
    finally:
        world.release()


@pytest.fixture(scope="session")
def lift_contact():
    """lift_contact(world, pick, item) -> the simulator's first contact along the pick's lift, or None."""
    return _lift_contact


def _sim_holds(inventory, model, specs, width_tol: float | None = None) -> None:
    """The simulator's Fin-Ray model (its own contact test) holds `model` with each grasp of `specs`, placed at
    the tool as the grasp says (closing within `width_tol` of the grasp's expected width, where given)."""
    from kitchenbot.fakes.gripper import FakeGripper
    from kitchenbot.fakes.world import SimWorld
    from kitchenbot.transforms import inv
    from kitchenbot.world.cell import Cell

    cfg = CellConfig()
    world = SimWorld(Cell(), inventory, T_flange_tcp=cfg.safety_limits().T_flange_tcp, q=np.array(cfg.robot.home))
    for spec in specs:
        uid = world.add_object(model, world.T_base_tcp() @ inv(spec.T_obj_tcp))
        g = FakeGripper(world)
        g.connect()
        g.open(spec.opening)
        r = g.grasp(0.8)
        assert r.holding and world.held_uid == uid, spec.name
        if width_tol is not None:
            assert abs(r.opening - spec.width) < width_tol, spec.name
        g.open(spec.opening)
        world.remove_object(uid)
        g.disconnect()


@pytest.fixture
def sim_holds():
    """sim_holds(inventory, model, specs, width_tol=None): the simulated Fin-Ray holds `model` with each grasp."""
    return _sim_holds


@pytest.fixture
def grasps_hold():
    """grasps_hold(model_name, prefix, every): the simulator's Fin-Ray model (its own contact test) holds the
    model with every `every`-th grasp whose name starts with `prefix`, at about the grasp's expected width."""

    def check(name: str, prefix: str, every: int) -> None:
        inventory = ensure_grasps(Inventory.builtin())
        m = inventory.by_name(name)
        specs = [g for g in m.grasps if g.name.startswith(prefix)][::every]
        assert specs, f"{name} has no {prefix} grasps"
        _sim_holds(inventory, m, specs, width_tol=0.006)

    return check



@pytest.fixture
def sim_items(cfg, inventory):
    """sim_items([(name, T_true, T_fit), ...]) -> (a SimWorld of the builtin cell with those items at their true
    poses, the items as perceived: ObjectPoses at T_fit with the simulator's instance ids)."""
    from kitchenbot.fakes.world import SimWorld
    from kitchenbot.world.cell import Cell

    def make(items):
        world = SimWorld(Cell(), inventory, T_flange_tcp=cfg.safety_limits().T_flange_tcp, q=np.array(cfg.robot.home))
        out = []
        for name, T_true, T_fit in items:
            m = inventory.by_name(name)
            out.append(ObjectPose(m.obj_id, m.cls, T_fit, 1.0, instance_id=world.add_object(m, T_true)))
        return world, out

    return make
