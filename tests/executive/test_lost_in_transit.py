"""An item lost in transit is found again or named in the run's outcome, never a silent success
(executive/done_check.py `_look_for_sink_drops`, Belief.await_in_sink / lost_drops)."""

import numpy as np

from kitchenbot.executive.oracle import OracleResult


class _HidesOnTheRim:
    """Oracle perception that does not see an item resting above the counter top (as the pipeline does not see a
    plate tilted on the sink's rim: it segments the basin)."""

    def __init__(self, real, world):
        self.real, self.world = real, world

    def __getattr__(self, name):
        return getattr(self.real, name)

    def perceive(self, views, *a, **kw):
        res = self.real.perceive(views)
        return OracleResult([p for p in res.poses if p.T_base_obj[2, 3] < 0.0])


def test_an_item_that_slips_onto_the_rim_is_no_silent_success(make_runner, safe_end):
    """Two cups; the first slips out during its lift above the sink and comes to rest tilted on the sink's rim,
    above the basin, where no scan poses it. Before, a drop above the sink counted as found at once ("the re-scan
    finds it"), and the run ended `succeeded` with the cup still there. Now the scans never see it back: the run
    looks straight down where it fell, sees something no model explains above the rim, and ends naming the drop and
    where it was last held."""
    runner, world = make_runner(task="sink-pick", cups=2, confirm=2)
    runner.perceiver = _HidesOnTheRim(runner.perceiver, world)
    lo, hi = world.cell.sink_interior
    attach, slip = world.attach, runner.arm._slip
    state = {"uid": None}

    def attach_slipping_once_in_the_lift(uid, slip=True):
        attach(uid, slip)
        if slip and state["uid"] is None:
            state["uid"] = uid
            world.slip_in_motions = 0  # the next motion: the lift

    def slip_onto_the_rim():
        uid = world.held_uid
        slip()
        if uid == state["uid"]:  # it bounced onto the rim: lying tilted 3 cm inside the basin's edge, above it
            T = np.eye(4)
            c, s = np.cos(np.radians(70.0)), np.sin(np.radians(70.0))
            T[:3, :3] = [[1, 0, 0], [0, c, -s], [0, s, c]]
            tcp = runner.arm.tcp_pose()[:3, 3]  # beside where it fell, toward the nearer wall
            y = hi[1] - 0.03 if tcp[1] > (lo[1] + hi[1]) / 2 else lo[1] + 0.03
            T[:3, 3] = (tcp[0], float(np.clip(y, tcp[1] - 0.12, tcp[1] + 0.12)), 0.03)
            world.set_pose(uid, T)

    world.attach = attach_slipping_once_in_the_lift
    runner.arm._slip = slip_onto_the_rim
    report = runner.run()
    safe_end(runner, world)
    assert report.slips >= 1
    assert report.truth["end"]["in_sink"] == 1  # the simulator's truth: it is still there (on the rim)
    assert report.status != "succeeded", report.message
    assert "dropped during the run" in report.message and "last held at" in report.message, report.message
    assert report.sink_drop_looks == 1
    assert len(report.lost) == 1 and report.lost[0]["cls"] == "cup"
