"""The scans that confirm the sink empty: the first captures the later ones' views at each waypoint, and the next
takes them instead of visiting the same waypoints again (executive/verification.py, ``_confirming_scan``); views
captured before anything touched the scene are never used after it. Oracle perception: the executive is under
test."""

from __future__ import annotations

from collections import Counter

from kitchenbot.executive.runner import RunOptions


def _count_moves(runner) -> Counter:
    """Planned joint moves by what they were for ("scan waypoint"), counted as the run makes them."""
    moves: Counter = Counter()
    move = runner._move_joints

    def counted(q, what, *a, **k):
        if max(abs(runner.arm.joint_positions() - q)) >= 1e-3:  # a move the arm makes (not one to where it stands)
            moves[what.rstrip("0123456789 ")] += 1
        return move(q, what, *a, **k)
    runner._move_joints = counted
    return moves


def _notes(runner, name: str) -> int:
    return sum(1 for e in runner.journal.events(runner.run_id) if e["kind"] == "note" and e["name"] == name)


CONFIRMED = "confirming scan from the views captured with the one before: nothing touched since"


def _run_cups(make_runner, safe_end, cups, prepare=None):
    """A sink-pick run on `cups` cups (two confirmations of the empty sink); every cup placed, no collision."""
    runner, world = make_runner(task="sink-pick", cups=cups, waypoints=3,
                                options=RunOptions(poll_period=0.05, confirm_empty_scans=2))
    if prepare is not None:
        prepare(world)
    moves = _count_moves(runner)
    report = runner.run()
    safe_end(runner, world)
    assert report.status == "succeeded" and report.truth["end"]["delivered"] == cups and report.collisions == 0
    return runner, moves, report


def test_the_second_confirming_scan_visits_no_waypoint(make_runner, safe_end):
    """One cup: the first scan, then (the cup placed, nothing left as perceived) a scan that confirms the sink
    empty and captures the second confirmation's views with its own; the second takes them: 3 scans, the
    waypoints visited twice (6 moves), not three times."""
    runner, moves, report = _run_cups(make_runner, safe_end, 1)
    assert runner.counts.scan_count == 3 and _notes(runner, CONFIRMED) == 1
    assert moves["scan waypoint"] == 6


def test_spare_views_are_not_used_after_a_pick(make_runner, safe_end):
    """Two cups apart; the first perception misses one (a missed detection). After the first cup nothing is left as
    perceived: the scan captures spare views and finds the second cup. It is picked: the views captured before that
    pick are not used; the scan after it visits the waypoints, and its own spare views confirm the sink empty."""
    from tests.executive.test_verify_no_rescan import _cups_apart

    def miss_one(world):
        _cups_apart(world)
        world.faults.missed_detection = 1

    runner, moves, report = _run_cups(make_runner, safe_end, 2, miss_one)
    # first scan; after cup 1 (spares captured, cup 2 found); after cup 2 (spares captured); the confirmation from
    # the spares
    assert runner.counts.scan_count == 4 and _notes(runner, CONFIRMED) == 1
    assert moves["scan waypoint"] == 9

