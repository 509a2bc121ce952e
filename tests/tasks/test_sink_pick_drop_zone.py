"""sink-pick's drop zone: a 10-item sink's worth of items fits (plates, bowls, cups on piles; glasses and mugs side
by side), pile heights are tracked, and every spot is reachable with the tool pointing down."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.placement import nesting_height
from kitchenbot.planning.types import NoFreeSlot
from kitchenbot.executive.belief import Belief
from kitchenbot.tasks import make_task
from kitchenbot.tasks.sink_pick import floor_radius
from kitchenbot.transforms import make_T
from kitchenbot.world.cell import Cell
from kitchenbot.world.gripper import DROP_HEIGHT
from kitchenbot.world.inventory import Inventory


def in_sink(inv, name, k):
    m = inv.by_name(name)
    return ObjectPose(m.obj_id, m.cls, make_T(np.eye(3), (0.45 + 0.01 * k, 0.0, -0.15)), 1.0, instance_id=k)


def clear_sink(task, belief, inv, names):
    """Place every item at its first target, in the task's pick order; returns the (pose, target) pairs."""
    left = [in_sink(inv, n, k) for k, n in enumerate(names)]
    out = []
    while left:
        belief.pending = task.pending_models(left)
        o = task.remaining(left)[0]
        left = [p for p in left if p is not o]
        ts = task.targets(o, belief)
        assert not isinstance(ts, NoFreeSlot), (inv[o.obj_id].name, [p.cls for p in belief.placed])
        belief.record_placed(task, o, ts[0], ts[0].T_base_obj)
        out.append((o, ts[0]))
    return out


def _overlap(a, b):
    return bool(np.all(a.lo < b.hi) and np.all(a.hi > b.lo))


@pytest.mark.parametrize("names", [
    ["dinner_plate"] * 3 + ["side_plate"] * 2 + ["bowl"] * 2 + ["cup", "mug", "glass"],
    ["glass"] * 4 + ["mug"] * 4 + ["dinner_plate", "bowl"],
    ["side_plate", "dinner_plate", "cup", "cup", "cup", "mug", "mug", "glass", "glass", "bowl"],
    ["dinner_plate"] * 10,
])
def test_a_ten_item_sink_fits_in_the_drop_zone(inv, names):
    cell = Cell()
    task = make_task("sink-pick", inv, cell)
    belief = Belief()
    placed = clear_sink(task, belief, inv, names)
    assert len(belief.placed) == len(names)
    z = cell.spec.drop_zone
    lo, hi = np.array(z.origin_xy), np.array(z.origin_xy) + np.array(z.size_xy)
    for p in belief.placed:
        c = p.T_base_obj[:2, 3]
        assert np.all(c >= lo - 1e-6) and np.all(c <= hi + 1e-6), (p.cls, c)
        assert p.T_base_obj[2, 2] > 0.99  # upright
    # items that overlap in xy are one pile (each on top of the one below); items of different piles do not touch
    for a in belief.placed:
        for b in belief.placed:
            if a is b or not _overlap(a, b):
                continue
            lower, upper = sorted((a, b), key=lambda p: p.T_base_obj[2, 3])
            if lower.cls == "plate" and upper.cls != "plate":  # off the centre of a plate: on its flat floor
                d = np.linalg.norm(upper.T_base_obj[:2, 3] - lower.T_base_obj[:2, 3])
                assert d + max(upper.hi - upper.lo) / 2 <= floor_radius(inv[lower.obj_id]) + 1e-6 or d < 1e-9
                continue
            assert np.allclose(a.T_base_obj[:2, 3], b.T_base_obj[:2, 3], atol=1e-9), (a.cls, b.cls)
    # plates only go onto plates, bowls onto bowls, cups onto cups; anything else only onto a plate pile once
    # every plate is placed (it would block the pile)
    for k, (o, t) in enumerate(placed):
        below = [p for j, p in enumerate(belief.placed) if j != k and p.T_base_obj[2, 3] < t.T_base_obj[2, 3] - 1e-6
                 and np.allclose(p.T_base_obj[:2, 3], t.T_base_obj[:2, 3])]
        if not below or all(p.cls == o.cls for p in below) and o.cls in ("plate", "bowl", "cup"):
            continue
        assert all(p.cls == "plate" for p in below), (o.cls, [p.cls for p in below])
        assert not any(later.cls == "plate" for later, _ in placed[k + 1:]), o.cls


