"""Recovery strategies, as data: for a failure kind, the strategies tried in order (MoveIt Task Constructor's
``Fallbacks`` stage, for getting the arm out of a fault rather than an item out of the sink). Each is a small
function with a precondition and a bounded number of tries per cycle (from one pick to the next,
``MotionTracks.new_cycle``). The first whose precondition holds and which succeeds ends the recovery; the journal
("recovery strategy") and the run report (``recovery_strategies``, ``kind/name``: count) name it. When none is left
the caller gets each one's reason (``Outcome.why``), which it puts into the failure it raises.

``STRATEGIES`` is the table; docs/executive.md's table is generated from it (``kitchenbot docs``). The functions
take the task runner (its Motions and RecoveryActions mixins): they use its arm, planner, belief and journal.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from kitchenbot.planning.types import Trajectory

# Motions whose start is clear of any contact (planned from a free pose): the only ones retraced to get out of the
# collision margin. The others start where the tool touched or let go of something (a lift at the grasp, a
# retreat at the release, a retrace or back-off at the stop point, an escape within the margin, a slide on the
# item): going back along them drives the tool back into that contact (a retreat retraced to where a plate was
# let go, and out again, 47 times in one run). A "move" that began by leaving a release (planning.leave) is marked
# as starting at a contact when it is run (``MotionTracks.last_from_contact``).
FREE_START = frozenset({"approach", "grasp_in", "transfer", "lower", "move"})


@dataclass(frozen=True)
class RecoveryStrategy:
    name: str
    when: str  # its precondition, in words (docs)
    does: str  # what it does, in words (docs)
    tries: int  # at most this many runs per cycle
    precondition: Callable[[object], str]  # runner -> "" when it applies, else why not
    run: Callable[[object], str]  # runner -> "" when it worked, else why not


@dataclass
class Outcome:
    strategy: str | None  # the strategy that worked, None when none did
    why: dict = field(default_factory=dict)  # strategy -> why it did not apply or failed

    def __bool__(self) -> bool:
        return self.strategy is not None

    def reason(self) -> str:
        return "; ".join(f"{k}: {v}" for k, v in self.why.items())


# ---- start within the collision margin (a stop left the arm there; every planned motion refuses the start) -------
def _always(r) -> str:
    return ""


def _straight_out(r) -> str:
    """planning.escape: a short straight TCP line out of the margin; where the marks of a stop close every way
    out, those around the arm are dropped and it is planned once more."""
    pick = r.item.pick
    held = pick.grasp if (pick is not None and r._holding()) else None
    b = r.belief
    # the pads where they are (open at the last grasp's opening after a release), not fully open as plans assume
    opening = None if held is not None else r._opening()
    q_now = r.arm.joint_positions()
    plan = r.planner.plan_escape(q_now, b.scene_objects(), map_points=b.map_points, held=held, opening=opening)
    if not plan.ok and "voxels" in str(plan) and len(b.contact_points):
        # the marks of the stop close every way out (those of the held item's volume where a lift stopped lie
        # just over the pads once the arm has backed down and let go): the ones around the arm go, those
        # farther away stay; a move blocked by the marks the arm stands in drops only those (_move_joints)
        n = b.drop_contacts(r._arm_points(q_now), r.MARKS_BLOCKING_RADIUS)
        if n:
            r._log("note", "contact marks dropped: they close the way out", reason=str(plan), dropped=n,
                   left=len(b.contact_points))
            plan = r.planner.plan_escape(q_now, b.scene_objects(), map_points=b.map_points, held=held,
                                         opening=opening)
    if not plan.ok:
        return str(plan)
    r._log("note", "escaping the collision margin", **plan.timings_ms)
    r._run_trajectory(plan.trajectory)
    r.report.escapes += 1
    return ""


def _last_is_free_to_retrace(r) -> str:
    last, tr = r.tracks.last, r.tracks
    if tr.searching:
        return "looking for a fallen item (it may lie on the way back)"
    if last is None:
        return "no motion yet"
    if last.name not in FREE_START or tr.last_from_contact:
        return f"the last motion ({last.name}) starts at a contact or a release: going back would drive into it"
    k = r._index_on(last)
    if k is None or k == 0:
        return f"the arm is not on the last motion ({last.name}) past its start"
    return ""


def _retrace_last(r) -> str:
    """Inside something as perceived (a pose error: the arm was stopped before real contact): back along the
    motion that brought it here, to its start (free in the world as it is)."""
    last = r.tracks.last
    if not r._retrace(last, "retrace"):
        return "not on the last motion"
    r._log("note", "retraced the stopped motion out of the collision margin", motion=last.name)
    r.report.escapes += 1
    return ""


# ---- the held item slipped out during the lift (the arm stopped among the items) -------------------------------
def _on_lift(r) -> str:
    last = r.tracks.last
    if r.planner is None:
        return "no planner to check the way"
    if last is None or last.name != "lift":
        return f"the slip was not in a lift ({last.name if last is not None else 'no motion'})"
    k = r._index_on(last)
    if k is None or k >= len(last) - 1:
        return "the arm is not on the lift before its end"
    return ""


def _leave_along_lift(r) -> str:
    """On up along the rest of the lift (planned out of the items with the tool as it is, the held item gone
    below), checked first in the scene without the item that fell (its pose is unknown now; it lies under the
    tool): the pairs within the margin where the arm stopped may stay closer but not touch, everything else keeps
    its margin, and the lift's end keeps every margin."""
    last, b, planner = r.tracks.last, r.belief, r.planner
    k = r._index_on(last)
    scene = planner.scene(b.scene_objects(), b.map_points, exclude=r.item.obj, opening=r._opening())
    Q = last.q[k:]
    pairs = scene.colliding_pairs(Q[0])
    along = scene.touching_only(pairs) if pairs else scene
    bad = [i for i in range(1, len(Q)) if not along.valid(Q[i])]
    if bad:
        return f"the rest of the lift meets {', '.join(f'{a}/{c}' for a, c in along.colliding_pairs(Q[bad[0]])[:4])}"
    if not scene.valid(Q[-1]):
        return "the lift's end is within the margin of something"
    r._run_trajectory(Trajectory(last.times[k:] - last.times[k], Q.copy(), "leave_lift"))
    r._log("note", "left along the rest of the lift after the slip", samples=len(Q))
    return ""


