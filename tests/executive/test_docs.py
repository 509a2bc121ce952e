"""docs/executive.md's generated sections (recovery rules, strategies, state machine) match the code."""

from __future__ import annotations

import pytest

from kitchenbot.executive import docs


def test_generated_docs_sections_are_current():
    assert docs.stale() == [], "run `kitchenbot docs` and commit docs/executive.md"


def test_every_rule_action_exists_and_is_described():
    from kitchenbot.executive.recovery import RecoveryActions
    from kitchenbot.executive.recovery_rules import ACTIONS, RULES

    for r in RULES:
        assert r.then in ("give_up", "retry", "rescan")
        for a in r.actions:
            assert a in ACTIONS and callable(getattr(RecoveryActions, f"_act_{a}", None)), a
    assert RULES[-1].condition == "otherwise"  # something always applies


def test_a_missing_section_is_a_clear_error():
    with pytest.raises(ValueError, match="no generated section 'state-machine'"):
        docs.render("# nothing here\n", "x.md")
