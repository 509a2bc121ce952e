"""The state machine table: complete, consistent, drawable, and strict about invalid triggers."""

from __future__ import annotations

import pytest
from transitions import MachineError

from kitchenbot.executive import machine as M


def test_table_names_only_known_states_and_every_state_is_reachable():
    names = {s.name for s in M.STATES}
    reach = {"idle"}
    changed = True
    while changed:
        changed = False
        for _t, src, dst in M.TRANSITIONS:
            srcs = [src] if isinstance(src, str) else src
            assert set(srcs) <= names and dst in names
            if any(s in reach for s in srcs) and dst not in reach:
                reach.add(dst)
                changed = True
    assert reach == names


def test_terminal_states_have_no_way_out_and_every_working_state_can_fault_stop_and_give_up():
    for _t, src, _dst in M.TRANSITIONS:
        srcs = [src] if isinstance(src, str) else src
        assert not set(srcs) & set(M.TERMINAL)
    for trig in ("fault", "stop", "give_up", "pause"):
        srcs = {s for t, src, _ in M.TRANSITIONS if t == trig for s in ([src] if isinstance(src, str) else src)}
        assert set(M.WORKING) - {"recover"} <= srcs
    assert {"scan", "perceive", "select_grasp", "plan", "execute", "verify"} <= {
        s for t, src, _ in M.TRANSITIONS if t == "fault" for s in src}


def test_cycle_walks_in_order_and_invalid_triggers_raise():
    m = M.MachineModel()
    M.build_machine(m)
    for trig, state in [("start", "scan"), ("scanned", "perceive"), ("perceived", "select_grasp"),
                        ("selected", "plan"), ("planned", "execute"), ("executed", "verify"), ("complete", "done")]:
        getattr(m, trig)()
        assert m.state == state
    with pytest.raises(MachineError):
        m.start()  # done is terminal


def test_mermaid_is_generated_from_the_table():
    text = M.mermaid()
    assert text.startswith("stateDiagram-v2")
    edges = sum(1 if isinstance(s, str) else len(s) for _, s, _ in M.TRANSITIONS)
    assert text.count(" --> ") == edges + 1 + len(M.TERMINAL)
    assert "execute --> verify: executed" in text and "recover --> scan: rescan" in text


def test_timeouts_are_positive_for_working_states():
    for s in M.WORKING:
        assert M.timeout_of(s) and M.timeout_of(s) > 0
    with pytest.raises(KeyError):
        M.timeout_of("nope")


def test_docs_show_the_current_diagram():
    from pathlib import Path

    doc = (Path(__file__).resolve().parents[2] / "docs" / "executive.md").read_text()
    assert M.mermaid() in doc, "docs/executive.md is stale: paste `kitchenbot run --diagram` into it"
