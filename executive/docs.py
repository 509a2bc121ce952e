"""Sections of docs/ generated from the tables in code, so the docs cannot drift from what runs:

- ``recovery-rules``: executive/recovery_rules.py (the rules and their actions);
- ``recovery-strategies``: executive/recovery_strategies.py (per failure kind, the strategies in order);
- ``strategies``: executive/strategies.py (the strategies and the tasks that list them);
- ``state-machine``: executive/machine.py (the mermaid diagram).

A section sits between ``<!-- generated: NAME (kitchenbot docs) -->`` and ``<!-- end generated: NAME -->``.
``kitchenbot docs`` rewrites them; ``kitchenbot docs --check`` (and tests/executive/test_docs.py) fails when one
is out of date.
"""

from __future__ import annotations

import re
from pathlib import Path

DOCS = Path(__file__).resolve().parents[1] / "docs" / "executive.md"


def sections() -> dict[str, str]:
    from kitchenbot.executive.machine import mermaid
    from kitchenbot.executive.recovery_rules import rules_markdown
    from kitchenbot.executive.recovery_strategies import strategies_markdown as recovery_markdown
    from kitchenbot.executive.strategies import strategies_markdown
    from kitchenbot.tasks import TASKS

    return {
        "state-machine": "```mermaid\n" + mermaid() + "\n```",
        "recovery-rules": rules_markdown(),
        "recovery-strategies": recovery_markdown(),
        "strategies": strategies_markdown(TASKS),
    }


def _pattern(name: str) -> re.Pattern:
    return re.compile(rf"(<!-- generated: {re.escape(name)} \(kitchenbot docs\) -->\n)(.*?)(<!-- end generated: "
                      rf"{re.escape(name)} -->)", re.S)


def render(text: str, where: str = "docs") -> str:
    """`text` with every generated section rewritten; ValueError naming a section whose markers are missing."""
    for name, body in sections().items():
        pat = _pattern(name)
        if not pat.search(text):
            raise ValueError(f"{where}: no generated section {name!r} (expected '<!-- generated: {name} "
                             f"(kitchenbot docs) -->' ... '<!-- end generated: {name} -->')")
        text = pat.sub(lambda m: m.group(1) + body + "\n" + m.group(3), text)
    return text


def stale(path: Path = DOCS) -> list[str]:
    """Names of the generated sections in `path` that differ from what the code says."""
    text = path.read_text()
    return [name for name, body in sections().items()
            if (m := _pattern(name).search(text)) is None or m.group(2) != body + "\n"]


def update(path: Path = DOCS) -> bool:
    """Rewrite the generated sections of `path`; True if anything changed."""
    text = path.read_text()
    new = render(text, str(path))
    if new != text:
        path.write_text(new)
    return new != text
