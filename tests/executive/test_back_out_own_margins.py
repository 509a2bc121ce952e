"""The straight rise out of the sink after a failed grasp or a slip keeps the arm's own margins
(executive/recovery.py `_back_out`, planning.leave.rise_keeping_own_margins).

A lift stopped part-way up (its plate slipped out) left the tool low in the sink, off the grasp-in line: the
recovery rose straight up 8 cm unplanned and unchecked, which swung the wrist (link6) within the margin of the
forearm (link3). Every planner then refused that start and the run gave up with items left in the sink."""

from __future__ import annotations

import numpy as np

from kitchenbot.executive.failures import Failure
from kitchenbot.executive.runner import RunOptions
from kitchenbot.executive.session import build_runner

# part-way up a lift out of the sink (TCP ~9 cm below the rim), the wrist turned back towards the forearm
Q_STOPPED = np.array([2.6288, -1.0942, 2.0646, 0.2484, 1.3321, 2.5246])


def test_the_rise_after_a_slip_ends_with_the_arms_own_margins_kept(small_config, tmp_path):
    cfg = small_config()
    runner = build_runner(cfg, "sink-pick", 0, oracle_perception=True, journal_path=tmp_path / "journal.sqlite",
                          options=RunOptions(poll_period=0.05, confirm_empty_scans=1))
    for dev in (runner.arm, runner.gripper, runner.camera):
        dev.connect()
    runner.arm.move_joints(Q_STOPPED)
    free = runner.planner.world.scene()  # the arm's own pairs (and the cell, which the rise does not reach)
    assert free.valid(Q_STOPPED)
    z0 = runner.arm.tcp_pose()[2, 3]
    lo, hi = runner.robot.cell.sink_interior
    assert np.all(runner.arm.tcp_pose()[:2, 3] >= np.asarray(lo)[:2]) and z0 < 0.05  # deep in the sink
    runner.failure = Failure("slip", "the plate slipped out during trajectory lift", "execute")
    assert runner.item.pick is None  # (a pick stopped off its grasp-in line goes on the same way)
    runner._back_out()
    q = runner.arm.joint_positions()
    assert ("link3", "link6") not in free.colliding_pairs(q) and free.valid(q)  # planned motions can start here
    assert runner.arm.tcp_pose()[2, 3] > z0 + 0.015  # and it did rise
