"""Escaping a stop within the collision margin: a short straight TCP line that ends with every margin kept."""

import numpy as np
import pytest

from kitchenbot.planning.escape import plan_escape

pytestmark = pytest.mark.timeout(120)


def _tcp_down_at(planner, home, xyz):
    T = planner.robot.fk_tcp(home)  # home points the tool down
    T[:3, 3] = xyz
    q = planner.robot.ik_q(T, home)
    assert q is not None
    return q


def test_stopped_near_the_sink_floor_escapes_up(planner, home):
    lo, _ = planner.cell.sink_interior
    # finger tips (12 mm past the TCP) 5 mm above the sink floor: inside the 1 cm margin, not touching
    q0 = _tcp_down_at(planner, home, (0.50, 0.0, lo[2] + 0.012 + 0.005))
    scene = planner.scene([])
    assert not scene.valid(q0)
    assert planner.plan_move(q0, home).kind == "start_in_collision"

    plan = planner.plan_escape(q0)
    assert plan.ok, plan
    q_end = plan.trajectory.q[-1]
    assert scene.valid(q_end)
    rise = planner.robot.fk_tcp(q_end)[2, 3] - planner.robot.fk_tcp(q0)[2, 3]
    assert rise > 0.03  # out, upwards
    assert planner.plan_move(q_end, home).ok  # and from there planned motions work again
    # every sample of the escape keeps the close pairs from touching
    close = scene.touching_only(scene.colliding_pairs(q0))
    assert all(close.valid(q) for q in plan.trajectory.q)


def test_touching_start_is_refused(planner, home):
    lo, _ = planner.cell.sink_interior
    q0 = _tcp_down_at(planner, home, (0.50, 0.0, lo[2] + 0.012 - 0.004))  # finger tips 4 mm into the floor
    res = plan_escape(planner, q0)
    assert not res.ok and res.kind == "start_in_collision"


def test_nothing_to_escape_from(planner, home):
    res = planner.plan_escape(home)
    assert not res.ok and "nothing to escape" in res.message
