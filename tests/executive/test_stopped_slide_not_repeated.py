"""A slide stopped on the way (a protective stop while the closed fingers press on the top plate of a leaning
nest) was planned again unchanged: the rescan gave the same belief, the planner the same press, yaw and direction,
and the arm stopped the same way, spending the item's slides (MAX_SLIDES_PER_OBJECT). Now the stopped slide is
recorded on the item (`Belief.record_slide_stopped`, from executive/execution.py `_execute_slide`) and the next
plan of it takes another press, yaw or direction (planning/slide.py `repeats`)."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.drivers.errors import ProtectiveStopError
from kitchenbot.executive.assembly import assemble
from kitchenbot.executive.belief import Belief
from kitchenbot.executive.oracle import OraclePerceiver
from kitchenbot.executive.runner import RunOptions
from kitchenbot.executive.session import build_runner
from kitchenbot.executive.strategies import PlanRequest, _slide_plan
from kitchenbot.planning.slide import repeats

from tests.planning.test_slide_sloping_top import nest_world

from .conftest import _small_config

pytestmark = pytest.mark.timeout(300)


def test_a_slide_stopped_on_the_way_is_not_planned_again_unchanged():
    cfg = _small_config()
    world, _, top_uid = nest_world(cfg)
    runner = build_runner(cfg, "sink-pick", 0, robot=assemble(cfg, world=world), oracle_perception=True,
                          journal_path=False, options=RunOptions(poll_period=0.05, confirm_empty_scans=1))
    for dev in (runner.arm, runner.gripper, runner.camera):
        dev.connect()
    poses = OraclePerceiver(world).perceive([]).poses
    top = next(p for p in poses if p.instance_id == top_uid)
    q0 = world.q.copy()

    def request(belief):  # the same scene each time: the rescan after the stop gives the same belief
        return PlanRequest(obj=top, targets=[], staged=None, task=None, belief=belief, planner=runner.planner,
                           joints=lambda: q0, escape=lambda: True, note=lambda *a, **k: None,
                           check_deadline=lambda: None, scene_objs=poses)

    first = _slide_plan("slide_top_of_nest", request(runner.belief))
    assert first is not None and first.slide.T_base_press is not None
    sl = first.slide
    runner.item.obj, runner.item.plan = top, first
    run = runner._run_trajectory

    def stopped_on_the_slide(traj, *a, **k):  # the arm stops half way along the slide (as on a jam)
        if traj is sl.slide:
            world.faults.protective_stop = 1
        return run(traj, *a, **k)

    runner._run_trajectory = stopped_on_the_slide
    with pytest.raises(ProtectiveStopError):
        runner._execute_slide()
    stopped = runner.belief.stopped_slides(top)
    assert len(stopped) == 1 and np.allclose(stopped[0][0], sl.T_base_press)

    again = _slide_plan("slide_top_of_nest", request(Belief()))  # what the item's record changes: without it,
    assert again is not None and repeats(again.slide.T_base_press, again.slide.direction, stopped)  # the same slide
    second = _slide_plan("slide_top_of_nest", request(runner.belief))
    assert second is not None, "no other slide of the plate"
    assert not repeats(second.slide.T_base_press, second.slide.direction, stopped)
