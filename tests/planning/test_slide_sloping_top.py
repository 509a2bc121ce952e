"""Sliding the top plate of a leaning nest: two side plates tilted 35 degrees, the top one about a nest pitch up the
lower one's axis, their tops sloping down towards (+x, -y) (not along x or y). The closed fingers press with both
tips (6 mm either side of the TCP along the closing axis). Before, the press height came from the one surface
point under the TCP and the closing axis was laid across or along the slide whatever the slope: here along the
slope, one tip 1.2 mm above the plate and the other 7.2 mm into it, and the simulated arm stopped at the slide's
start (its rule: a tip more than 6 mm into an item while moving sideways). Now the height is set from the higher
of the surfaces under the two tips and the most level closing axis (the plate's level line) comes first."""

import numpy as np
import open3d as o3d
import pytest

from kitchenbot.executive.assembly import make_sim_world
from kitchenbot.executive.config import load_config
from kitchenbot.executive.oracle import OraclePerceiver
from kitchenbot.fakes.arm import FakeArm
from kitchenbot.fakes.gripper import FakeGripper
from kitchenbot.planning.pick_place import Planner
from kitchenbot.planning.slide import PRESS_DEPTH, TopSurface, closing_axis, press_point, press_yaws, tip_offset
from kitchenbot.world.gripper import FINGERS

pytestmark = pytest.mark.timeout(120)

LOWER = [[0.90003, -0.0407, 0.43393, 0.564], [0.20995, 0.91298, -0.34984, -0.08869],
         [-0.38193, 0.40597, 0.83025, -0.13617]]
TOP = [[-0.41893, 0.80094, 0.42778, 0.56744], [-0.88583, -0.25697, -0.38637, -0.08455],
       [-0.19953, -0.54079, 0.81715, -0.12827]]  # 35 degrees from vertical, 6.3 mm up the lower one's axis


def _pose(rows) -> np.ndarray:
    T = np.eye(4)
    T[:3] = rows
    U, _, Vt = np.linalg.svd(T[:3, :3])
    T[:3, :3] = U @ Vt
    return T


def nest_world(cfg):
    """A simulated world holding only the two nested side plates: (world, plate model, the top plate's uid)."""
    world = make_sim_world(cfg, 0)
    for u in list(world.objects):
        world.remove_object(u)
    plate = world.inventory.by_name("side_plate")
    world.add_object(plate, _pose(LOWER))
    return world, plate, world.add_object(plate, _pose(TOP))


@pytest.fixture
def leaning_nest():
    cfg = load_config("config/sim.yaml")
    world, plate, top_uid = nest_world(cfg)
    planner = Planner.from_config(cfg, world.inventory)
    poses = OraclePerceiver(world).perceive([]).poses
    top = next(p for p in poses if p.instance_id == top_uid)
    return cfg, world, planner, plate, poses, top, top_uid


def _tip_depths(plate, T_base_obj, T_base_tcp) -> list[float]:
    """How far (m) each closed finger's tip is below the plate's top surface straight above or below it."""
    surface = TopSurface(plate, T_base_obj)
    out = []
    for y in (tip_offset(), -tip_offset()):
        tip = (T_base_tcp @ np.array([0.0, y, FINGERS.tip_z, 1.0]))[:3]
        out.append(float(surface.heights(tip[None, :2])[0] - tip[2]))
    return out


def test_the_press_is_planned_along_the_level_line_first(leaning_nest):
    """Any yaw offered: the one whose closing axis runs along the top's level line comes first, its tips level and
    the deeper PRESS_DEPTH in."""
    _, _, _, plate, _, top, _ = leaning_nest
    T = np.asarray(top.T_base_obj)
    p = press_point(plate, T)
    surface = TopSurface(plate, T)
    yaws = press_yaws(surface, p, [0.0, np.pi / 4])  # the first: the closing axis (0.71, -0.71), down the slope
    a, z_tcp = yaws[0]
    n = T[:3, 2] if T[2, 2] > 0 else -T[:3, 2]
    assert abs(closing_axis(a)[:2] @ n[:2]) / np.linalg.norm(n[:2]) < 0.1  # across the slope
    h = surface.heights(np.array([p[:2] + s * tip_offset() * closing_axis(a)[:2] for s in (1, -1)]))
    assert abs(h[0] - h[1]) < 0.001
    assert z_tcp == pytest.approx(h.max() + FINGERS.tip_z - PRESS_DEPTH, abs=1e-5)
    assert all(abs(closing_axis(b)[:2] @ [0.7071, -0.7071]) < 0.99 for b, _ in yaws)  # 7 mm into it: dropped


def test_the_top_plate_of_a_leaning_nest_is_slid_with_both_tips_on_it(leaning_nest):
    cfg, world, planner, plate, poses, top, top_uid = leaning_nest
    plan = planner.plan_slide(world.q.copy(), poses, top)
    assert plan.ok, plan
    depths = _tip_depths(plate, top.T_base_obj, planner.robot.fk_tcp(plan.press.q[-1]))
    assert all(0.0 <= d <= 0.006 for d in depths), depths  # before: -1.2 and 7.2 mm
    arm, grip = FakeArm(world, cfg.safety_limits()), FakeGripper(world)
    arm.connect()
    grip.connect()
    grip.open(0.0)
    for traj in plan.trajectories:
        arm.execute_trajectory(traj.times, traj.q)  # before: ProtectiveStopError, a tip more than 6 mm in
    assert arm.log.protective_stops == 0 and arm.log.collisions == 0
    moved = world.objects[top_uid].T_base_obj[:2, 3] - np.asarray(top.T_base_obj)[:2, 3]
    assert moved @ plan.direction[:2] > 0.02  # the fingers dragged it along