def test_a_plate_goes_on_top_of_the_plate_pile_with_its_height_tracked(inv):
    task = make_task("sink-pick", inv, Cell())
    belief = Belief()
    placed = clear_sink(task, belief, inv, ["dinner_plate"] * 3 + ["side_plate"])
    T = [t.T_base_obj for _, t in placed]
    dinner = inv.by_name("dinner_plate")
    for k in (1, 2):  # each dinner plate nests into the one below
        np.testing.assert_allclose(T[k][:2, 3], T[0][:2, 3], atol=1e-9)
        # (the one below came to rest DROP_HEIGHT under its release target)
        assert T[k][2, 3] == pytest.approx(T[k - 1][2, 3] + nesting_height(dinner))
    # the side plate rests on top of the pile: its underside at the top dinner plate's top
    side = inv.by_name("side_plate")
    np.testing.assert_allclose(T[3][:2, 3], T[0][:2, 3], atol=1e-9)
    assert T[3][2, 3] - side.extents[2] / 2 == pytest.approx(belief.placed[2].top_z + DROP_HEIGHT)


def test_a_glass_keeps_a_plate_pile_free_and_piles_stop_at_a_safe_height(inv):
    from kitchenbot.tasks.sink_pick import PILE_MAX_TOP

    task = make_task("sink-pick", inv, Cell())

    belief = Belief()
    plate = in_sink(inv, "side_plate", 0)
    big = in_sink(inv, "dinner_plate", 1)
    belief.pending = task.pending_models([plate, big])
    t = task.targets(plate, belief)[0]
    belief.record_placed(task, plate, t, t.T_base_obj)
    glasses = [in_sink(inv, "glass", 2 + k) for k in range(12)]
    for k, glass in enumerate(glasses):  # glasses fill the counter while the dinner plate is still in the sink
        belief.pending = task.pending_models([big, *glasses[k:]])
        g = task.targets(glass, belief)
        if isinstance(g, NoFreeSlot):
            break
        belief.record_placed(task, glass, g[0], g[0].T_base_obj)
    # ... but none takes the room around the side plate's pile that the dinner plate needs on top of it
    dinner = inv.by_name("dinner_plate")
    on_pile = [nt for nt in task.targets(big, belief) if np.allclose(nt.T_base_obj[:2, 3], t.T_base_obj[:2, 3])]
    assert on_pile and on_pile[0].T_base_obj[2, 3] - dinner.extents[2] / 2 == pytest.approx(
        belief.placed[0].top_z + DROP_HEIGHT)
    assert len(belief.placed) >= 6  # and the counter still took a row of glasses
    # a pile is never built past PILE_MAX_TOP
    task = make_task("sink-pick", inv, Cell())
    belief = Belief()
    clear_sink(task, belief, inv, ["bowl"] * 14)
    assert max(p.top_z for p in belief.placed) <= PILE_MAX_TOP + DROP_HEIGHT + 1e-6


def test_every_drop_zone_spot_is_reachable_tool_down():
    from kitchenbot.executive.config import CellConfig
    from kitchenbot.planning.pick_place import Planner
    from kitchenbot.tasks.sink_pick import PILE_MAX_TOP

    cfg = CellConfig()
    planner = Planner.from_config(cfg, Inventory.builtin())
    home = np.asarray(cfg.robot.home, float)
    z = cfg.cell.drop_zone
    scene = planner.world.scene()
    R = np.diag([1.0, -1.0, -1.0])  # tool pointing down
    for x in np.linspace(z.origin_xy[0], z.origin_xy[0] + z.size_xy[0], 4):
        for y in np.linspace(z.origin_xy[1], z.origin_xy[1] + z.size_xy[1], 4):
            for h in (0.03, PILE_MAX_TOP + 0.02):  # the TCP over an item on the counter / on a full pile
                q = planner.robot.ik_q(make_T(R, (x, y, h)), home)
                assert q is not None and scene.valid(q), (x, y, h)


