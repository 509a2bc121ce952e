"""What "the same item" means, once for every layer: perception's merge of a region's view with what was known
(perception/region.py) and the executive's belief (executive/belief.py) count items alike."""

from __future__ import annotations

import numpy as np

#: m: two poses of one class this close are taken for the same item (a perceived pose against an item the robot
#: put there; attempts kept per class and place; a found item against one placed earlier; a pose of a region's
#: view against one known). Perception puts an item within ~2 cm of where it is; different items of one class are
#: at least a rim apart.
SAME_ITEM_RADIUS = 0.04


def same_item(cls_a: str, p_a: np.ndarray, cls_b: str, p_b: np.ndarray, radius: float = SAME_ITEM_RADIUS,
              dims: int = 3) -> bool:
    """Whether items of class `cls_a` at `p_a` and `cls_b` at `p_b` (base frame, m) are one item: the same class
    and within `radius` (in the first `dims` coordinates: 2 compares xy only)."""
    if cls_a != cls_b:
        return False
    d = np.asarray(p_a, float)[:dims] - np.asarray(p_b, float)[:dims]
    return bool(np.linalg.norm(d) < radius)
