"""Two identical dinner plates nested flat in the sink, seen as one plate (the lower one hidden under the upper, as
perception sees a real pair). The upper one is carried into its dishwasher slot and let go there; the view of the
target does not show it where it was recorded (a plate on edge seen from above, leaning against a tine), and the
re-scan still shows a plate where it was picked: the lower one, now uncovered.

Before, the verify decided "the plate is still in the sink" and the placement was forgotten: the slot looked free
and the next plate (the lower one) was carried into the one standing there. Now the evidence is weighed
(executive/verify.py, ``where_it_went``): the gripper held it from the lift to its release at the target, so it
is not in the sink whatever the sink shows there; it stays recorded in its slot as an obstacle (looked at again
from above: seen there, verified), and the plate seen where it was picked is another item, with no attempts of its
own. A put-down whose hold was not polled on the way keeps the old rule. Oracle perception: the executive's
mechanism is under test."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.executive.failures import StepFailed
from kitchenbot.executive.verify import (KEPT, NOT_TAKEN, PLACED, UNSEEN, Presence, target_presence,
                                         where_it_went)
from kitchenbot.perception.types import View
from kitchenbot.transforms import make_T

from tests.executive.test_nested_plates import nested_plates_runner


def _looking_down_at(xyz, behind: float) -> View:
    """A 320x240 depth camera 0.4 m straight above `xyz` whose every pixel measures `behind` m further than the
    point itself: whatever model stands there, the view sees past it (decided absent)."""
    R = np.diag([1.0, -1.0, -1.0])  # camera z (its optical axis) pointing down
    T = make_T(R, (xyz[0], xyz[1], xyz[2] + 0.4))
    K = np.array([[300.0, 0.0, 160.0], [0.0, 300.0, 120.0], [0.0, 0.0, 1.0]])
    depth = np.full((240, 320), 0.4 + behind, np.float32)
    return View(np.zeros((240, 320, 3), np.uint8), depth, K, T)


@pytest.fixture
def stacked(small_config, tmp_path):
    runner, world, lower, upper = nested_plates_runner(small_config(), "sink-to-dishwasher",
                                                       tmp_path / "journal.sqlite", hidden_while_held=True)
    assert [runner._do_scan(), runner._do_perceive(), runner._do_select_grasp()] == ["scanned", "perceived",
                                                                                    "selected"]
    assert runner.item.obj.instance_id == upper  # the pair, seen as one plate, at the upper one's pose
    return runner, world, lower, upper


def _place_upper_unseen(runner, world, upper, carried: bool):
    """The upper plate carried into its slot and let go there; the target's view sees past it."""
    obj, tgt = runner.item.obj, runner.item.targets[0]
    T = np.array(tgt.T_base_obj, float)
    runner.belief.record_attempt(obj)  # as the execute state records it
    world.set_pose(upper, T)  # it stands in its slot
    view = _looking_down_at(T[:3, 3], behind=0.3)
    assert not target_presence(view, runner.robot.inventory[obj.obj_id], T).present  # the view says absent
    runner._target_view = lambda where: view
    runner._expect_placed(tgt, T, staging=False, **({} if carried else {"carried": False}))
    return T


def _at(records, xyz, tol=0.03):
    return [p for p in records if np.linalg.norm(p.T_base_obj[:3, 3] - xyz) < tol]


def test_a_plate_carried_off_a_stack_stays_in_its_slot_and_the_one_under_it_is_a_new_sink_item(stacked):
    runner, world, lower, upper = stacked
    T = _place_upper_unseen(runner, world, upper, carried=True)
    with pytest.raises(StepFailed) as e:
        runner._perceive()  # the re-scan's perception verifies the placement
    assert e.value.kind == "verify_failed"
    assert "still in the sink" not in str(e.value)  # before: "the plate is still in the sink"
    b = runner.belief
    assert len(_at(b.placed, T[:3, 3])) == 1, "the placed plate forgotten: its slot looks free"  # before: 0
    assert _at(b.obstacles(), T[:3, 3])  # every later plan keeps clear of it
    under = [q for q in b.poses if q.instance_id == lower]
    assert under and runner.task.remaining(b.poses) == under  # the one under it: the sink's item now
    assert b.attempts_for(under[0]) is None  # a new item: the attempts on the one carried away are not its
    site, rec = b.take_drop_site()  # the recovery looks at the target again from above
    assert rec is not None and np.allclose(site, T[:3, 3])


def _showing(view: View, model, T: np.ndarray) -> View:
    """`view` with the item at T drawn into its depth (nearest surface per 4x4 pixel block), the rest unchanged."""
    T_cam_obj = np.linalg.inv(view.T_base_cam) @ T
    P = model.points @ T_cam_obj[:3, :3].T + T_cam_obj[:3, 3]
    uv = P @ view.K.T
    u, v = (uv[:, 0] / uv[:, 2]).astype(int) // 4, (uv[:, 1] / uv[:, 2]).astype(int) // 4
    depth = view.depth.copy()
    for k in np.argsort(-P[:, 2]):  # far to near: the nearest surface is written last
        depth[4 * v[k]:4 * v[k] + 4, 4 * u[k]:4 * u[k] + 4] = P[k, 2]
    return View(view.rgb, depth, view.K, view.T_base_cam)


def test_a_second_look_that_shows_it_standing_at_its_target_verifies_it_there(stacked):
    runner, world, lower, upper = stacked
    T = _place_upper_unseen(runner, world, upper, carried=True)
    with pytest.raises(StepFailed):
        runner._perceive()
    b = runner.belief
    (rec,) = _at(b.placed, T[:3, 3])
    assert b.unverified == ["plate"] and runner.report.objects_done == 0
    model = runner.robot.inventory[rec.obj_id]
    assert not runner._seen_at_its_target(_looking_down_at(T[:3, 3], behind=0.3), rec)  # seen past it again
    assert b.unverified == ["plate"] and runner.report.objects_done == 0
    view = _showing(_looking_down_at(T[:3, 3], behind=0.3), model, rec.T_base_obj)
    assert runner._seen_at_its_target(view, rec)  # this look shows it standing there
    assert b.unverified == [] and runner.report.objects_done == 1
    assert _at(b.placed, T[:3, 3])  # it stays in its slot (not picked out of it again)


def test_a_put_down_whose_hold_was_not_polled_keeps_the_old_rule(stacked):
    runner, world, lower, upper = stacked
    T = _place_upper_unseen(runner, world, upper, carried=False)
    with pytest.raises(StepFailed) as e:
        runner._perceive()
    assert "still in the sink" in str(e.value)
    assert not _at(runner.belief.placed, T[:3, 3])


def _p(present: bool | None) -> Presence | None:
    if present is None:
        return None
    return Presence(200, 0.9 if present else 0.2, True, present)


@pytest.mark.parametrize("carried,still,presence,went", [
    (True, True, _p(True), PLACED), (True, False, _p(True), PLACED), (False, True, _p(True), PLACED),
    (True, True, None, KEPT), (False, True, Presence(10, 0.0, False, False), KEPT),
    (True, True, _p(False), UNSEEN),  # before: "still in the sink", the record dropped
    (False, True, _p(False), NOT_TAKEN),
    (True, False, _p(False), UNSEEN), (False, False, _p(False), UNSEEN),
    (True, False, None, PLACED), (False, False, None, PLACED),
])
def test_where_it_went_weighs_the_carry_the_sink_and_the_target_view(carried, still, presence, went):
    assert where_it_went(carried, still, presence) == went
