"""The world model: what every layer knows about the physical world before it looks.

``Cell``/``CellSpec`` (the kitchen's fixed geometry), ``Inventory``/``ObjectModel``/``GraspSpec`` (the dishware
meshes, symmetries and grasps as data), ``gripper`` (the Fin-Ray gripper's geometry, one description),
``attitude`` (upright / inverted / lying / on edge from a pose). Perception, planning, tasks and the simulator
stand on it; it imports none of them.
"""

from kitchenbot.world.cell import Cell, CellSpec
from kitchenbot.world.inventory import GraspSpec, Inventory, InventoryError, ObjectModel

__all__ = ["Cell", "CellSpec", "GraspSpec", "Inventory", "InventoryError", "ObjectModel"]
