"""`kitchenbot bench WHAT`: benchmarks that print numbers (and optionally write a JSON report).

Each area keeps its benchmarks in its own `bench.py` exposing `register(subparsers)` (one sub-subcommand per
benchmark, `set_defaults(func=...)`). This file only collects the modules below that exist.
"""

from __future__ import annotations

import argparse
import importlib

BENCH_MODULES = [
    "kitchenbot.fakes.bench",  # render, scenes
    "kitchenbot.fakes.dynamixel_bench",  # dynamixel
    "kitchenbot.fakes.arm_bench",  # fakearm
    "kitchenbot.perception.bench",
    "kitchenbot.perception.bench_backends",  # backends (learned detectors, SAM2, image encoders)
    "kitchenbot.planning.bench",  # planning
    "kitchenbot.executive.bench",  # tasks
    "kitchenbot.calibration.bench",
]


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="run a benchmark and print its numbers")
    bs = p.add_subparsers(dest="bench_command", metavar="WHAT", required=True)
    for name in BENCH_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as e:
            if e.name == name:
                continue
            raise
        module.register(bs)