def test_upside_down_bowls_set_down_as_they_lay_nest_onto_each_other(inv):
    from kitchenbot.transforms import rot_x

    task = make_task("sink-pick", inv, Cell())

    belief = Belief()
    m = inv.by_name("bowl")
    bowls = [ObjectPose(m.obj_id, "bowl", make_T(rot_x(np.pi)[:3, :3], (0.5 + 0.01 * k, 0.0, -0.15)), 1.0,
                        instance_id=k) for k in range(2)]
    belief.pending = task.pending_models(bowls)
    first = next(t for t in task.targets(bowls[0], belief) if t.support == "counter (as it lay)")
    belief.record_placed(task, bowls[0], first, first.T_base_obj)
    ts = task.targets(bowls[1], belief)
    on_it = [t for t in ts if "pile" in t.support]
    assert on_it, [t.support for t in ts]
    T = on_it[0].T_base_obj
    np.testing.assert_allclose(T[:3, :3], first.T_base_obj[:3, :3], atol=1e-9)  # lying the same way
    np.testing.assert_allclose(T[:2, 3], first.T_base_obj[:2, 3], atol=1e-9)
    assert T[2, 3] == pytest.approx(first.T_base_obj[2, 3] + nesting_height(m))  # the first rests DROP_HEIGHT lower


def test_tilted_mouth_down_bowls_are_set_down_level_and_nest_into_one_pile(inv):
    """Bowls tipped over on the items below (mouth down, 30 degrees off level, each tilted another way) are set
    down level and mouth down: the first on the counter (its level footprint, not the wider tilted one), the next
    ones nested onto it, so three tipped bowls take one bowl's room."""
    from kitchenbot.transforms import rot_x, rot_z

    task = make_task("sink-pick", inv, Cell())
    belief = Belief()
    m = inv.by_name("bowl")
    bowls = [ObjectPose(m.obj_id, "bowl", make_T(rot_z(yaw)[:3, :3] @ rot_x(np.pi - 0.5)[:3, :3],
                                                 (0.5 + 0.01 * k, 0.0, -0.12)), 1.0, instance_id=k)
             for k, yaw in enumerate((0.3, 2.0, 4.0))]
    placed = []
    for k, bowl in enumerate(bowls):
        belief.pending = task.pending_models(bowls[k:])
        ts = task.targets(bowl, belief)
        level = [t for t in ts if "upside down" in t.support]
        assert level, [t.support for t in ts]
        t = level[0]
        assert t.T_base_obj[2, 2] == pytest.approx(-1.0)  # level, mouth down
        order = [x.support for x in ts]
        assert order.index(t.support) < order.index("counter (as it lay)")  # before the tilted pose
        if k:
            assert t.support == "a bowl pile (upside down)"
            np.testing.assert_allclose(t.T_base_obj[:2, 3], placed[0].T_base_obj[:2, 3], atol=1e-9)
            assert t.T_base_obj[2, 3] == pytest.approx(placed[-1].T_base_obj[2, 3] + nesting_height(m))
        belief.record_placed(task, bowl, t, t.T_base_obj)
        placed.append(t)
    lo = np.min([p.lo for p in belief.placed], 0)
    hi = np.max([p.hi for p in belief.placed], 0)
    np.testing.assert_allclose(hi - lo, m.extents[:2], atol=1e-6)  # one bowl's disc


