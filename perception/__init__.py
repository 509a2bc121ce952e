"""Perception: views -> instance map -> object poses.

Public face: ``View``, ``ObjectPose`` (types). What it knows beforehand (the inventory, the cell) is the world
model's (kitchenbot.world). The pipeline stages live in their own modules.
"""

from kitchenbot.perception.types import ObjectPose, View

__all__ = ["ObjectPose", "View"]
