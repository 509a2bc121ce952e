"""No per-scene rules: non-test code and its comments name no benchmark seed (a behaviour one scene revealed is
described as its mechanism, and tested on a hand-made situation). Command-line usage lines (`--seed N`) are
options, not rules."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SEED = re.compile(r"(?<!-)\bseeds?\s+\d", re.I)


def test_no_seed_numbers_in_non_test_code():
    hits = []
    for p in sorted(ROOT.rglob("*.py")):
        rel = p.relative_to(ROOT)
        if rel.parts[0] in ("tests", ".venv", "build") or "site-packages" in rel.parts:
            continue
        for k, line in enumerate(p.read_text(errors="replace").splitlines(), 1):
            if SEED.search(line) and "--seed" not in line:
                hits.append(f"{rel}:{k}: {line.strip()}")
    assert not hits, "seed numbers in non-test code:\n" + "\n".join(hits)
