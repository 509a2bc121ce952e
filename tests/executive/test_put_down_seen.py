"""What a put-down after a fault let go at a target is checked there, as any placement: where the sink still shows
an item of its class (the hand held another item than the one believed: a pinch across two plates of a stack took
the one below), a check of the sink alone says "still in the sink" and forgot the put-down; the spot looked free
and the next plate was carried into the one standing there (executive/execution.py, ``_expect_placed``). Oracle
perception: the executive's mechanism is under test."""

from __future__ import annotations

import numpy as np

from kitchenbot.executive.failures import StepFailed


def test_an_item_let_go_at_a_target_while_the_sink_still_shows_its_class_is_recorded_there(make_runner):
    runner, world = make_runner(task="sink-pick")
    for dev in (runner.arm, runner.gripper, runner.camera):
        dev.connect()
    assert [runner._do_scan(), runner._do_perceive(), runner._do_select_grasp()] == ["scanned", "perceived",
                                                                                    "selected"]
    obj = runner.item.obj  # the cup believed in hand, still in the sink
    tgt = runner.item.targets[0]  # a drop-zone spot on the counter
    cup = runner.robot.inventory[obj.obj_id]
    world.add_object(cup, np.array(tgt.T_base_obj, float))  # what the put-down let go there: another cup
    runner._expect_placed(tgt, np.array(tgt.T_base_obj, float), staging=False)
    try:
        runner._perceive()  # the next perception verifies the put-down
    except StepFailed as e:  # before: "the cup is still in the sink", nothing recorded at the target
        raise AssertionError(f"put-down not recorded: {e}") from e
    placed = [p for p in runner.belief.placed if np.linalg.norm(p.T_base_obj[:3, 3] - tgt.T_base_obj[:3, 3]) < 0.03]
    assert len(placed) == 1  # the spot is taken for every later plan
