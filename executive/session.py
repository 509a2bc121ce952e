"""Wiring for one run: devices (executive.assembly), task, perceiver, planner, journal, recorder, dataset and
the simulation-only hooks (clock tick, missed-detection fault, truth audit). The daemon and `run_task` share it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from kitchenbot.executive.journal import Journal, default_journal_path
from kitchenbot.executive.runner import RunOptions, TaskRunner


def is_simulated(config) -> bool:
    return config.drivers.arm.kind == "fake"


def missed_detection_hook(world):
    """Simulation fault `missed_detection`: the next N perception results each lose one object in the sink."""

    def hook(poses: list) -> list:
        if world.faults.missed_detection > 0 and poses:
            in_sink = [k for k, p in enumerate(poses) if world.cell.in_sink(p.T_base_obj[:3, 3])[0]]
            if in_sink:
                world.faults.missed_detection -= 1
                drop = in_sink[int(world.rng.integers(len(in_sink)))]
                return [p for k, p in enumerate(poses) if k != drop]
        return poses

    return hook


def truth_audit(world, task):
    """What the simulator says: wanted objects in the sink, delivered to their target area, elsewhere."""
    from kitchenbot.perception.types import ObjectPose

    def audit(phase: str) -> dict:
        in_sink = delivered = elsewhere = 0
        lost = []  # where the ones neither in the sink nor delivered are
        for uid, o in world.objects.items():
            p = ObjectPose(o.model.obj_id, o.model.cls, o.T_base_obj, 1.0, instance_id=uid)
            if not task.wants(p):
                continue
            if uid != world.held_uid and world.cell.in_sink(o.T_base_obj[:3, 3])[0]:
                in_sink += 1
            elif uid != world.held_uid and task.at_target(o.model.cls, o.T_base_obj):
                delivered += 1
            else:
                elsewhere += 1
                lost.append({"cls": o.model.cls, "xyz": np.round(o.T_base_obj[:3, 3], 3).tolist(),
                             "held": uid == world.held_uid})
        return {"in_sink": in_sink, "delivered": delivered, "elsewhere": elsewhere, "held": world.held_uid is not None,
                "elsewhere_items": lost}

    return audit


def make_perceiver(config, robot, oracle: bool):
    if oracle:
        if robot.world is None:
            raise ValueError("--oracle-perception reads the simulator's truth: it needs the simulated cell (--sim)")
        from kitchenbot.executive.oracle import OraclePerceiver

        return OraclePerceiver(robot.world), "oracle"
    from kitchenbot.perception.pipeline import Perceiver

    return Perceiver(config.perception, robot.inventory, robot.cell), "pipeline"


def open_journal(config, journal_path) -> Journal | None:
    if journal_path is False:
        return None
    return Journal(journal_path or default_journal_path(is_simulated(config)))


def build_runner(config, task_name: str, seed: int | None = None, *, record_path=None, oracle_perception=False,
                 journal_path=None, dataset_dir=None, listeners=None, robot=None, options: RunOptions | None = None,
                 journal: Journal | None = None, planner=None) -> TaskRunner:
    from kitchenbot.executive.assembly import assemble
    from kitchenbot.planning.pick_place import Planner
    from kitchenbot.tasks import make_task

    from kitchenbot.tasks import TASKS

    if task_name not in TASKS:
        raise ValueError(f"unknown task {task_name!r}; expected one of {sorted(TASKS)}")
    seed = config.sim.seed if seed is None else seed
    owns = robot is None
    robot = robot or assemble(config, seed)
    task = make_task(task_name, robot.inventory, robot.cell)
    planner = planner or Planner.from_config(config, robot.inventory)
    if planner.q_rest is None and config.scan_waypoints:  # a re-scan, or the move back over the sink, ends there
        planner.q_rest = np.asarray(config.scan_waypoints[-1], float)
    perceiver, label = make_perceiver(config, robot, oracle_perception)
    if journal is None:
        journal = open_journal(config, journal_path)
    recorder = None
    if record_path:
        from kitchenbot.executive.recording import Recorder

        recorder = Recorder(record_path, robot.arm.model, config.robot.tool.T_flange_tcp.matrix(), robot.inventory,
                            f"{task_name}-{seed}")
    dataset = None
    if dataset_dir:
        from kitchenbot.executive.recording import ScanDataset

        dataset = ScanDataset(Path(dataset_dir))
    world = robot.world
    sim = world is not None and is_simulated(config)
    if journal is not None and sim and owns:
        # A simulated cell assembled just now has its arm at the home pose: an earlier simulation that was
        # killed leaves nothing to home here (real arms keep the interlock).
        journal.recover()
        journal.mark_homed()
    opt = options or RunOptions(poll_period=0.05 if sim else 0.01)
    runner = TaskRunner(
        robot, task, perceiver, planner, journal=journal, recorder=recorder, dataset=dataset, listeners=listeners,
        advance=robot.arm.step if sim else None,
        sim_clock=world.clock.now if world is not None else None,
        fault_hook=missed_detection_hook(world) if world is not None else None,
        options=opt, seed=seed, perception_label=label,
        truth=truth_audit(world, task) if world is not None else None,
    )
    runner.owns_devices = owns
    return runner


__all__ = ["build_runner", "is_simulated", "make_perceiver", "missed_detection_hook", "open_journal", "truth_audit",
]
