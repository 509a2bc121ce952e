"""The report of one task run (what ``run_task`` returns and ``--report`` writes): outcome, counts, per-state
times, failures, the strategies and recovery actions used, and (simulation) the truth audit."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np


@dataclass
class RunReport:
    task: str
    status: str = "running"  # succeeded | unrecognised_left (sink empty but for `unrecognised`) | failed | stopped
    objects_total: int = 0
    objects_done: int = 0
    attempts: int = 0
    recoveries: int = 0
    slides: int = 0  # items slid sideways to free them (the top plate of a nested stack)
    escapes: int = 0  # straight moves out of a stop within the collision margin (planning.escape)
    recovered_drops: int = 0  # items that slipped out over the counter, found there and picked up again
    strategies: dict = field(default_factory=dict)  # per strategy (executive/strategies.py): tried, planned
    recovery_actions: dict = field(default_factory=dict)  # per recovery action (executive/recovery_rules.py): count
    recovery_strategies: dict = field(default_factory=dict)  # "kind/strategy" (recovery_strategies.py) that worked
    state_time_s: dict = field(default_factory=dict)  # wall seconds per state
    state_sim_time_s: dict = field(default_factory=dict)  # simulated seconds per state (simulation only)
    transitions: list = field(default_factory=list)
    failures: list = field(default_factory=list)
    collisions: int | None = None  # counted by the fake arm
    limit_violations: int | None = None  # commands the safety limits refused
    protective_stops: int | None = None
    slips: int | None = None
    cycles: list = field(default_factory=list)  # per placement: compute_s, motion_s, object
    compute_time_s: float = 0.0  # wall seconds of everything but waiting for motions
    compute_cpu_time_s: float = 0.0  # process CPU seconds of the same (less distorted by a loaded machine)
    compute_by_stage_s: dict = field(default_factory=dict)  # compute wall seconds per stage (executive/stage_times.py)
    compute_cpu_by_stage_s: dict = field(default_factory=dict)  # compute CPU seconds per stage
    items_per_minute: float | None = None  # objects done per minute of simulated motion + compute (see rate)
    wall_time_s: float = 0.0
    sim_time_s: float | None = None
    seed: int | None = None
    run_id: int | None = None
    perception: str = "pipeline"  # pipeline | oracle (ground truth from the simulator)
    truth: dict | None = None  # simulation: what really happened
    message: str = ""
    # item-sized things in the sink no pose explains at the end (executive/done_check.py): xyz, size (m), voxels
    unrecognised: list = field(default_factory=list)
    unrecognised_looks: list = field(default_factory=list)  # the targeted looks taken at them: xyz, size, seen
    # items that left the gripper on the way and were not seen again (executive/done_check.py): cls, xyz (m: where
    # the tool was when it fell)
    lost: list = field(default_factory=list)
    sink_drop_looks: int = 0  # looks at where an item fell above the sink that no scan saw back in it
    safe: bool = True  # ended with the arm at a known safe pose

    @property
    def done_status(self) -> str:
        """The status of a run that reached `done`: the sink empty as perceived, but an item-sized thing no pose
        explains left in it (executive/done_check.py) is no success."""
        return "unrecognised_left" if self.unrecognised else "succeeded"

    def rate(self, items: int) -> float | None:
        """`items` per minute of this run's time: in simulation simulated time (motions, gripper, camera frames)
        plus compute (a robot's run would take both: the simulator's motions do not wait for the computer, so
        wall time would count the simulator's own stepping); on real devices wall time."""
        t = (self.sim_time_s + self.compute_time_s) if self.sim_time_s is not None else self.wall_time_s
        return round(60.0 * items / t, 3) if t > 0 else None

    def as_dict(self) -> dict:
        return asdict(self)

    def to_dict(self) -> dict:
        """Plain JSON types only (what the report file holds)."""
        return json.loads(json.dumps(self.as_dict(), default=_jsonable))

    def save(self, path: str | Path) -> None:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        Path(path).write_text(json.dumps(self.to_dict(), indent=2))


def _jsonable(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    return str(o)
