"""The recovery rules, as a table: which failure, under what condition, which recovery actions (in order), and
what the state machine does then. The ``recover`` state takes the first rule that applies
(RecoveryActions._do_recover); docs/executive.md's table is generated from this one (``kitchenbot docs``).

Actions are RecoveryActions methods named ``_<action>`` (executive/recovery.py); each is described in ACTIONS.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from kitchenbot.executive import machine as M
from kitchenbot.executive.failures import Failure

CAMERA = ("camera_timeout", "bad_depth")


@dataclass(frozen=True)
class Rule:
    failures: str  # the failure kinds it is about (for people)
    condition: str  # when it applies, in words
    applies: Callable[[Failure, object], bool]  # (failure, the runner's counters) -> bool
    actions: tuple[str, ...]
    then: str  # give_up | retry | rescan (the trigger fired)
    why: str = ""
    message: str = "gave up after {kind}: {message}"  # the report's message when it gives up


#: The rules, first match wins. `c` is the runner's Counters (executive/runner.py).
RULES: tuple[Rule, ...] = (
    Rule("`estop`", "always", lambda f, c: f.kind == "estop", (), "give_up",
         "a person must release it; the journal requires homing; the arm is not moved"),
    Rule("`error` (an unexpected exception)", "always", lambda f, c: f.kind == "error", ("make_safe",), "give_up",
         "a bug is not retried"),
    Rule("any but `planning`", f"more than {M.MAX_CONSECUTIVE_RECOVERIES} recoveries without a verified placement",
         lambda f, c: c.consecutive_recoveries > M.MAX_CONSECUTIVE_RECOVERIES, ("make_safe",), "give_up"),
    Rule("`camera_timeout`, `bad_depth`", f"the {M.MAX_SCAN_RETRIES}rd failing scan in a row",
         lambda f, c: f.kind in CAMERA and c.scan_failures >= M.MAX_SCAN_RETRIES,
         ("restore_devices", "make_safe"), "give_up", message="camera keeps failing: {message}"),
    Rule("`planning`", "in plan",
         lambda f, c: f.kind == "planning" and f.state == "plan",
         ("restore_devices", "record_plan_failure", "prefer_blocker"), "retry",
         "the other items are tried first, since the same poses give the same answer; after "
         f"{M.MAX_PLAN_FAILURES_PER_SCENE} failures an item waits until the scene has changed"),
    Rule("anything else (`protective_stop`, `contact`, `grasp_missed`, `slip`, `verify_failed`, `timeout`, "
         "`limit_violation`, `no_path`, `camera_timeout`, `bad_depth`, `arm_disconnected`, `gripper_hardware`)",
         "otherwise",
         lambda f, c: True,
         ("restore_devices", "record_failure", "back_off", "leave_after_slip", "put_down_held", "mark_lift_contact",
          "back_out", "search_drop_site"), "rescan"),
)

#: What each action does (the docs table's legend; the methods are in executive/recovery.py).
ACTIONS: dict[str, str] = {
    "make_safe": "put down what is held, the arm to `robot.home`, the gripper open (the report's `safe` says "
                 "whether that worked)",
    "restore_devices": "reconnect the arm (at most `RunOptions.max_reconnects`, 3, per run), unlock a "
                       "protective stop, reboot and open a faulted gripper, stop a moving arm",
    "record_plan_failure": "count a planning failure against the item in the belief (skipped until the scene "
                           "changes after too many)",
    "prefer_blocker": "the item the planner named as lying on this one or in its lift's way is selected next "
                      "(strategy `blocker_first`)",
    "record_failure": "note the failure against the item (executed attempts are counted when executed)",
    "back_off": "after a protective stop or a contact: mark where the motion met something (a sliver of the "
                "space the pads and the held item were about to sweep, kept as map points no object explains) "
                "and go back along the stopped motion to its start (the one way known to be free); a stopped lift "
                "goes back down to 5 mm above where the item was taken and lets go there (a put-down planned from "
                "the stop point started against what the lift met and met it again): that item keeps the lift's "
                "direction instead (its next plans lift it another way) and its sliver is not marked (it filled "
                "the space of the item's own next grasp)",
    "leave_after_slip": "after a slip: the strategies for a `slip` (below, executive/recovery_strategies.py): "
                        "on a lift, on up along its rest, checked, out of the items before the re-scan",
    "put_down_held": "anything still held: at its target, else the drop zone (staged, picked up again unless the "
                     "task takes it there), else open in place over the cell; never again within 10 cm of a target "
                     "whose way in was just stopped",
    "mark_lift_contact": "after a stopped lift whose item was put down elsewhere (not let go where it was "
                         "taken): the sliver the lift was about to sweep is marked, so the next try lifts clear of it",
    "back_out": "after a failed grasp: open and retrace the grasp-in line, else 8 cm straight up",
    "search_drop_site": "an item that slipped out (or a placement not seen at its target) outside the sink: the "
                        "camera straight down at the spot, perception without the cell, and an item of its class "
                        "found within 25 cm is picked up again from there (`recovered_drops`); where it cannot be "
                        "seen, a keep-out cylinder stays for the run; where it is seen but not recognised, what "
                        "the view shows inside that cylinder and nothing believed explains stays marked",
}


def rule_for(f: Failure, counters) -> Rule:
    return next(r for r in RULES if r.applies(f, counters))


def rules_markdown() -> str:
    """The rules and the actions as markdown tables (docs/executive.md)."""
    lines = ["| failure | when | actions, in order | then |", "|---|---|---|---|"]
    for r in RULES:
        acts = ", ".join(f"`{a}`" for a in r.actions) or "-"
        then = f"**{r.then}**" + (f" ({r.why})" if r.why else "")
        lines.append(f"| {r.failures} | {r.condition} | {acts} | {then} |")
    lines += ["", "| action | what it does |", "|---|---|"]
    lines += [f"| `{a}` | {d} |" for a, d in ACTIONS.items()]
    return "\n".join(lines)
