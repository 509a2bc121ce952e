"""Planning: robot model + IK, collision world, grasp selection, placement, RRT-Connect, timing.

Public face::

    from kitchenbot.planning import Planner, SlotBook
    planner = Planner.from_config(cfg, inventory)                 # cfg: executive CellConfig
    book = SlotBook(planner.cell)                                 # rack slots, filled as the task goes
    targets = book.targets_for(model)                             # [PlaceTarget]: plates upright, vessels inverted
    pick = planner.plan_pick(q_now, object_poses, target=obj, map_points=pts, place_target=targets)
    if pick.ok:   # open to pick.grasp.spec.opening; run pick.approach, pick.grasp_in; close; run pick.lift
        place = planner.plan_place(pick.end, pick.grasp, targets, objects=others)   # PlacePlan | failure
        # run place.transfer, place.lower; open; run place.retreat; book.fill(place.target.slot, place.T_base_obj, model)
    else:
        pick.kind   # no_ik | no_graspable_object | no_collision_free_grasp | no_feasible_placement | planner_timeout
                    # | start_in_collision | goal_in_collision | cartesian_path_failed | invalid_input ...
    move = planner.plan_move(q_now, q_scan, objects=object_poses)   # MovePlan | failure

Every trajectory is a ``Trajectory(times, q)`` within the safety limits (checked with
``SafetyLimits.check_trajectory`` before it is returned); failures are result objects, never exceptions.
``no_feasible_placement`` from ``plan_pick`` means grasps exist but none can also reach the placement (an upright
cup cannot be turned upside down with a grasp from above): ask for other targets (e.g.
``book.targets_for(model, inverted=False)``) or pick without ``place_target`` and stage the object.
``planning.fcl_check`` re-checks plans independently; ``kitchenbot bench planning`` measures it all.
"""

from kitchenbot.planning.pick_place import Planner
from kitchenbot.planning.placement import SlotBook, nesting_height, stack_target
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
    "SlotBook",
    "StartInCollision",
    "Trajectory",
    "nesting_height",
    "stack_target",
]