def test_an_item_that_fell_into_the_drop_zone_is_done_where_it_lies_elsewhere_not(inv):
    """A dropped item found in the drop zone is done for sink-pick (it takes items as they lie); one on the counter
    outside it is not, and no other task takes an item where it fell."""
    cell = Cell()
    z = cell.spec.drop_zone
    cup = inv.by_name("cup")
    lying = make_T(np.eye(3), (z.origin_xy[0] + 0.1, z.origin_xy[1] + 0.1, 0.04))
    beside = make_T(np.eye(3), (0.5, 0.30, 0.04))  # the counter between the sink and the stacking area
    task = make_task("sink-pick", inv, cell)
    belief = Belief()
    assert task.accepts_as_it_lies(ObjectPose(cup.obj_id, "cup", lying, 1.0))
    assert not task.accepts_as_it_lies(ObjectPose(cup.obj_id, "cup", beside, 1.0))
    for name in ("sink-to-dishwasher", "cup-stacking"):
        assert not make_task(name, inv, cell).accepts_as_it_lies(ObjectPose(cup.obj_id, "cup", lying, 1.0))


def test_a_neighbour_grazing_a_pile_does_not_close_it_to_an_item_of_its_size(inv):
    """A mug set down turned beside a dinner-plate pile: its box grazes the pile's. The next dinner plate still
    nests on the pile (it covers nothing the pile does not), while a bigger plate on a smaller pile would overhang
    the mug and is not offered there."""
    task = make_task("sink-pick", inv, Cell())
    belief = Belief()
    dinner = [in_sink(inv, "dinner_plate", k) for k in range(2)]
    mug = in_sink(inv, "mug", 5)
    belief.pending = task.pending_models([*dinner, mug])
    t = task.targets(dinner[0], belief)[0]
    belief.record_placed(task, dinner[0], t, t.T_base_obj)
    pile = belief.placed[0]
    # the mug turned by 45 degrees beside the pile (in the zone), its box reaching 5 mm into the pile's
    from kitchenbot.tasks.base import footprint
    from kitchenbot.transforms import rot_z

    m = inv.by_name("mug")
    R = rot_z(np.pi / 4)[:3, :3]
    half = footprint(m, make_T(R))[1]
    T_mug = make_T(R, (pile.lo[0] - half[0] + 0.005, pile.T_base_obj[1, 3], pile.T_base_obj[2, 3]))
    belief.record_placed(task, mug, t, T_mug)
    assert _overlap(belief.placed[1], pile) and task._in_zone(belief.placed[1])
    belief.pending = task.pending_models([dinner[1]])
    on_pile = [nt for nt in task.targets(dinner[1], belief)
               if np.allclose(nt.T_base_obj[:2, 3], pile.T_base_obj[:2, 3]) and "pile" in nt.support]
    assert on_pile, "the dinner plate pile was closed by a neighbour that only grazes it"
    # a side-plate pile with the same neighbour: a dinner plate on it would overhang the mug
    task = make_task("sink-pick", inv, Cell())
    belief = Belief()
    side = in_sink(inv, "side_plate", 0)
    belief.pending = task.pending_models([side])
    t = task.targets(side, belief)[0]
    belief.record_placed(task, side, t, t.T_base_obj)
    pile = belief.placed[0]
    half = footprint(m, make_T(np.eye(3)))[1]
    T_mug = make_T(np.eye(3), (pile.lo[0] - half[0] - 0.01, pile.T_base_obj[1, 3], pile.T_base_obj[2, 3]))
    belief.record_placed(task, mug, t, T_mug)
    assert not _overlap(belief.placed[1], pile) and task._in_zone(belief.placed[1])
    belief.pending = task.pending_models([dinner[0]])
    assert not [nt for nt in task.targets(dinner[0], belief)
                if np.allclose(nt.T_base_obj[:2, 3], pile.T_base_obj[:2, 3])]