#: failure kind -> the strategies, in order; the first that applies and works ends the recovery.
STRATEGIES: dict[str, tuple[RecoveryStrategy, ...]] = {
    "start_in_collision": (
        RecoveryStrategy("straight_out", "always", "a straight TCP line of 5 or 10 cm out of the margin "
                         "(`Planner.plan_escape`); where a stop's contact marks close every way out, those around "
                         "the arm are dropped and it is planned once more", 4, _always, _straight_out),
        RecoveryStrategy("retrace_last", "not looking for a fallen item; the arm stands on the last motion past its "
                         "start, and that motion starts clear of any contact (an approach, grasp-in, transfer, "
                         "lower, or a move that did not begin by leaving a release: never a lift, retreat, "
                         "back-off, back-out, retrace or escape)", "back along the last motion to its start",
                         2, _last_is_free_to_retrace, _retrace_last),
    ),
    "slip": (
        RecoveryStrategy("leave_along_lift", "the slip stopped the arm on a lift before its end", "on up along the "
                         "rest of the lift, checked first without the fallen item (the pairs within the margin "
                         "where it stopped may come closer but not touch; the end keeps every margin)",
                         1, _on_lift, _leave_along_lift),
    ),
}


def recover_with(r, kind: str) -> Outcome:
    """Try the strategies for `kind` in order (at most `tries` runs of each per cycle); journaled and counted."""
    out = Outcome(None)
    used = r.tracks.tries
    for s in STRATEGIES[kind]:
        key = f"{kind}/{s.name}"
        if used.get(key, 0) >= s.tries:
            out.why[s.name] = f"its {s.tries} tries this cycle are used"
            continue
        why = s.precondition(r)
        if why:
            out.why[s.name] = why
            continue
        used[key] = used.get(key, 0) + 1
        why = s.run(r)
        r._log("note", "recovery strategy", kind=kind, strategy=s.name, ok=not why, **({"reason": why} if why else {}))
        if not why:
            counts = r.report.recovery_strategies
            counts[key] = counts.get(key, 0) + 1
            out.strategy = s.name
            return out
        out.why[s.name] = why
    r._log("note", "no recovery strategy left", kind=kind, reason=out.reason())
    counts = r.report.recovery_strategies
    counts[f"{kind}/none"] = counts.get(f"{kind}/none", 0) + 1
    return out


def strategies_markdown() -> str:
    """The table as markdown (docs/executive.md)."""
    lines = ["| failure | strategy, in order | when | does | tries per cycle |", "|---|---|---|---|---|"]
    for kind, ss in STRATEGIES.items():
        for s in ss:
            lines.append(f"| `{kind}` | `{s.name}` | {s.when} | {s.does} | {s.tries} |")
    return "\n".join(lines)
