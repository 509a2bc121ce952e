"""Value types that planning produces: grasps, placement targets, timed trajectories, plans, typed failures.

Failures are returned, not raised: every planning entry point returns either its plan or a
:class:`PlanningFailure` subclass whose ``kind`` the executive can branch on (re-scan, try another object,
recover the arm, give up). ``plan.ok`` is True for plans and False for failures, so ``if not result.ok`` works
for both.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from kitchenbot.perception.types import ObjectPose
from kitchenbot.world.inventory import GraspSpec


# ---- trajectories -------------------------------------------------------------------------------------------
@dataclass
class Trajectory:
    """A timed joint trajectory: ``times`` (N,) seconds from 0, strictly increasing; ``q`` (N, 6) radians.

    Samples are uniform in time (8 ms). Joint-space linear interpolation between consecutive samples stays on
    the collision-checked path (every vertex of a planned polyline is a sample; straight Cartesian segments are
    sampled from their dense IK points); finite-difference velocities/accelerations are within the safety
    limits (verified with drivers.safety.SafetyLimits.check_trajectory before the plan is returned).
    """

    times: np.ndarray
    q: np.ndarray
    name: str = ""

    def __post_init__(self) -> None:
        self.times = np.asarray(self.times, dtype=np.float64)
        self.q = np.asarray(self.q, dtype=np.float64)
        if self.q.ndim != 2 or self.q.shape[1] != 6 or len(self.times) != len(self.q):
            raise ValueError(
                f"Trajectory {self.name!r}: expected times (N,) and q (N, 6), got {self.times.shape} and {self.q.shape}"
            )

    @property
    def duration(self) -> float:
        return float(self.times[-1] - self.times[0]) if len(self.times) else 0.0

    @property
    def start(self) -> np.ndarray:
        return self.q[0]

    @property
    def end(self) -> np.ndarray:
        return self.q[-1]

    def __len__(self) -> int:
        return len(self.times)

    def sample(self, t: float) -> np.ndarray:
        """Joint positions at time t (linear between waypoints, clamped at the ends)."""
        return np.array([np.interp(t, self.times, self.q[:, j]) for j in range(6)])


# ---- grasps and placements ----------------------------------------------------------------------------------
@dataclass
class Grasp:
    """A grasp of one perceived object, resolved for this robot.

    ``T_base_tcp = obj.T_base_obj @ spec.T_obj_tcp``; ``q`` the IK solution at the grasp,
    ``q_pregrasp`` at the pre-grasp pose (backed off along the approach axis by ``approach_distance``).
    ``score``: higher is better (clearance and motion cost); ``clearance``: metres from the gripper to the
    nearest obstacle other than the grasped object at the grasp pose.
    """

    spec: GraspSpec
    obj: ObjectPose
    T_base_tcp: np.ndarray
    q: np.ndarray
    q_pregrasp: np.ndarray
    T_base_pregrasp: np.ndarray
    score: float = 0.0
    clearance: float = 0.0
    # (pad, obj:<neighbour>) pairs the pads may touch during the grasp-in (planning/pad_give.py); () for most
    pad_contacts: tuple = ()

    @property
    def T_obj_tcp(self) -> np.ndarray:
        """The grasp actually used, in the object frame (the spec's, possibly backed off along the approach)."""
        from kitchenbot.transforms import inv

        return inv(np.asarray(self.obj.T_base_obj, float)) @ self.T_base_tcp

    @property
    def T_tcp_obj(self) -> np.ndarray:
        """The held object's pose in the TCP frame once grasped (rigid attachment)."""
        from kitchenbot.transforms import inv

        return inv(self.T_obj_tcp)

    @property
    def approach(self) -> np.ndarray:
        """Unit approach direction in the base frame (TCP z)."""
        return self.T_base_tcp[:3, 2].copy()


class MapPoints(np.ndarray):
    """Map points (N, 3), base frame, whose last ``marks`` rows are marks that no perceived object explains: where
    a stopped motion met something, a keep-out. Every plan keeps clear of them even inside a perceived object's
    box (the object they met was perceived a little off: its model there is no explanation). A plain array
    behaves as one without marks; a slice or copy of this one has none."""

    marks: int = 0

    @classmethod
    def of(cls, points: np.ndarray, marks: int) -> "MapPoints":
        out = np.asarray(points, float).reshape(-1, 3).view(cls)
        out.marks = int(min(max(marks, 0), len(out)))
        return out

    def __array_finalize__(self, obj) -> None:
        self.marks = 0  # derived arrays (slices, copies) do not know which of their rows are marks


def marks_of(points) -> int:
    """How many trailing rows of `points` are marks no object explains (:class:`MapPoints`; 0 for a plain array)."""
    return int(getattr(points, "marks", 0) or 0)


@dataclass
class PlaceTarget:
    """Where the held object should end up: its pose ``T_base_obj`` (object frame as in the inventory).

    ``kind``: "slot" (dishwasher rack), "stack" (on a cup of the same type), "drop" (counter drop zone).
    ``free_yaw``: the planner may turn the object about its own z axis (through the target origin) to find a
    reachable release pose for the grasp used. Objects whose inventory model is rotationally symmetric are
    turned about their symmetry axis regardless (the placement looks the same); the flag matters for the
    others (a mug: its handle direction).
    ``slot``: the rack slot name for kind "slot" (SlotBook bookkeeping), else None.
    """

    T_base_obj: np.ndarray
    kind: str
    slot: str | None = None
    free_yaw: bool = True
    support: str = ""  # what it rests on: a rack name, an object instance, "counter"
    approach_distance: float | None = None  # override the settings' approach distance (None = default)
    # May the object also face the other way (turned by pi about the vertical through its centre)? None: yes
    # for "slot" targets of objects whose symmetry axis is horizontal (plates on edge in a rack), else no.
    flip_ok: bool | None = None
    # Lowest release height (m) above the resting pose: onto another item (a pile, a stack) the held item is let
    # go this high, since its pose in the gripper is only as good as perception was (it drops and nests).
    clearance: float = 0.0


# ---- failures ------------------------------------------------------------------------------------------------
@dataclass
class PlanningFailure:
    """Why a plan could not be made. Subclasses fix ``kind``; ``message`` is for people, ``details`` for logs."""

    message: str = ""
    details: dict = field(default_factory=dict)
    kind: ClassVar[str] = "planning_failure"
    ok: ClassVar[bool] = False

    def __str__(self) -> str:
        return f"{self.kind}: {self.message}"


@dataclass
class InvalidInput(PlanningFailure):
    kind: ClassVar[str] = "invalid_input"


@dataclass
class NoIK(PlanningFailure):
    """No joint configuration reaches the target pose within the joint limits."""

    kind: ClassVar[str] = "no_ik"


@dataclass
class NoGraspableObject(PlanningFailure):
    """Every candidate object was dropped (too occluded, no grasps in its model, unknown model)."""

    kind: ClassVar[str] = "no_graspable_object"


@dataclass
class NoCollisionFreeGrasp(PlanningFailure):
    """Grasps were reachable but each one collides or would take in another object."""

    kind: ClassVar[str] = "no_collision_free_grasp"


@dataclass
class StartInCollision(PlanningFailure):
    kind: ClassVar[str] = "start_in_collision"


@dataclass
class GoalInCollision(PlanningFailure):
    kind: ClassVar[str] = "goal_in_collision"


@dataclass
class PlannerTimeout(PlanningFailure):
    """RRT-Connect found no path within the time budget."""

    kind: ClassVar[str] = "planner_timeout"


@dataclass
class CartesianPathFailed(PlanningFailure):
    """A straight approach/retreat/lift segment has no IK or collides along the line."""

    kind: ClassVar[str] = "cartesian_path_failed"


@dataclass
class NoFreeSlot(PlanningFailure):
    """No free place for this object (rack full, no stack base, drop zone full)."""

    kind: ClassVar[str] = "no_free_slot"


@dataclass
class NoFeasiblePlacement(PlanningFailure):
    """Places exist but none is reachable and collision-free with the grasp used."""

    kind: ClassVar[str] = "no_feasible_placement"


# ---- plans ---------------------------------------------------------------------------------------------------
@dataclass
class PickPlan:
    """Pick one object: ``approach`` (start -> pre-grasp, collision-free joint motion),
    ``grasp_in`` (straight line pre-grasp -> grasp, then close the gripper to ``grasp.spec.width``),
    ``lift`` (straight up by ``lift_height`` with the object attached).
    Execute: open gripper to ``grasp.spec.opening`` -> approach -> grasp_in -> close -> lift.
    """

    grasp: Grasp
    approach: Trajectory
    grasp_in: Trajectory
    lift: Trajectory
    candidates_tried: int = 0
    timings_ms: dict = field(default_factory=dict)
    # metres of lift (TCP travel from the grasp) during which the held object and fingers may keep the contacts
    # they had at the grasp (3 cm, or until those contacts clear: planning.pick_place LIFT_CLEAR_TRAVEL)
    lift_contact_travel: float = 0.03
    ok: ClassVar[bool] = True

    @property
    def trajectories(self) -> list[Trajectory]:
        return [self.approach, self.grasp_in, self.lift]

    @property
    def end(self) -> np.ndarray:
        return self.lift.end


@dataclass
class PlacePlan:
    """Place the held object: ``transfer`` (start -> pre-place, joint motion with the object attached),
    ``lower`` (straight line down onto the target), then open the gripper, ``retreat`` (straight back out).
    """

    target: PlaceTarget
    T_base_obj: np.ndarray  # the object's pose at release (target, possibly turned about z when free_yaw)
    T_base_tcp: np.ndarray
    transfer: Trajectory
    lower: Trajectory
    retreat: Trajectory
    timings_ms: dict = field(default_factory=dict)
    # the gripper opening (m) to let go with, which the retreat was planned for: the grasp's own opening, or less
    # where its pads would meet a neighbour at the target (Planner._retreat); None: the grasp's opening
    release_opening: float | None = None
    ok: ClassVar[bool] = True

    @property
    def trajectories(self) -> list[Trajectory]:
        return [self.transfer, self.lower, self.retreat]

    @property
    def release_drop(self) -> float:
        """How far (m) above the target pose the object is released (it falls that far; see
        PlanningSettings.max_release_drop): 0 when the gripper could go all the way down."""
        return float(self.T_base_obj[2, 3] - np.asarray(self.target.T_base_obj)[2, 3])

    @property
    def end(self) -> np.ndarray:
        return self.retreat.end


@dataclass
class SlidePlan:
    """``approach`` (joint motion to above the press point, gripper closed), ``press`` (straight down),
    ``slide`` (level, sideways by ``distance`` along ``direction``), ``release`` (straight up)."""

    target: ObjectPose
    T_base_obj_after: np.ndarray  # where the item should end (before it settles)
    direction: np.ndarray  # unit, horizontal
    distance: float
    approach: Trajectory
    press: Trajectory
    slide: Trajectory
    release: Trajectory
    timings_ms: dict = field(default_factory=dict)
    T_base_press: np.ndarray | None = None  # the TCP pressing on the item where the slide starts
    ok: ClassVar[bool] = True

    @property
    def trajectories(self) -> list[Trajectory]:
        return [self.approach, self.press, self.slide, self.release]


@dataclass
class MovePlan:
    """A plain collision-free joint motion (e.g. to a scan waypoint or home)."""

    trajectory: Trajectory
    timings_ms: dict = field(default_factory=dict)
    ok: ClassVar[bool] = True

    @property
    def end(self) -> np.ndarray:
        return self.trajectory.end


FAILURE_TYPES: tuple[type[PlanningFailure], ...] = (
    InvalidInput,
    NoIK,
    NoGraspableObject,
    NoCollisionFreeGrasp,
    StartInCollision,
    GoalInCollision,
    PlannerTimeout,
    CartesianPathFailed,
    NoFreeSlot,
    NoFeasiblePlacement,
)
