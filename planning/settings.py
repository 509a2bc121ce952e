"""Planning settings (the `planning:` section of the cell config).

Two defaults come from the environment, so that a whole process tree (the test suite, `kitchenbot` subprocesses,
the daemon's worker) can run its planners on a work budget without editing every config:
``KITCHENBOT_PLANNER_MAX_ITERATIONS`` and ``KITCHENBOT_PLANNER_SEED`` (unset: wall-clock budgets, process-wide
seed). A value in the config file wins over them.
"""

from __future__ import annotations

import os

from pydantic import BaseModel, ConfigDict, Field


def _env_int(name: str) -> int | None:
    value = os.environ.get(name, "").strip()
    if not value:
        return None
    try:
        return int(value)
    except ValueError:
        raise ValueError(f"environment variable {name}={value!r}: expected an integer") from None


class PlanningSettings(BaseModel):
    model_config = ConfigDict(extra="forbid")

    planner_timeout: float = Field(1.0, gt=0.0, le=60.0, description="seconds per RRT-Connect query")
    simplify_timeout: float = Field(0.2, ge=0.0, le=10.0)
    planner_max_iterations: int | None = Field(
        default_factory=lambda: _env_int("KITCHENBOT_PLANNER_MAX_ITERATIONS"), ge=1, le=10_000_000,
        validate_default=True,
        description="when set, RRT-Connect stops after this many iterations instead of after planner_timeout, and "
                    "simplification runs all its steps (simplify_timeout > 0) instead of stopping on time: plans do "
                    "not depend on the machine's load (tests, reproducible benchmarks)",
    )
    planner_seed: int | None = Field(
        default_factory=lambda: _env_int("KITCHENBOT_PLANNER_SEED"), ge=0, le=2**31 - 1, validate_default=True,
        description="when set, OMPL is reseeded before every query, so a plan does not depend on the queries "
                    "planned before it in the process",
    )
    shortcut_rounds: int = Field(
        30, ge=0, le=1000,
        description="random shortcuts tried on an RRT-Connect path for the arm's time along it (planning/shortcut.py; "
                    "each new segment densely checked, the faster of the path and its shortcut kept); 0: none",
    )
    validity_resolution: float = Field(0.004, gt=0.0, le=0.05, description="max TCP travel (m) between checked states")
    approach_distance: float = Field(0.10, gt=0.0, le=0.3, description="straight approach/retreat, metres")
    lift_height: float = Field(0.15, gt=0.0, le=0.5)
    max_occlusion: float = Field(0.6, ge=0.0, le=1.0, description="skip objects hidden more than this fraction")
    visible_fraction_unoccluded: float = Field(
        0.5, gt=0.0, le=1.0,
        description="ObjectPose.visible_fraction of a fully visible object: perception counts the share of all "
                    "model points its views confirmed, and from above at most about half a surface faces a camera",
    )
    max_approach_up: float = Field(
        0.1, ge=-1.0, le=1.0, description="largest upward z component of a grasp's approach direction (-1 = straight down)"
    )
    collision_margin: float = Field(0.01, ge=0.0, le=0.05, description="clearance (m) kept by every motion")
    grasp_margin: float = Field(0.002, ge=0.0, le=0.02, description="gripper clearance (m) in the final approach")
    # Off by default: on a fresh block (sink-to-dishwasher, one scene) the grasps it admitted ended in 3 collisions
    # and a protective stop where the same code with 0 placed everything without one. The pads' give is real, but
    # the perceived neighbour is often off by more than the 1 mm the finger keeps clear (docs/planning.md).
    pad_give: float = Field(
        0.0, ge=0.0, le=0.004,
        description="m a neighbour may reach into a pad envelope's outer face during a grasp (planning/pad_give.py; "
                    "at most PAD_GIVE = 3 mm, the envelope is 4 mm thicker than the finger); 0: pads keep clear",
    )
    planning_resolution: float = Field(
        0.015, gt=0.0, le=0.05, description="RRT-Connect motion check step (m of point travel); < 2 * collision_margin"
    )
    max_place_targets: int = Field(12, ge=1, le=200, description="place targets considered per query, in the given order")
    max_grasp_candidates: int = Field(8, ge=1, le=100, description="ranked grasps tried by plan_pick")
    map_voxel_size: float = Field(0.02, gt=0.002, le=0.1, description="voxels (m) for map points no object explains")
    max_release_drop: float = Field(
        0.10, ge=0.0, le=0.2, description="highest release (m) above the resting pose when the gripper cannot go lower"
    )
    grasp_cache_dir: str | None = Field(
        "~/.cache/kitchenbot/grasps",
        description="where grasps synthesised from meshes are cached (keyed by a hash of the mesh); null: no cache",
    )
    # Fractions of the safety limits (drivers/safety.py: joint speed and acceleration; the TCP speed limit holds for
    # every profile, planning/timing.py) that free motions are timed for: the whole of them.
    velocity_scale: float = Field(1.0, gt=0.0, le=1.0, description="fraction of the joint speed limits")
    acceleration_scale: float = Field(1.0, gt=0.0, le=1.0, description="fraction of the joint acceleration limits")
    contact_speed_scale: float = Field(
        0.5, gt=0.0, le=1.0,
        description="further factor on both for motions that end in or make contact (grasp_in, the guarded lower, "
                    "press, slide, escape): an item set down or closed on at half speed, as before",
    )
