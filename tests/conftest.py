"""Shared pytest fixtures and the hardware-in-the-loop switch.

Tests marked ``@pytest.mark.hil`` talk to real devices named in the config given by
``KITCHENBOT_HIL_CONFIG``; they run only when ``KITCHENBOT_HIL=1`` (never in CI).
"""

from __future__ import annotations

import os

import numpy as np
import pytest

# Every planner in the suite (in this process, in `kitchenbot` subprocesses, in the daemon's worker) stops
# RRT-Connect after a fixed number of iterations from a fixed seed instead of after a wall-clock budget: a plan
# is then the same on an idle machine and on a loaded one. Set before kitchenbot is imported (the config's
# defaults read them). ~200 iterations are about the default 1 s budget on an idle machine.
os.environ.setdefault("KITCHENBOT_PLANNER_MAX_ITERATIONS", "200")
os.environ.setdefault("KITCHENBOT_PLANNER_SEED", "0")


def pytest_collection_modifyitems(config, items):
    if os.environ.get("KITCHENBOT_HIL") == "1":
        return
    skip = pytest.mark.skip(reason="hardware-in-the-loop test: set KITCHENBOT_HIL=1 and KITCHENBOT_HIL_CONFIG")
    for item in items:
        if "hil" in item.keywords:
            item.add_marker(skip)


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(1234)