def test_on_a_full_counter_two_glasses_stand_side_by_side_on_a_dinner_plate_pile(inv):
    """Once the counter is full and no plate is left to come, glasses stand on the flat floor of the plate that
    tops a pile, off its centre and apart, so a dinner plate takes two glasses (one in the middle took it whole);
    a plate pile with a glass on it takes no further plate."""
    from kitchenbot.planning.types import PlaceTarget
    from kitchenbot.tasks.base import Placed, footprint, upright
    from kitchenbot.tasks.sink_pick import floor_radius

    cell = Cell()
    task = make_task("sink-pick", inv, cell)
    z = cell.spec.drop_zone
    plate, glass = inv.by_name("dinner_plate"), inv.by_name("glass")
    belief = Belief()
    # the zone full (bowls everywhere) but for a dinner plate in its corner
    lo, hi = np.array(z.origin_xy), np.array(z.origin_xy) + np.array(z.size_xy)
    Tp = upright(plate, lo + plate.extents[:2] / 2 + 0.005, z.z)
    Tp[2, 3] -= DROP_HEIGHT
    belief.placed.append(Placed(plate.obj_id, "plate", Tp, *footprint(plate, Tp), PlaceTarget(Tp, "drop")))
    bowl = inv.by_name("bowl")
    for x in np.arange(lo[0] - 0.04, hi[0] + 0.08, 0.06):  # bowls over every bit of the zone the plate leaves
        for y in np.arange(lo[1] - 0.04, hi[1] + 0.08, 0.06):
            T = upright(bowl, (x, y), z.z)
            T[2, 3] -= DROP_HEIGHT
            f = footprint(bowl, T)
            if not (np.all(f[0] < belief.placed[0].hi) and np.all(f[1] > belief.placed[0].lo)):
                belief.placed.append(Placed(bowl.obj_id, "bowl", T, *f, PlaceTarget(T, "drop")))
    glasses = [ObjectPose(glass.obj_id, "glass", make_T(np.eye(3), (0.5 + 0.1 * k, 0.0, -0.15)), 1.0, instance_id=k)
               for k in range(2)]
    spots = []
    for k, g in enumerate(glasses):
        belief.pending = task.pending_models(glasses[k:])
        ts = task.targets(g, belief)
        assert not isinstance(ts, NoFreeSlot), k
        t = ts[0]
        assert t.support == "a plate pile", t.support
        d = np.linalg.norm(t.T_base_obj[:2, 3] - Tp[:2, 3])
        assert d + glass.extents[0] / 2 <= floor_radius(plate) + 1e-6  # on the plate's flat floor
        assert t.T_base_obj[2, 3] > Tp[2, 3] + plate.extents[2] / 2
        belief.record_placed(task, g, t, t.T_base_obj)
        spots.append(t.T_base_obj[:2, 3])
    assert np.linalg.norm(spots[0] - spots[1]) >= glass.extents[0]  # side by side, not into each other
    # a plate found later does not go onto the glasses
    late = ObjectPose(plate.obj_id, "plate", make_T(np.eye(3), (0.5, 0.0, -0.15)), 1.0, instance_id=9)
    belief.pending = [plate]
    ts = task.targets(late, belief)
    assert isinstance(ts, NoFreeSlot) or all(np.linalg.norm(t.T_base_obj[:2, 3] - Tp[:2, 3]) > 0.1 for t in ts)


@pytest.mark.parametrize("names", [
    ["bowl", "mug", "mug", "mug", "glass", "cup"] + ["dinner_plate"] * 5 + ["side_plate"] * 3,
    ["glass", "cup", "cup", "bowl", "bowl", "mug", "mug", "bowl", "glass", "mug"] + ["dinner_plate"] * 6,
])
def test_items_that_come_out_before_the_plates_leave_them_a_pile_spot(inv, names, place_in_order):
    """Bowls, mugs and cups that come out of the sink first (the plates lie under them) are set down around the
    spot the plate pile will take: every plate still finds room (one pile holds them all)."""
    task = make_task("sink-pick", inv, Cell())
    belief = Belief()
    assert place_in_order(task, belief, names) == []
