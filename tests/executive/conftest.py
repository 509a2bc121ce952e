"""Small simulated scenes for the executive's tests (fake drivers; oracle perception where a test says so)."""

from __future__ import annotations

import pytest

from kitchenbot.executive.assembly import assemble, make_sim_world
from kitchenbot.executive.belief import Belief
from kitchenbot.executive.config import load_config
from kitchenbot.executive.runner import RunOptions
from kitchenbot.executive.session import build_runner
from kitchenbot.executive.strategies import PlanRequest, plan_item, strategies_for
from kitchenbot.tasks import make_task


def _small_config(n: int = 3, seed: int = 0, waypoints: int = 1):
    """The shipped sim config with n objects and only the first `waypoints` scan waypoints (oracle tests need
    no more; it keeps each run to a few seconds)."""
    cfg = load_config()
    cfg.sim.min_objects = cfg.sim.max_objects = n
    cfg.sim.seed = seed
    cfg.scan_waypoints = cfg.scan_waypoints[:waypoints]
    return cfg


def _cup_world(cfg, keep_cups: int = 1):
    """Seed 0's three-object scene (a plate under two nested cups) reduced to `keep_cups` cups, settled on what
    is below them. Picks that the planner handles reliably: the point here is the executive."""
    from kitchenbot.fakes.placement import drop_onto

    world = make_sim_world(cfg, 0)
    cups = sorted([u for u, o in world.objects.items() if o.model.cls == "cup"],
                  key=lambda u: world.objects[u].T_base_obj[2, 3])
    for u in list(world.objects):
        if u not in cups[:keep_cups]:
            world.remove_object(u)
    kept = cups[:keep_cups]
    # The plate they rested on is gone: settle the lowest cup (the others out of the way), the rest move with it.
    saved = {u: world.objects[u].T_base_obj.copy() for u in kept[1:]}
    for u in saved:
        far = saved[u].copy()
        far[:3, 3] += (0, 0, 5.0)
        world.set_pose(u, far)
    T0 = world.objects[kept[0]].T_base_obj
    T1 = drop_onto(world, kept[0], T0)
    world.set_pose(kept[0], T1)
    for u, T in saved.items():
        T = T.copy()
        T[2, 3] += T1[2, 3] - T0[2, 3]
        world.set_pose(u, T)
    return world


@pytest.fixture
def small_config():
    """small_config(n=3, seed=0, waypoints=1) -> CellConfig"""
    return _small_config


@pytest.fixture
def cup_world():
    """cup_world(cfg, keep_cups=1) -> SimWorld with only cups in the sink"""
    return _cup_world


@pytest.fixture
def safe_end():
    """safe_end(runner, world): asserts the run ended safe and journaled."""
    return assert_safe_end


@pytest.fixture
def state_dir(tmp_path, monkeypatch):
    monkeypatch.setenv("KITCHENBOT_STATE_DIR", str(tmp_path / "state"))
    return tmp_path / "state"


@pytest.fixture
def make_runner(tmp_path):
    """make_runner(task="cup-stacking", cups=1, oracle=True, journal=True) -> (runner, world)."""

    def make(task: str = "cup-stacking", cups: int = 1, oracle: bool = True, journal: bool = True,
             waypoints: int = 1, confirm: int = 1, **kw):
        cfg = _small_config(waypoints=waypoints)
        world = _cup_world(cfg, cups)
        robot = assemble(cfg, world=world)
        runner = build_runner(cfg, task, 0, robot=robot, oracle_perception=oracle,
                              journal_path=(tmp_path / "journal.sqlite") if journal else False,
                              options=kw.pop("options", RunOptions(poll_period=0.05, confirm_empty_scans=confirm)), **kw)
        return runner, world

    return make


def assert_safe_end(runner, world) -> None:
    """The run ended in a terminal state, journaled, with nothing in the gripper and the arm still."""
    assert runner.state in ("done", "failed", "stopped")
    assert world.held_uid is None
    assert not runner.arm.is_moving()
    j = runner.journal
    if j is not None:
        rec = j.run(runner.run_id)
        assert rec.ended is not None and rec.status == runner.report.status
        trans = j.events(runner.run_id, kind="transition")
        assert [e["name"] for e in trans] == [t["trigger"] for t in runner.report.transitions]




@pytest.fixture
def record_staged():
    """A function (runner, model, T_put) -> Placed: records `model` as staged on the counter at T_put (released
    1 cm above it, as a put-down for a regrasp is), the way the executive records a staged item."""
    from kitchenbot.executive.belief import as_pose
    from kitchenbot.planning.types import PlaceTarget

    def record(runner, model, T_put):
        obj = as_pose(type("R", (), {"obj_id": model.obj_id, "cls": model.cls, "T_base_obj": T_put,
                                     "instance_id": -1})())
        T_release = T_put.copy()
        T_release[2, 3] += 0.01
        target = PlaceTarget(T_release, "stage", support="counter (regrasp)")
        rec = runner.belief.record_placed(runner.task, obj, target, T_put)
        runner.belief.record_staged(rec)
        return rec

    return record


@pytest.fixture
def run_slide():
    """A function (world, cfg, slide, uid) -> (start, moved): runs a planned slide's trajectories on the simulated
    arm (gripper closed), checks it met nothing and dragged item `uid` more than 2 cm to within 1 cm of where the
    planner said, and returns the item's pose before and after."""
    import numpy as np

    from kitchenbot.fakes.arm import FakeArm
    from kitchenbot.fakes.gripper import FakeGripper

    def run(world, cfg, slide, uid):
        arm = FakeArm(world, cfg.safety_limits())
        arm.connect()
        grip = FakeGripper(world)
        grip.connect()
        grip.open(0.0)
        start = world.objects[uid].T_base_obj.copy()
        for traj in slide.trajectories:
            arm.execute_trajectory(traj.times, traj.q)
        assert arm.log.collisions == 0 and arm.log.protective_stops == 0
        moved = world.objects[uid].T_base_obj
        assert np.linalg.norm(moved[:2, 3] - start[:2, 3]) > 0.02  # dragged along
        assert np.linalg.norm(moved[:2, 3] - slide.T_base_obj_after[:2, 3]) < 0.01  # where the planner said
        return start, moved

    return run


def plan_with_strategies(task_name, obj, world, planner, poses):
    """Plan OBJ with TASK_NAME's strategies on a fresh belief, the arm where WORLD holds it: (plan, counts)."""
    task, belief = make_task(task_name, world.inventory, planner.cell), Belief()
    req = PlanRequest(obj, task.targets(obj, belief), None, task, belief, planner, lambda: world.q.copy(),
                      lambda: False, lambda *a, **k: None, lambda: None, scene_objs=poses)
    counts: dict = {}
    return plan_item(req, strategies_for(task), counts), counts
