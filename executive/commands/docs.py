"""`kitchenbot docs [--check]`: regenerate the sections of docs/executive.md that come from tables in code
(recovery rules, strategies, the state machine; executive/docs.py)."""

from __future__ import annotations

import argparse
import sys


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("docs", help="regenerate the docs sections that come from tables in code (--check: only "
                                    "say whether they are current)")
    p.add_argument("--check", action="store_true", help="exit 1 if a generated section is out of date")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from kitchenbot.executive.docs import DOCS, stale, update

    if args.check:
        old = stale(DOCS)
        if old:
            print(f"{DOCS}: out of date: {', '.join(old)} (run `kitchenbot docs`)", file=sys.stderr)
            return 1
        print(f"{DOCS}: generated sections current")
        return 0
    print(f"{DOCS}: {'updated' if update(DOCS) else 'already current'}")
    return 0
