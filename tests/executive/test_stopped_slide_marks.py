"""A slide stopped by a protective stop (the closed fingers press on a plate and drag it; the plate jams on what
it rests on) marked, like any stopped motion, the space the pads were about to sweep. Pressing on the plate, the
pads ride over it: that space lies over the plate itself, where its next pick lifts it. The marks last until the
scene changes, so every lift of that plate ran into them (`held/voxels`) and it stayed, and with it what it lay on
(a fresh sink-pick: 5 plates left). Now a stopped slide marks the item's surface where it was about to be and
the pad points beside it, not those over it (executive/recovery.py, _dragged_sliver)."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.executive.assembly import assemble, make_sim_world
from kitchenbot.executive.oracle import OraclePerceiver
from kitchenbot.executive.runner import RunOptions
from kitchenbot.executive.session import build_runner
from kitchenbot.executive.strategies import ItemPlan

from .conftest import _small_config

pytestmark = pytest.mark.timeout(300)


def test_a_stopped_slide_does_not_mark_the_space_over_the_item_it_dragged():
    cfg = _small_config()
    world = make_sim_world(cfg, 0)  # a plate under two nested cups: the plate alone is kept
    for u in [u for u, o in world.objects.items() if o.model.cls != "plate"]:
        world.remove_object(u)
    robot = assemble(cfg, world=world)
    runner = build_runner(cfg, "sink-pick", 0, robot=robot, oracle_perception=True, journal_path=False,
                          options=RunOptions(poll_period=0.05, confirm_empty_scans=1))
    for dev in (runner.arm, runner.gripper, runner.camera):
        dev.connect()
    planner = runner.planner
    q_home = runner.arm.joint_positions()
    poses = OraclePerceiver(world).perceive([]).poses
    plate = next(o for o in poses if o.cls == "plate")
    assert planner.plan_pick(q_home, poses, target=plate).ok  # the situation: the plate alone picks

    sl = planner.plan_slide(q_home, poses, plate, then_pickable=False)
    assert sl.ok, sl
    # stopped a third of the way along the slide, the fingers closed on the plate
    runner.item.obj, runner.item.plan = plate, ItemPlan(strategy="slide_off_stack", slide=sl)
    runner.gripper.open(0.0)
    world.set_joints(sl.slide.q[len(sl.slide) // 3])
    marks = runner._contact_sliver(sl.slide)
    assert marks is not None and len(marks)
    runner.belief.mark_contact(marks)

    r = planner.plan_pick(q_home, poses, target=plate, map_points=runner.belief.map_points)
    assert r.ok, f"the marks of the stopped slide block the plate's pick: {r}"
    # what was marked lies ahead of the plate's leading side or beside it, none of it over the plate as it lies
    T = np.asarray(plate.T_base_obj, float)
    m = planner.inventory[plate.obj_id]
    P = m.points @ T[:3, :3].T + T[:3, 3]
    from scipy.spatial import Delaunay

    assert not (Delaunay(P[:, :2]).find_simplex(marks[:, :2]) >= 0).any()
