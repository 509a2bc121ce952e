"""How an item rests, from its pose: upright, inverted, lying on its side (a plate: on edge), or tilted.

Everything reads the cosine between the item's z axis (BOP frame: rim up) and the base frame's z (up), i.e.
``T_base_obj[2, 2]``. Three thresholds, named once:

- ``LEVEL_COS`` 0.95 (within 18 degrees of vertical): the item stands level, upright (rim up) or inverted;
- ``FACING_COS`` 0.5 (within 60 degrees): its mouth faces up or down rather than sideways;
- ``LYING_COS`` 0.3 (axis within 17 degrees of horizontal): it lies on its side; a flat item (a plate) then
  stands on edge.
"""

from __future__ import annotations

from enum import Enum

import numpy as np

LEVEL_COS = 0.95
FACING_COS = 0.5
LYING_COS = 0.3


class Attitude(str, Enum):
    UPRIGHT = "upright"
    INVERTED = "inverted"
    LYING = "lying"
    ON_EDGE = "on_edge"
    TILTED = "tilted"


def up_cos(T_base_obj: np.ndarray) -> float:
    """Cosine between the item's axis (its z, rim up) and the vertical: 1 upright, -1 inverted, 0 lying."""
    return float(T_base_obj[2, 2])


def is_upright(T_base_obj: np.ndarray, cos: float = LEVEL_COS) -> bool:
    return up_cos(T_base_obj) >= cos


def is_inverted(T_base_obj: np.ndarray, cos: float = LEVEL_COS) -> bool:
    return up_cos(T_base_obj) <= -cos


def is_level(T_base_obj: np.ndarray, cos: float = LEVEL_COS) -> bool:
    """Upright or inverted: the axis within acos(`cos`) of vertical."""
    return abs(up_cos(T_base_obj)) >= cos


def faces_up(T_base_obj: np.ndarray) -> bool:
    """The rim (mouth) faces up rather than sideways or down."""
    return up_cos(T_base_obj) > FACING_COS


def faces_down(T_base_obj: np.ndarray) -> bool:
    """The rim (mouth) faces down rather than sideways or up."""
    return up_cos(T_base_obj) < -FACING_COS


def is_lying(T_base_obj: np.ndarray) -> bool:
    """The axis is near horizontal: a vessel on its side, a plate on edge."""
    return abs(up_cos(T_base_obj)) < LYING_COS


def attitude(T_base_obj: np.ndarray, flat: bool = False) -> Attitude:
    """The named attitude; `flat` items (plates: much wider than tall) lying on their side are ON_EDGE."""
    if is_upright(T_base_obj):
        return Attitude.UPRIGHT
    if is_inverted(T_base_obj):
        return Attitude.INVERTED
    if is_lying(T_base_obj):
        return Attitude.ON_EDGE if flat else Attitude.LYING
    return Attitude.TILTED
