"""Regrasp staging: when a task's targets turn an item over from how it lies, the executive sets it down on the
counter and picks it again. An upright item wanted mouth-down (the dishwasher's upper rack) is staged lying on
its side when it is a round cup or glass, else upright (turned over from there by a level side grasp); a cup upside down in the sink wanted upright (a stack) is staged
upside down (carried there from above, then turned over by a level side grasp): staging it upright would need the
very turn no grasp in the sink can make."""

from __future__ import annotations

import numpy as np

from kitchenbot.planning.types import NoFreeSlot
from kitchenbot.executive.belief import Belief
from kitchenbot.tasks import make_task
from kitchenbot.tasks.base import PAD_ROOM, footprint
from kitchenbot.world.cell import Cell

MOUTH_DOWN = np.diag([1.0, -1.0, -1.0])


def lying(tilt_deg: float) -> np.ndarray:
    a = np.radians(tilt_deg)
    return np.array([[1.0, 0.0, 0.0], [0.0, np.cos(a), -np.sin(a)], [0.0, np.sin(a), np.cos(a)]])


def test_an_upside_down_cup_needs_a_regrasp_for_its_stack(inv, sink_item):
    task = make_task("cup-stacking", inv, Cell())
    belief = Belief()
    up, down = sink_item("cup"), sink_item("cup", MOUTH_DOWN)
    assert not task.needs_regrasp(task.targets(up, belief), up)
    assert task.needs_regrasp(task.targets(down, belief), down)
    assert task.needs_regrasp(task.targets(sink_item("cup", lying(140)), belief), sink_item("cup", lying(140)))
    # lying on its side: a rolled rim pinch stands it up directly
    assert not task.needs_regrasp(task.targets(sink_item("cup", lying(90)), belief), sink_item("cup", lying(90)))
    # without the object: only targets that turn it over (the old rule)
    assert not task.needs_regrasp(task.targets(down, belief))


def test_an_upside_down_cup_is_staged_upside_down_with_room_for_the_pads(inv, sink_item):
    task = make_task("cup-stacking", inv, Cell())
    belief = Belief()
    other = sink_item("glass")
    zone = task.cell.spec.drop_zone
    lo0 = np.array(zone.origin_xy)
    first = task.targets(other, belief)  # a glass is not wanted: moved out of the way into the drop zone
    belief.record_placed(task, other, first[0], first[0].T_base_obj)
    down = sink_item("cup", MOUTH_DOWN)
    stage = task.staging_targets(down, belief, task.targets(down, belief))
    assert not isinstance(stage, NoFreeSlot), stage
    assert stage[0].T_base_obj[2, 2] < -0.99  # upside down first, then lying on its side
    for t in stage:
        assert t.kind == "stage"
        assert t.T_base_obj[2, 2] < -0.99 or abs(t.T_base_obj[2, 2]) < 1e-6
        xy = t.T_base_obj[:2, 3]
        assert np.all(xy >= lo0) and np.all(xy <= lo0 + np.array(zone.size_xy))
        lo, hi, _ = footprint(inv[down.obj_id], t.T_base_obj)
        p = belief.placed[0]
        assert np.max(np.maximum(np.maximum(p.lo - hi, lo - p.hi), 0.0)) >= PAD_ROOM - 1e-6
    assert any(abs(t.T_base_obj[2, 2]) < 1e-6 for t in stage)


def test_only_round_cups_and_glasses_are_laid_on_their_side(inv):
    task = make_task("sink-to-dishwasher", inv, Cell())
    belief = Belief()
    for name in ("cup", "glass"):
        spots = task.lying_spots(inv.by_name(name), belief)
        assert spots and all(abs(t.T_base_obj[2, 2]) < 1e-6 for t in spots)
        m = inv.by_name(name)
        for t in spots:  # resting on the counter: its lowest point just above the drop zone
            P = m.points @ t.T_base_obj[:3, :3].T + t.T_base_obj[:3, 3]
            assert abs(P[:, 2].min() - task.cell.spec.drop_zone.z) < 0.02
    for name in ("mug", "bowl"):
        assert task.lying_spots(inv.by_name(name), belief) == []


def test_an_upright_cup_for_the_rack_is_laid_on_its_side_first(inv, sink_item):
    """From its side a grasp from above turns it mouth-down anywhere in the rack; upright (a level side grasp)
    only in the rack's near part. A mug is not laid on its side (it rolls onto its handle)."""
    task = make_task("sink-to-dishwasher", inv, Cell())
    belief = Belief()
    up = sink_item("cup")
    ts = task.targets(up, belief)
    assert task.needs_regrasp(ts, up)
    stage = task.staging_targets(up, belief, ts)
    assert not isinstance(stage, NoFreeSlot) and abs(stage[0].T_base_obj[2, 2]) < 1e-6
    assert any(t.T_base_obj[2, 2] > 0.99 for t in stage)  # upright ones after
    # without targets (the old call): upright only
    assert all(t.T_base_obj[2, 2] > 0.99 for t in task.staging_targets(up, belief))
    mug = sink_item("mug")
    assert all(t.T_base_obj[2, 2] > 0.99 for t in task.staging_targets(mug, belief, task.targets(mug, belief)))


def test_a_new_stack_is_offered_after_the_top_of_the_existing_one(inv, sink_item):
    """The top of a stack first; then free spots for another stack of the same type, clear of the first (the
    planner takes the first target a grasp reaches: a flipped cup, held level by its side, may not reach a high
    stack's top)."""
    task = make_task("cup-stacking", inv, Cell())
    belief = Belief()
    cup = sink_item("cup")
    first = task.targets(cup, belief)
    assert [t.kind for t in first] == ["stack_base"] * len(first)
    belief.record_placed(task, cup, first[0], first[0].T_base_obj)
    ts = task.targets(cup, belief)
    assert ts[0].kind == "stack" and np.allclose(ts[0].T_base_obj[:2, 3], first[0].T_base_obj[:2, 3])
    assert len(ts) > 1 and all(t.kind == "stack_base" for t in ts[1:])
    base = belief.placed[0]
    for t in ts[1:]:
        lo, hi, _ = footprint(inv[cup.obj_id], t.T_base_obj)
        assert not (np.all(lo < base.hi) and np.all(hi > base.lo))


def test_as_is_rests_the_lowest_point_on_the_support(inv):
    """A tilted mug (not symmetric) set down as it lay: its lowest point (in the base frame) just above the
    support."""
    from kitchenbot.tasks.base import as_is
    from kitchenbot.transforms import rot_x, rot_z
    from kitchenbot.world.gripper import DROP_HEIGHT

    m = inv.by_name("mug")
    R = (rot_z(0.7) @ rot_x(1.1))[:3, :3]
    T = as_is(R)(m, (0.1, 0.5), 0.02)
    P = m.points @ T[:3, :3].T + T[:3, 3]
    assert abs(P[:, 2].min() - (0.02 + DROP_HEIGHT)) < 1e-9
