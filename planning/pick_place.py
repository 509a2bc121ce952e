"""The planning entry points the executive calls: pick an object, place the held object, move.

``Planner`` owns the robot model (IK), the collision world and the settings. Each call builds the scene's
collision objects from what perception returned (object poses + unexplained map points) and returns a plan or
a typed :class:`~kitchenbot.planning.types.PlanningFailure` (never raises for planning outcomes; bad inputs
give ``InvalidInput``).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.types import (
    Grasp,
    MovePlan,
    PickPlan,
    PlaceTarget,
    PlacePlan,
    PlanningFailure,
)


class Planner:
    """Plans pick, place and free motions for one cell (robot + tool + fixed geometry + inventory)."""

    def __init__(self, robot, cell, inventory, settings, limits):  # filled in below (issue 5)
        raise NotImplementedError("planning.pick_place.Planner is being written (issue 5); API is stable")

    @classmethod
    def from_config(cls, cfg, inventory=None) -> "Planner":
        """Build from an executive CellConfig (duck-typed: robot.model, robot.tool, safety_limits(), planning,
        cell); `inventory` defaults to the builtin one."""
        raise NotImplementedError

    def select_grasps(
        self,
        q_current: np.ndarray,
        objects: Sequence[ObjectPose],
        *,
        target: ObjectPose | None = None,
        map_points: np.ndarray | None = None,
        place_target: PlaceTarget | None = None,
    ) -> list[Grasp] | PlanningFailure:
        """Ranked feasible grasps (best first) over `objects` (or only `target`)."""
        raise NotImplementedError

    def plan_pick(
        self,
        q_start: np.ndarray,
        objects: Sequence[ObjectPose],
        *,
        target: ObjectPose | None = None,
        map_points: np.ndarray | None = None,
        place_target: PlaceTarget | None = None,
    ) -> PickPlan | PlanningFailure:
        """Pick the best graspable object in `objects` (or `target`): approach, straight grasp-in, lift.

        `objects`: every perceived object (all are obstacles, candidates unless `target` is given);
        `map_points`: (N, 3) fused map points in the base frame; those no object or cell surface explains become
        voxel obstacles; `place_target`: when given, only grasps that can also reach that placement are kept
        (e.g. cups to be inverted into the upper rack need side grasps).
        """
        raise NotImplementedError

    def plan_place(
        self,
        q_start: np.ndarray,
        grasp: Grasp,
        target: PlaceTarget,
        *,
        objects: Sequence[ObjectPose] = (),
        map_points: np.ndarray | None = None,
    ) -> PlacePlan | PlanningFailure:
        """Carry the object held with `grasp` to `target`: transfer, straight lower, (open), straight retreat.
        `objects` are the other perceived objects (the held one is excluded by instance id)."""
        raise NotImplementedError

    def plan_move(
        self,
        q_start: np.ndarray,
        q_goal: np.ndarray,
        *,
        objects: Sequence[ObjectPose] = (),
        held: Grasp | None = None,
        map_points: np.ndarray | None = None,
    ) -> MovePlan | PlanningFailure:
        """Collision-free joint motion (e.g. to a scan waypoint or home), with `held` attached if given."""
        raise NotImplementedError
