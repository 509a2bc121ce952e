"""A bowl resting steeply tilted in another (its axis 33 deg off the lower one's, as a bowl dropped into a bowl
settles): the lower bowl shows its rim and outer wall, within 1.5 voxels (15 mm) of the upper bowl's surface.

Traced in a simulated sink-pick run (issue 18, twenty-sixth session): the lower bowl was fitted and verified on
the re-scan after an item over the pair was taken, then dropped as the upper bowl's duplicate, because the
duplicate test judged a pair of nesting items by the strict rule (points on the other's surface within 3 mm,
facing the same way) only when their axes were within 30 deg of each other. Unperceived, the lower bowl was map
points only; the upper bowl's every lift ran into their voxels, and both were left in the sink."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.perception.metrics import adi
from kitchenbot.perception.synthetic import render, resting_pose, scan_poses
from kitchenbot.transforms import rot_x, trans

BOWL = 3


@pytest.fixture(scope="module")
def leaning(inventory, cell):
    """The lower bowl upright on the floor; the upper one 3.1 cm higher, 2.3 cm across, tilted 33 deg."""
    assert inventory[BOWL].cls == "bowl"
    lower = resting_pose(inventory, BOWL, 0.50, 0.0, 0.4, cell)
    upper = lower @ trans(0.0, 0.023, 0.031) @ rot_x(np.radians(33.0))
    return [(BOWL, lower), (BOWL, upper)]


def _found(inventory, poses, placed) -> float:
    """ADI / diameter of the bowl poses matched one-to-one to the two bowls placed, the worse of the two (9 when
    there are not two bowl poses: ADI alone forgives the upper bowl's pose as the lower one's, 0.085)."""
    bowls = [po for po in poses if po.obj_id == BOWL]
    if len(bowls) != 2:
        return 9.0
    d = inventory[BOWL].diameter
    E = np.array([[adi(po.T_base_obj, T, inventory[BOWL].points) / d for po in bowls] for _, T in placed])
    return float(min(max(E[0, 0], E[1, 1]), max(E[0, 1], E[1, 0])))


def test_a_bowl_leaning_steeply_in_a_bowl_leaves_the_lower_one_its_pose(perceiver, inventory, cell, leaning):
    """Whichever of the two scores higher: the duplicate test goes through the poses best first, and in the traced
    run the re-scan's tracked upper bowl scored above the lower one (here the executive's re-scan: the belief's poses
    and map as priors, the surroundings unchanged, so each keeps its pose and score; before, the lower bowl was
    dropped when the upper one led, and kept when it led itself)."""
    from dataclasses import replace

    views, _ = render(inventory, leaning, scan_poses(cell), cell, noise=0.002)
    first = perceiver.perceive(views)
    assert _found(inventory, first.poses, leaning) < 0.1
    d = inventory[BOWL].diameter
    upper = min(first.poses, key=lambda p: adi(p.T_base_obj, leaning[1][1], inventory[BOWL].points) / d)
    for upper_score, lower_score in ((0.99, 0.9), (0.9, 0.99)):
        priors = [replace(p, score=upper_score if p is upper else lower_score) for p in first.poses]
        again = perceiver.perceive(views, priors=priors, prior_map=first.map_points)
        # before (upper first): one pose, the upper bowl's
        assert _found(inventory, again.poses, leaning) < 0.1 and len(again.poses) == 2, upper_score
