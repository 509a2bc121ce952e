"""Grasp selection filters and ranking; placement targets inside the rack slots; the slot book; stacking."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.planning.grasps import GraspStats
from kitchenbot.planning.placement import SlotBook, nesting_height, stack_target
from kitchenbot.planning.types import Grasp, NoFreeSlot, NoGraspableObject, PlanningFailure
from kitchenbot.world.gripper import DROP_HEIGHT


def test_grasps_ranked_and_from_above(planner, home, resting):
    cup = resting("cup", (0.5, 0.0), 1)
    grasps = planner.select_grasps(home, [cup])
    assert isinstance(grasps, list) and grasps
    assert all(isinstance(g, Grasp) for g in grasps)
    scores = [g.score for g in grasps]
    assert scores == sorted(scores, reverse=True)
    for g in grasps:
        assert g.approach[2] <= planner.settings.max_approach_up + 1e-9
        np.testing.assert_allclose(planner.robot.fk_tcp(g.q), g.T_base_tcp, atol=1e-4)
        # T_base_tcp = T_base_obj @ T_obj_tcp (possibly backed off along the approach by <= 8 mm)
        d = np.linalg.inv(cup.T_base_obj @ g.spec.T_obj_tcp) @ g.T_base_tcp
        assert abs(d[2, 3]) <= 0.008 + 1e-9 and np.allclose(d[:2, 3], 0, atol=1e-9)


def test_upside_down_bowl_is_grasped_by_its_foot_ring(planner, home, resting):
    bowl = resting("bowl", (0.5, 0.0), 1, upside_down=True)
    st = GraspStats()
    res = planner.select_grasps(home, [bowl], stats=st)
    assert st.from_below > 0  # every rim pinch would come up from below
    assert isinstance(res, list) and res
    names = [g.spec.name for g in res]
    for g in res:  # only the foot-ring pinches are left, from above (pitched ones: 10-20 degrees off vertical)
        assert g.spec.name.startswith("foot") and g.approach[2] < -0.93
    # the vertical pinches first, those pitched in from outside the ring (a slanted hold) after all of them
    assert names[0].startswith("foot_"), names
    first_pitched = next((i for i, n in enumerate(names) if n.startswith("footpitch")), len(names))
    assert all(n.startswith("footpitch") for n in names[first_pitched:]), names
    # and such a bowl goes into the upper rack mouth down with the grasp it was picked with
    book = SlotBook(planner.cell)
    targets = book.targets_for(planner.inventory.by_name("bowl"))
    res = planner.select_grasps(home, [bowl], place_target=targets[:4])
    assert isinstance(res, list) and res


def test_occluded_objects_are_dropped(planner, home, resting):
    cup = resting("cup", (0.5, 0.0), 1)
    full = planner.settings.visible_fraction_unoccluded
    cup.visible_fraction = full * (1.0 - planner.settings.max_occlusion) - 0.02  # just more hidden than allowed
    assert isinstance(planner.select_grasps(home, [cup]), NoGraspableObject)
    cup.visible_fraction = full * (1.0 - planner.settings.max_occlusion) + 0.02  # just visible enough
    assert isinstance(planner.select_grasps(home, [cup]), list)


def test_multi_object_grasps_are_rejected(planner, home, resting):
    a = resting("cup", (0.5, 0.0), 1)
    b = resting("glass", (0.5, 0.075), 2)  # touching the cup: pads around one would take in the other
    st = GraspStats()
    res = planner.select_grasps(home, [a, b], target=a, stats=st)
    assert st.multi_object > 0
    if isinstance(res, list):
        for g in res:  # no returned grasp closes across the glass
            y = g.T_base_tcp[:3, 1]
            to_b = b.T_base_obj[:3, 3] - g.T_base_tcp[:3, 3]
            assert abs(to_b @ y) > g.spec.opening / 2 or np.linalg.norm(to_b - (to_b @ y) * y) > 0.06


def _inside_rack(planner, model, T, rack):
    V = np.asarray(model.mesh.vertices) @ T[:3, :3].T + T[:3, 3]
    spec = getattr(planner.cell.spec.dishwasher, rack)
    lo = np.array(spec.origin_xy)
    hi = lo + np.array(spec.size_xy)
    return bool(np.all(V[:, :2] >= lo - 1e-3) and np.all(V[:, :2] <= hi + 1e-3) and V[:, 2].min() >= spec.floor_z - 1e-6)


@pytest.mark.parametrize("name,rack", [("dinner_plate", "lower"), ("side_plate", "lower"), ("cup", "upper"),
                                       ("glass", "upper"), ("mug", "upper"), ("bowl", "upper")])
def test_slot_targets_lie_inside_their_rack(planner, name, rack):
    book = SlotBook(planner.cell)
    model = planner.inventory.by_name(name)
    targets = book.targets_for(model)
    assert targets
    for t in targets:
        assert t.kind == "slot" and t.slot.startswith(rack)
        assert _inside_rack(planner, model, t.T_base_obj, rack), t.slot
        z = t.T_base_obj[:3, 2]
        if rack == "upper":
            assert z[2] < -0.99  # cups, glasses, bowls, mugs go in upside down
        else:
            assert abs(z[2]) < 1e-9  # plates stand upright


def test_slot_book_fills_and_frees(planner):
    book = SlotBook(planner.cell)
    cup = planner.inventory.by_name("cup")
    names = {t.slot for t in book.targets_for(cup)}
    for n in names:
        book.fill(n)
    assert isinstance(book.target_for(cup), NoFreeSlot)
    book.free(sorted(names)[0])
    assert book.target_for(cup).slot == sorted(names)[0]
    with pytest.raises(KeyError):
        book.fill("no_such_slot")


def test_a_placed_plate_blocks_the_slots_it_overlaps(planner):
    book = SlotBook(planner.cell)
    plate = planner.inventory.by_name("dinner_plate")
    first = book.targets_for(plate)[0]
    book.fill(first.slot, first.T_base_obj, plate)
    for t in book.targets_for(plate):
        a = np.asarray(plate.mesh.vertices) @ t.T_base_obj[:3, :3].T + t.T_base_obj[:3, 3]
        b = np.asarray(plate.mesh.vertices) @ first.T_base_obj[:3, :3].T + first.T_base_obj[:3, 3]
        overlap = np.all(a[:, :2].min(0) < b[:, :2].max(0)) and np.all(a[:, :2].max(0) > b[:, :2].min(0))
        assert not overlap, t.slot


def test_stacking_raises_by_the_nesting_height(planner, resting):
    cup = planner.inventory.by_name("cup")
    h = nesting_height(cup)
    assert 0.005 < h < cup.extents[2] * 0.8  # nests: less than its own height, more than nothing
    plate = planner.inventory.by_name("dinner_plate")
    assert nesting_height(plate) < plate.extents[2]
    base = resting("cup", (0.45, 0.4), 3, z_floor=0.0)
    t = stack_target(cup, base)
    np.testing.assert_allclose(t.T_base_obj[:3, :3], base.T_base_obj[:3, :3])
    assert t.T_base_obj[2, 3] - base.T_base_obj[2, 3] == pytest.approx(h + DROP_HEIGHT)


def test_grasps_to_avoid_are_not_planned_nor_their_tilted_variants(planner, home, resting):
    """plan_pick(avoid_grasps=...): a grasp that closed on nothing on this item is not used again, nor its tilted
    variants (expand_grasps: the same pinch from a 5-50 degree different direction)."""
    cup = resting("cup", (0.50, -0.02), 1)
    first = planner.plan_pick(home, [cup], target=cup)
    assert first.ok, first
    name = first.grasp.spec.name.split("_tilt")[0]
    again = planner.plan_pick(home, [cup], target=cup, avoid_grasps=[first.grasp.spec.name])
    assert again.ok, again
    assert again.grasp.spec.name.split("_tilt")[0] != name
    grasps = planner.select_grasps(home, [cup], target=cup, avoid_grasps=[name])
    assert grasps and all(g.spec.name.split("_tilt")[0] != name for g in grasps)


def test_the_placeable_cache_emptied_when_full_still_answers(planner, home, resting):
    """The cache of which grasps can reach the placement is bounded (emptied at 5000 answers): the grasp whose answer
    fills it still gets that answer (it was emptied after keeping it, then read back: a KeyError ended a
    sink-to-dishwasher run with own dishware, whose vessels have more grasps to check)."""
    bowl = resting("bowl", (0.5, 0.0), 1, upside_down=True)
    targets = SlotBook(planner.cell).targets_for(planner.inventory.by_name("bowl"))
    planner._placeable.clear()
    for k in range(4999):
        planner._placeable[("filler", k)] = False
    res = planner.select_grasps(home, [bowl], place_target=targets[:4])
    assert isinstance(res, list) and res
    assert len(planner._placeable) < 5000
