"""Shared, session-scoped perception fixtures (the inventory and the CAD database are slow to build)."""

from __future__ import annotations

import pytest

from kitchenbot.perception.pipeline import Perceiver
from kitchenbot.perception.settings import PerceptionSettings
from kitchenbot.world.cell import Cell
from kitchenbot.world.inventory import Inventory


@pytest.fixture(scope="session")
def inventory() -> Inventory:
    return Inventory.builtin()


@pytest.fixture(scope="session")
def cell() -> Cell:
    return Cell()


@pytest.fixture(scope="session")
def perceiver(inventory, cell, tmp_path_factory) -> Perceiver:
    p = Perceiver(PerceptionSettings(cache_dir=str(tmp_path_factory.mktemp("cad"))), inventory, cell)
    p.database  # build once
    return p
