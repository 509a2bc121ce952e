"""An item pinned by a pose the views saw through (planning/seen_through.py, the strategy `pick_past_seen_through`).

Hand-made: a cup standing in the sink, its surface seen all round (the oracle's model points), and a bowl posed
upside down over its upper half. A real bowl there would have hidden the cup's upper half; the points seen of it
lie inside the bowl's body as posed, so that pose is a fit of something else (a bowl lying on its side, fitted as
an upside-down bowl resting on the bowl beside it, pinned that bowl and could not be grasped itself: both stayed
in the sink). A bowl resting on the cup's rim, or one lying mouth sideways around it, is not judged so."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.executive.belief import Belief
from kitchenbot.executive.failures import StepFailed
from kitchenbot.executive.strategies import plan_item, strategies_for
from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.seen_through import seen_through
from kitchenbot.planning.types import CartesianPathFailed
from kitchenbot.tasks import make_task
from kitchenbot.transforms import make_T, rot_x
from kitchenbot.world.cell import Cell
from kitchenbot.world.inventory import Inventory

from .test_strategies import Situation, _Ok, request

CUP_Z = -0.15  # m: the cup's centre (bounding box), standing on its base
MOUTH_DOWN = np.diag([1.0, -1.0, -1.0])


@pytest.fixture(scope="module")
def inv():
    return Inventory.builtin()


def _cup(inv):
    m = inv.by_name("cup")
    T = make_T(np.eye(3), (0.5, 0.0, CUP_Z))
    pts = np.asarray(m.points, float)[::8]  # 256 points all round
    return ObjectPose(m.obj_id, "cup", T, 1.0, pts @ T[:3, :3].T + T[:3, 3], instance_id=1)


def _bowl(inv, R, z, k=2):
    m = inv.by_name("bowl")
    return ObjectPose(m.obj_id, "bowl", make_T(R, (0.5, 0.0, z)), 0.8, instance_id=k)


def test_a_pose_over_what_the_views_saw_is_contradicted_one_resting_on_it_is_not(inv):
    cup = _cup(inv)
    top = CUP_Z + inv.by_name("cup").extents[2] / 2
    half = inv.by_name("bowl").extents[2] / 2
    over = _bowl(inv, MOUTH_DOWN, top - half + 0.02)  # upside down over the cup's upper half
    resting = _bowl(inv, np.eye(3), top + half + 0.001, k=3)  # upright on the cup's rim: a real lying-on
    sideways = _bowl(inv, rot_x(np.pi / 2)[:3, :3], top - 0.02, k=4)  # mouth sideways: its cavity may hold the cup
    assert seen_through(inv, cup, [over, resting, sideways]) == [over]
    assert seen_through(inv, ObjectPose(cup.obj_id, "cup", cup.T_base_obj, 1.0, cup.points[:10], 1), [over]) == []


class _Pinned(Situation):
    """The cup's lift is pinned by the bowl while the bowl is among the objects; without it the pick plans."""

    def __init__(self, inv, bowl):
        self.inventory, self.bowl, self.objects = inv, bowl, []

        def pick(staging, n):
            if any(o is self.bowl for o in self.objects[-1]):
                return CartesianPathFailed("test: lift: straight line collides (held/obj:2)",
                                           {"blocking": 2, "blocking_all": [(2, "bowl")], "pinned": True})
            return _Ok()
        super().__init__(pick)

    def plan_pick(self, q, objects, **kw):
        self.objects.append(list(objects))
        return super().plan_pick(q, objects, **kw)


def _request(inv, task, bowl, planner):
    b = Belief()
    cup = _cup(inv)
    b.poses = [cup, bowl]
    req = request(task, b, cup, planner)
    req.scene_objs = [cup, bowl]
    return req


def test_a_pin_the_views_saw_through_is_not_trusted(inv):
    task = make_task("sink-pick", inv, Cell())
    top = CUP_Z + inv.by_name("cup").extents[2] / 2
    half = inv.by_name("bowl").extents[2] / 2
    over = _bowl(inv, MOUTH_DOWN, top - half + 0.02)
    planner = _Pinned(inv, over)
    counts: dict = {}
    plan = plan_item(_request(inv, task, over, planner), strategies_for(task), counts)
    assert plan.strategy == "pick_past_seen_through"
    assert any(o is over for o in planner.objects[0]) and not any(o is over for o in planner.objects[-1])
    assert counts["pick_past_seen_through"] == {"tried": 1, "planned": 1}


def test_a_pin_by_an_item_really_resting_on_it_still_waits(inv):
    task = make_task("sink-pick", inv, Cell())
    top = CUP_Z + inv.by_name("cup").extents[2] / 2
    resting = _bowl(inv, np.eye(3), top + inv.by_name("bowl").extents[2] / 2 + 0.001)
    planner = _Pinned(inv, resting)
    with pytest.raises(StepFailed) as e:
        plan_item(_request(inv, task, resting, planner), strategies_for(task), {})
    assert e.value.details.get("blocking") == 2 and e.value.details.get("pinned_by") == (2,)
    assert all(any(o is resting for o in objs) for objs in planner.objects)
