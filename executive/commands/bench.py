"""`kitchenbot bench WHAT`: benchmarks that print numbers (and optionally write a JSON report).

The benchmarks live in the bench package (kitchenbot/bench/), one module per area exposing `register(subparsers)`
(one sub-subcommand per benchmark, `set_defaults(func=...)`). This file only collects the modules below.
"""

from __future__ import annotations

import argparse
import importlib

BENCH_MODULES = [
    "kitchenbot.bench.sim",  # render, scenes
    "kitchenbot.bench.dynamixel",  # dynamixel
    "kitchenbot.bench.fakearm",  # fakearm
    "kitchenbot.bench.perception",  # perception
    "kitchenbot.bench.backends",  # backends (learned detectors, SAM2, image encoders)
    "kitchenbot.bench.planning",  # planning
    "kitchenbot.bench.tasks",  # tasks
    "kitchenbot.bench.calibration",  # calibration-accuracy, calibration-sim
]


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="run a benchmark and print its numbers")
    bs = p.add_subparsers(dest="bench_command", metavar="WHAT", required=True)
    for name in BENCH_MODULES:
        importlib.import_module(name).register(bs)
