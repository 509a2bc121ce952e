"""A grasp selection blocked by map points no perceived item explains is reported as blocked by them, not by a
neighbour a few of its grasps also touched (planning.grasps._crowded_by counts the map's voxels, and
Planner.plan_pick names them first where they crowd the grasps at least as often as any item). The scene of a
stopped lift (tests/planning/test_lift_foot_under_rim.py: a bowl lying on the rim of a stack of plates) with the
bowl's own surface marked 15 mm over where it stands, as a stopped straight lift's contact sliver marked it: every
grasp of the bowl met the marks, and the failure said "blocked by the dinner_plate"."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.planning.grasps import VOXELS
from kitchenbot.planning.types import MapPoints
from tests.planning.test_lift_foot_under_rim import Q_SCAN, bowl_on_plates  # noqa: F401 (a fixture)


def test_a_grasp_blocked_only_by_marks_is_reported_as_such(planner, inventory, bowl_on_plates):  # noqa: F811
    world, (bowl, top, mid) = bowl_on_plates
    T = np.array(bowl.T_base_obj, float)
    T[2, 3] += 0.015  # the bowl's surface 15 mm up: where a stopped straight lift was about to take it
    P = inventory[bowl.obj_id].points
    marks = P @ T[:3, :3].T + T[:3, 3]
    pick = planner.plan_pick(Q_SCAN, [bowl, top, mid], target=bowl, map_points=MapPoints.of(marks, len(marks)))
    assert not pick.ok and pick.kind == "no_collision_free_grasp", str(pick)
    crowded = pick.details["crowded_by"]
    assert crowded.get(VOXELS, 0) > max([c for k, c in crowded.items() if k != VOXELS] or [0])
    assert pick.details["blocked_by_voxels"] == crowded[VOXELS]
    assert "blocked by map points no perceived item explains" in pick.message
    assert "blocked by the" not in pick.message, pick.message  # no neighbour named as what blocks it
    if pick.details.get("blocking") is not None:  # a neighbour some grasps met too is named second
        assert "fewer met the" in pick.message


def test_without_the_marks_the_bowl_plans(planner, bowl_on_plates):  # noqa: F811
    world, (bowl, top, mid) = bowl_on_plates
    assert planner.plan_pick(Q_SCAN, [bowl, top, mid], target=bowl).ok
