"""The task state machine, declared as a table (states + transitions) and built with `transitions`.

The table is the single description: the runner drives it, `mermaid()` draws it (``kitchenbot run --diagram``,
docs/executive.md), and the journal records every trigger it fires. Per-state timeouts and retry bounds live
beside the states so the policy reads in one place.

Cycle: scan -> perceive -> select_grasp -> plan -> execute -> verify -> (select_grasp | scan | done);
any working state may `fault` into `recover`, which re-scans, tries the next grasp/object, or gives up
(`failed`, with the arm at a safe pose and the gripper open over a safe place). `pause` takes effect at safe
points (between motions); `stop` acts at once from anywhere.
"""

from __future__ import annotations

from dataclasses import dataclass

from transitions import Machine


@dataclass(frozen=True)
class StateSpec:
    name: str
    timeout_s: float | None  # seconds a single visit may take (None: unbounded); in simulation wall + simulated
    #                          seconds. Generous: they catch hangs, not slowness (verify = a scan + perception).
    doc: str


#: The states. Timeouts bound one visit (execute: per motion segment they are also derived from durations).
STATES: tuple[StateSpec, ...] = (
    StateSpec("idle", None, "nothing running"),
    StateSpec("scan", 90.0, "visit the scan waypoints, capture a view at each"),
    StateSpec("perceive", 180.0, "views -> object poses in the base frame"),
    StateSpec("select_grasp", 10.0, "choose the next object (task order) and its target place"),
    StateSpec("plan", 60.0, "plan pick (approach, grasp-in, lift) and place (transfer, lower, retreat)"),
    StateSpec("execute", 120.0, "run the plan with asynchronous moves and polling; gripper checks"),
    StateSpec("verify", 240.0, "the placement view where it settles it, else (if enabled) one view of the pick "
                               "region, else a re-scan: gone from the sink, present at the target"),
    StateSpec("recover", 120.0, "clear the fault, back out, decide: re-scan, next grasp/object, give up"),
    StateSpec("paused", None, "holding still at a safe point until resumed"),
    StateSpec("stopped", None, "stopped on request (terminal)"),
    StateSpec("done", None, "task complete (terminal)"),
    StateSpec("failed", None, "gave up; arm at a safe pose, gripper open (terminal)"),
)

WORKING = ["scan", "perceive", "select_grasp", "plan", "execute", "verify", "recover"]
TERMINAL = ["stopped", "done", "failed"]

#: The transitions table: (trigger, source(s), dest).
TRANSITIONS: tuple[tuple[str, str | list[str], str], ...] = (
    ("start", "idle", "scan"),
    ("scanned", "scan", "perceive"),
    ("perceived", "perceive", "select_grasp"),
    ("selected", "select_grasp", "plan"),
    ("nothing_left", "select_grasp", "verify"),  # nothing pickable: confirm with a fresh scan
    ("planned", "plan", "execute"),
    ("executed", "execute", "verify"),
    ("next_object", "verify", "select_grasp"),
    ("complete", "verify", "done"),
    ("fault", list(WORKING), "recover"),
    ("rescan", "recover", "scan"),
    ("retry", "recover", "select_grasp"),  # next grasp of the same object, or the next object
    ("give_up", list(WORKING), "failed"),
    ("pause", list(WORKING), "paused"),
    ("resume", "paused", "scan"),  # the world may have changed while paused: look again
    ("stop", list(WORKING) + ["paused", "idle"], "stopped"),
)

#: Retry bounds the runner enforces.
MAX_ATTEMPTS_PER_OBJECT = 3  # grasp attempts on one object before it is skipped
MAX_PLAN_FAILURES_PER_SCENE = 2  # planning failures on one object before it waits for the scene to change
MAX_SLIDES_PER_OBJECT = 2  # sideways slides of one item (freeing a nested plate) before it is left
MAX_SET_ASIDE_PLANS = 2  # plans to set aside one item with no target that blocks another (strategies.SetAsideBlocker)
MAX_SCAN_RETRIES = 3  # consecutive failed scans (camera/arm faults) before giving up
MAX_CONSECUTIVE_RECOVERIES = 6  # recoveries without a verified placement in between
CONFIRM_EMPTY_SCANS = 2  # consecutive scans that must agree the work is done (missed detections)


def timeout_of(state: str) -> float | None:
    for s in STATES:
        if s.name == state:
            return s.timeout_s
    raise KeyError(f"unknown state {state!r}")


class MachineModel:
    """The object `transitions` attaches `state` and the trigger methods to."""

    state: str


def build_machine(model: object | None = None, after_state_change=None) -> Machine:
    """A `transitions.Machine` over `model` from the table; `after_state_change` is called after each."""
    model = model if model is not None else MachineModel()
    return Machine(
        model=model,
        states=[s.name for s in STATES],
        transitions=[{"trigger": t, "source": src, "dest": dst} for t, src, dst in TRANSITIONS],
        initial="idle",
        auto_transitions=False,
        after_state_change=after_state_change,
        ignore_invalid_triggers=False,
    )


def mermaid() -> str:
    """The machine as a mermaid `stateDiagram-v2`, generated from the table."""
    lines = ["stateDiagram-v2", "    [*] --> idle"]
    for trig, src, dst in TRANSITIONS:
        for s in [src] if isinstance(src, str) else src:
            lines.append(f"    {s} --> {dst}: {trig}")
    for s in TERMINAL:
        lines.append(f"    {s} --> [*]")
    for s in STATES:
        if s.timeout_s is not None:
            lines.append(f"    note right of {s.name}: timeout {s.timeout_s:g} s")
    return "\n".join(lines)
