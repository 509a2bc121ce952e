"""Perception: views -> instance map -> object poses.

Public face: ``View``, ``ObjectPose`` (types), ``Inventory``/``ObjectModel``/``GraspSpec`` (the known objects),
``Cell`` (the known fixed geometry). The pipeline stages live in their own modules.
"""

from kitchenbot.perception.cell import Cell, CellSpec
from kitchenbot.perception.inventory import GraspSpec, Inventory, InventoryError, ObjectModel
from kitchenbot.perception.types import ObjectPose, View

__all__ = ["Cell", "CellSpec", "GraspSpec", "Inventory", "InventoryError", "ObjectModel", "ObjectPose", "View"]
