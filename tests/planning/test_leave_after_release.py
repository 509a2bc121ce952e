"""A motion that starts within the margin of the items the tool let go among leaves the way the tool came in
(planning.leave), as a lift leaves what its item rested on.

A plate let go by a rim pinch in the rack, a plate 6 cm to either side: with the pads at the opening they let go
with (4.5 cm) every margin is kept, but free motions are planned with the pads fully open, and those touch both
neighbours. RRT-Connect refused the start, and the escape refuses a start whose pads touch two items: no way home
(twenty-third session: a sink-to-dishwasher run gave up after six `no_path` with items left in the sink)."""

import numpy as np
import pytest

from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.escape import plan_escape
from kitchenbot.planning.fcl_check import FclChecker
from kitchenbot.planning.placement import SlotBook

pytestmark = pytest.mark.timeout(180)

OPENING = 0.045  # m: the pads' distance as they let go


def _scene(planner, home):
    m = planner.inventory.by_name("dinner_plate")
    T1 = SlotBook(planner.cell).targets_for(m)[1].T_base_obj
    objs = [ObjectPose(m.obj_id, m.cls, T1, 1.0, instance_id=1)]
    for side, k in ((-1, 0), (1, 2)):
        T = T1.copy()
        T[0, 3] += side * 0.06
        objs.append(ObjectPose(m.obj_id, m.cls, T, 1.0, instance_id=k))
    V = (T1[:3, :3] @ np.asarray(m.mesh.vertices, float).T).T + T1[:3, 3]
    top = V[:, 2].max()
    rim = V[V[:, 2] > top - 0.02].mean(axis=0)
    T = planner.robot.fk_tcp(home)  # tool down, the pads closing along x: across the rack's plates
    T[:3, 3] = (rim[0], rim[1], top + 0.012 - 0.02)  # finger tips 2 cm down over the plate's rim
    q = planner.robot.ik_q(T, home)
    assert q is not None
    return q, objs, m


def test_released_between_two_plates_leaves_along_the_tool_axis_then_goes_home(planner, home):
    q0, objs, m = _scene(planner, home)
    at = planner.scene(objs, opening=OPENING)
    assert at.valid(q0)  # where the pads really are: every margin kept
    full = planner.scene(objs)
    touching = full.touching_only(full.colliding_pairs(q0)).colliding_pairs(q0)
    assert sorted(touching) == [("pad_a", "obj:0"), ("pad_b", "obj:2")]  # fully open: into both neighbours
    assert plan_escape(planner, q0, objs, opening=OPENING).kind == "start_in_collision"  # two items: refused

    # the executive gives the pads' opening where it reads it; without it, the first leg is checked with them
    # fully open (the start pairs unchecked for its first centimetres)
    for kw in ({}, {"opening": OPENING}):
        plan = planner.plan_move(q0, home, objects=objs, **kw)
        assert plan.ok, plan  # before: start_in_collision (pad_a/obj:0, pad_b/obj:2), the arm could not move
        Q = plan.trajectory.q
        assert np.allclose(Q[0], q0) and np.allclose(Q[-1], home, atol=1e-6)
        # first straight up (back along the tool axis) until every margin is kept
        k = next(i for i, q in enumerate(Q) if full.valid(q))
        p = np.array([planner.robot.fk_tcp(q)[:3, 3] for q in Q[: k + 1]])
        assert p[-1, 2] - p[0, 2] > 0.01 and np.abs(p[:, :2] - p[0, :2]).max() < 1e-3
        assert all(full.valid(q) for q in Q[k:])  # the rest with the full margins
        # the independent checker: no contact along the whole motion, the pads where they are
        checker = FclChecker(planner.robot, planner.cell, planner.world.T_flange_cam)
        r = checker.check_path(Q, objects=[(str(o.instance_id), m, o.T_base_obj) for o in objs], opening=OPENING,
                               step=0.004)
        assert r.ok, str(r)


def test_a_start_within_the_margin_of_the_cell_is_not_left_this_way(planner, home):
    from kitchenbot.planning.leave import tool_item_pairs

    assert tool_item_pairs([("pad_a", "obj:0"), ("obj:2", "pad_b"), ("palm", "obj:1")])
    assert not tool_item_pairs([("pad_a", "cell:sink_floor")])  # the escape's case (planning.escape)
    assert not tool_item_pairs([("pad_a", "obj:0"), ("link6", "obj:0")])
    assert not tool_item_pairs([("held", "obj:0")])
    assert not tool_item_pairs([])
    lo, _ = planner.cell.sink_interior
    T = planner.robot.fk_tcp(home)
    T[:3, 3] = (0.50, 0.0, lo[2] + 0.012 + 0.005)  # finger tips 5 mm above the sink floor
    q0 = planner.robot.ik_q(T, home)
    assert planner.plan_move(q0, home).kind == "start_in_collision"  # as before: the escape's job
