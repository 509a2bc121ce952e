"""Shared fixtures for the task tests: the builtin inventory and items standing in the sink."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.types import NoFreeSlot
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


@pytest.fixture(scope="session")
def place_in_order(inv):
    """place_in_order(task, belief, names, first_id=0) -> the names that found no target: items standing in the sink
    (instance ids from first_id) placed at their first target in the order given (the one in which the sink gives
    them up: a buried plate comes out after the cups on it), the items still to come pending (targets only)."""

    def place(task, belief, names, first_id: int = 0) -> list[str]:
        left = []
        for k, n in enumerate(names):
            m = inv.by_name(n)
            left.append(ObjectPose(m.obj_id, m.cls, make_T(np.eye(3), (0.45 + 0.01 * k, 0.0, -0.15)), 1.0,
                                   instance_id=first_id + k))
        failed = []
        for k, o in enumerate(left):
            belief.pending = task.pending_models(left[k:])
            ts = task.targets(o, belief)
            if isinstance(ts, NoFreeSlot):
                failed.append(inv[o.obj_id].name)
                continue
            belief.record_placed(task, o, ts[0], ts[0].T_base_obj)
        return failed

    return place
