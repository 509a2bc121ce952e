"""FakeGripper: contact width from the mesh between the pads, current near the limit when stalled, closing on
nothing, overload fault and reboot, release on open, timing in simulated seconds."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest

from kitchenbot.drivers import DeviceNotConnectedError, HardwareError
from kitchenbot.executive.config import CellConfig
from kitchenbot.fakes.gripper import FakeGripper
from kitchenbot.fakes.world import SimWorld
from kitchenbot.planning.grasp_synthesis import ensure_grasps
from kitchenbot.transforms import inv, trans
from kitchenbot.world.cell import Cell
from kitchenbot.world.inventory import Inventory, ObjectModel

CFG = CellConfig()
INVENTORY = ensure_grasps(Inventory.builtin())


def make_world() -> SimWorld:
    # The arm stays at home (TCP 0.27 m above the counter, pointing down); objects are put between the pads.
    return SimWorld(Cell(), INVENTORY, T_flange_tcp=CFG.safety_limits().T_flange_tcp, q=np.array(CFG.robot.home))


def box_model(size=(0.06, 0.04, 0.08)) -> ObjectModel:
    m = o3d.geometry.TriangleMesh.create_box(*size)
    m.translate(-np.asarray(size) / 2)
    return ObjectModel(obj_id=99, name="block", cls="cup", mesh=m, diameter=float(np.linalg.norm(size)))


def connected(world: SimWorld) -> FakeGripper:
    g = FakeGripper(world)
    g.connect()
    return g


def test_grasp_block_stalls_at_its_width():
    world = make_world()
    uid = world.add_object(box_model(), world.T_base_tcp() @ trans(0, 0, 0.03))  # 40 mm along the closing axis
    g = connected(world)
    t0 = world.clock.now()
    r = g.grasp(0.8)
    assert r.holding and r.opening == pytest.approx(0.040, abs=1e-4)
    assert 0.9 * 0.8 <= r.current <= 0.8
    assert world.clock.now() - t0 == pytest.approx((0.10 - 0.040) / 0.1)
    assert world.held_uid == uid and world.gripper_opening == pytest.approx(r.opening)
    st = g.status()
    assert st.holding and st.error is None and st.current == pytest.approx(r.current)
    assert 20 < st.temperature_c < 60 and 11 < st.voltage_v < 13


@pytest.mark.parametrize("kind", ["side", "rim"])
def test_grasp_cup_gives_about_its_width(kind):
    world = make_world()
    cup = INVENTORY.by_name("cup")
    spec = next(s for s in cup.grasps if s.name.startswith(kind))
    uid = world.add_object(cup, world.T_base_tcp() @ inv(spec.T_obj_tcp))
    g = connected(world)
    g.open(spec.opening)
    r = g.grasp(0.6)
    assert r.holding and world.held_uid == uid
    # flat pads stall on the widest part over the pad face, the spec measures the span at the TCP
    assert abs(r.opening - spec.width) < 0.002
    assert r.current >= 0.9 * 0.6


def test_closing_on_nothing():
    world = make_world()
    world.add_object(box_model(), world.T_base_tcp() @ trans(0.08, 0, 0.03))  # beside the fingers, not between
    g = connected(world)
    t0 = world.clock.now()
    r = g.grasp(0.6)
    assert not r.holding and r.opening < 1e-3 and abs(r.current) < 0.2
    assert world.clock.now() - t0 == pytest.approx(1.0)
    assert world.held_uid is None and not g.status().holding


def test_open_releases_and_times():
    world = make_world()
    uid = world.add_object(box_model(), world.T_base_tcp() @ trans(0, 0, 0.03))
    g = connected(world)
    g.grasp(0.6)
    z_held = world.objects[uid].T_base_obj[2, 3]
    t0 = world.clock.now()
    g.open()
    assert world.clock.now() - t0 == pytest.approx(0.06 / 0.1)
    assert world.held_uid is None and not g.status().holding and g.opening() == pytest.approx(0.10)
    assert world.objects[uid].T_base_obj[2, 3] < z_held - 0.1  # dropped onto what is below


def test_overload_fault_needs_reboot():
    world = make_world()
    world.add_object(box_model(), world.T_base_tcp() @ trans(0, 0, 0.03))
    g = connected(world)
    world.faults.gripper_overload = 1
    with pytest.raises(HardwareError, match="overload"):
        g.grasp(0.6)
    assert world.faults.gripper_overload == 0
    assert g.status().error == "overload" and not g.status().holding
    with pytest.raises(HardwareError):
        g.open()
    with pytest.raises(HardwareError):
        g.grasp(0.6)
    g.reboot()
    assert g.error() is None and world.held_uid is None
    g.open()
    assert g.grasp(0.6).holding  # healthy again


def test_bad_arguments_and_connection():
    world = make_world()
    g = FakeGripper(world)
    with pytest.raises(DeviceNotConnectedError):
        g.open()
    g.connect()
    with pytest.raises(ValueError, match="current_limit"):
        g.grasp(5.0)
    with pytest.raises(ValueError, match="opening"):
        g.open(0.2)


def test_upside_down_bowl_is_held_by_its_foot_ring():
    """A foot-ring pinch (world.gripper) from above an upside-down bowl: the pads stall on the ring."""
    world = make_world()
    bowl = INVENTORY.by_name("bowl")
    spec = next(g for g in bowl.grasps if g.name.startswith("foot_"))
    T_obj = world.T_base_tcp() @ inv(spec.T_obj_tcp)
    assert T_obj[2, 2] < -0.99  # the bowl is upside down under a gripper pointing down
    uid = world.add_object(bowl, T_obj)
    g = connected(world)
    g.open(spec.opening)
    r = g.grasp(0.8)
    assert r.holding and world.held_uid == uid
    assert r.opening == pytest.approx(spec.width, abs=1e-3)
