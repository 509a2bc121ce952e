"""Two items that block each other's way out: a cup lying on its side on a side plate's rim, its mouth against the
basin's wall. The plate's lift runs into the cup (it lies on the plate); where the cup cannot be picked either
(its grasps crowded by the plate and the wall), `blocker_first` went round that pair until the attempts ran out.
The strategy `slide_off_blocked` pushes the cup off the plate with the closed fingers pressing on its top (off its
centre, away from the wall the palm would meet) and the simulated arm drags it; a slide may now also run along a
wall the item already touches (`planning.slide.slide_directions`: before, every direction had to keep 5 mm from
all walls, so an item touching one was never slid)."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.executive.belief import Belief
from kitchenbot.executive.oracle import OraclePerceiver
from kitchenbot.executive.strategies import PlanFailure, PlanRequest, SlideOffBlocked
from kitchenbot.fakes.placement import drop_onto
from kitchenbot.planning.slide import slide_directions
from kitchenbot.transforms import rot_y

pytestmark = pytest.mark.timeout(300)

WALL_GAP = 0.0015  # m between the cup's mouth and the basin's +x wall


@pytest.fixture(scope="module")
def scene(empty_sim_cell):
    """The sink emptied; a side plate flat on its floor 3 mm from the +x wall; a cup lying on the plate's rim
    (10 cm off the plate's centre across the wall), its axis along x, mouth to that wall, WALL_GAP from it."""
    cfg, world, planner = empty_sim_cell()
    lo, hi = planner.cell.sink_interior
    plate = next(m for m in world.inventory if m.name == "side_plate")
    cup = next(m for m in world.inventory if m.name == "cup")
    y = 0.02
    T = np.eye(4)
    T[:3, 3] = (hi[0] - plate.extents[0] / 2 - 0.003, y - 0.10, 0.0)
    p = world.add_object(plate, T)
    world.set_pose(p, drop_onto(world, p, T))
    T = rot_y(np.pi / 2)
    V = np.asarray(cup.mesh.vertices) @ T[:3, :3].T
    T[:3, 3] = (hi[0] - WALL_GAP - V[:, 0].max(), y, 0.05)
    c = world.add_object(cup, T)
    world.set_pose(c, drop_onto(world, c, T))
    return cfg, world, planner, p, c


def _poses(world):
    return OraclePerceiver(world).perceive([]).poses


def test_an_item_touching_a_wall_may_slide_along_it(scene):
    cfg, world, planner, p, c = scene
    poses = _poses(world)
    cup = next(o for o in poses if o.instance_id == c)
    dirs = slide_directions(planner, cup, [o for o in poses if o is not cup], 0.03)
    along = [d for d, _ in dirs if abs(d[0]) < 1e-6]
    assert along, [d for d, _ in dirs]  # +-y: the cup keeps its WALL_GAP from the +x wall
    assert all(d[0] <= 1e-6 for d, _ in dirs)  # never towards the wall it touches


def test_plan_slides_off_the_item_only_the_failure_named(scene):
    """The belief does not yet know the cup blocks the plate; only the cup's own failure names the plate under
    it. plan() must slide the cup off that plate (before, it asked again without the failure and slid "off"
    nothing)."""
    cfg, world, planner, p, c = scene
    poses = _poses(world)
    cup = next(o for o in poses if o.instance_id == c)
    notes = []
    req = PlanRequest(obj=cup, targets=[], staged=None, task=None, belief=Belief(), planner=planner,
                      joints=lambda: world.q.copy(), escape=lambda: True,
                      note=lambda *a, **k: notes.append((a, k)), check_deadline=lambda: None, scene_objs=poses)
    s = SlideOffBlocked()
    assert s.applies(PlanFailure("no_collision_free_grasp", "", "pick", "direct_pick", p), cup, req.belief, req)
    s.plan(req)
    offs = [k["off"] for a, k in notes if a[:2] == ("command", "plan_slide")]
    assert offs == [[p]], notes


def test_mutual_blockers_the_upper_is_slid_off(scene, run_slide):
    cfg, world, planner, p, c = scene
    poses = _poses(world)
    plate = next(o for o in poses if o.instance_id == p)
    cup = next(o for o in poses if o.instance_id == c)
    r = planner.plan_pick(world.q.copy(), poses, target=plate)
    assert not r.ok and r.details.get("blocking") == c  # the cup lies in the plate's lift's way

    belief = Belief()
    belief.poses = poses
    notes = []
    req = PlanRequest(obj=cup, targets=[], staged=None, task=None, belief=belief, planner=planner,
                      joints=lambda: world.q.copy(), escape=lambda: True,
                      note=lambda *a, **k: notes.append(a), check_deadline=lambda: None, scene_objs=poses)
    s = SlideOffBlocked()
    crowded = PlanFailure("no_collision_free_grasp", "every grasp collides", "pick", "direct_pick", None)
    assert not s.applies(crowded, cup, belief, req)  # nothing says it blocks the plate yet
    belief.record_blocked(plate, c)  # the plate's failure named the cup
    assert s.applies(crowded, cup, belief, req)
    assert s.applies(PlanFailure("no_collision_free_grasp", "", "pick", "direct_pick", p), cup, Belief(), req)
    assert not s.applies(PlanFailure("no_feasible_placement", "", "pick", "direct_pick", p), cup, belief, req)
    req_plate = PlanRequest(**{**req.__dict__, "obj": plate})  # the plate lies on nothing: not slid by this
    assert not s.applies(PlanFailure("cartesian_path_failed", "", "pick", "direct_pick", c), plate, belief, req_plate)

    plan = s.plan(req)
    assert plan is not None and plan.slide is not None and plan.strategy == "slide_off_blocked"
    start, moved = run_slide(world, cfg, plan.slide, c)
    assert moved[2, 3] < start[2, 3] - 0.01  # down off the plate's rim
    poses = _poses(world)
    plate = next(o for o in poses if o.instance_id == p)
    assert all(o.instance_id != c for o in planner.items_on(plate, poses))  # off the plate
    r = planner.plan_pick(world.q.copy(), poses, target=plate)
    assert r.ok or r.details.get("blocking") != c, r
