"""Planning: robot model + IK, collision world, grasp selection, placement, RRT-Connect, timing.

Public face::

    from kitchenbot.planning import Planner, SlotBook
    planner = Planner.from_config(cfg, inventory)            # cfg: executive CellConfig
    pick = planner.plan_pick(q_now, object_poses, map_points=pts)      # PickPlan | PlanningFailure
    if pick.ok:  # execute: open to pick.grasp.spec.opening, pick.approach, pick.grasp_in, close, pick.lift
        target = slots.target_for(pick.grasp)                           # PlaceTarget | NoFreeSlot
        place = planner.plan_place(pick.end, pick.grasp, target, objects=others)  # PlacePlan | failure
    else:
        print(pick.kind, pick.message)   # no_ik, no_collision_free_grasp, planner_timeout, ...

Every trajectory is a ``Trajectory(times, q)`` within the safety limits; failures are result objects.
"""

from kitchenbot.planning.pick_place import Planner
from kitchenbot.planning.types import (
    FAILURE_TYPES,
    CartesianPathFailed,
    GoalInCollision,
    Grasp,
    InvalidInput,
    MovePlan,
    NoCollisionFreeGrasp,
    NoFeasiblePlacement,
    NoFreeSlot,
    NoGraspableObject,
    NoIK,
    PickPlan,
    PlaceTarget,
    PlacePlan,
    PlannerTimeout,
    PlanningFailure,
    StartInCollision,
    Trajectory,
)

__all__ = [
    "FAILURE_TYPES",
    "CartesianPathFailed",
    "GoalInCollision",
    "Grasp",
    "InvalidInput",
    "MovePlan",
    "NoCollisionFreeGrasp",
    "NoFeasiblePlacement",
    "NoFreeSlot",
    "NoGraspableObject",
    "NoIK",
    "PickPlan",
    "PlaceTarget",
    "PlacePlan",
    "Planner",
    "PlannerTimeout",
    "PlanningFailure",
    "StartInCollision",
    "Trajectory",
]
