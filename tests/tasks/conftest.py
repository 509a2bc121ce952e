"""Shared fixtures for the task tests: the builtin inventory and items standing in the sink."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.perception.types import ObjectPose
from kitchenbot.transforms import make_T
from kitchenbot.world.inventory import Inventory


@pytest.fixture(scope="session")
def inv() -> Inventory:
    return Inventory.builtin()


@pytest.fixture(scope="session")
def sink_item(inv):
    """sink_item(name, R=identity) -> ObjectPose of that builtin model in the sink (its middle, 15 cm down)."""

    def make(name: str, R=np.eye(3)) -> ObjectPose:
        m = inv.by_name(name)
        return ObjectPose(m.obj_id, m.cls, make_T(R, (0.5, 0.0, -0.15)), 1.0)

    return make
