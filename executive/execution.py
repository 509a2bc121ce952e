"""The plan and execute states of the task runner: the task's strategies plan the current item
(executive/strategies.py), and the plan is run with the gripper checked (grasped? still held?), the set-down as a
guarded move, and the placement handed to the next perception to verify.

A mixin of TaskRunner (executive/runner.py); the item being handled is ``self.item`` (:class:`Item`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from kitchenbot.drivers.errors import ProtectiveStopError
from kitchenbot.executive.belief import Released
from kitchenbot.executive.failures import StepFailed
from kitchenbot.executive import machine as M
from kitchenbot.executive.strategies import ItemPlan, PlanRequest, harder_settings, plan_item
from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.types import Trajectory


@dataclass
class Item:
    """The item being handled now: what it is, where it may go, and the plan for it."""

    obj: ObjectPose | None = None
    targets: list = field(default_factory=list)
    staged: object = None  # the Placed record it is picked up from when it was staged on the counter
    plan: ItemPlan | None = None

    @property
    def pick(self):
        return self.plan.pick if self.plan is not None else None

    @property
    def place(self):
        return self.plan.place if self.plan is not None else None

    @property
    def slide(self):
        return self.plan.slide if self.plan is not None else None

    @property
    def staging(self) -> bool:
        return self.plan is not None and self.plan.staging


class Execution:
    # A lowering stopped by contact this close above its release pose has set the item down on its support (the
    # held item sat lower in the fingers than its perceived pose said): it is let go there, as from a guarded move.
    RELEASE_IF_STOPPED_WITHIN = 0.03  # m of TCP descent left
    # A grasp closes on the item at the width its pads meet it (GraspSpec.width: a rim's thickness, a body's span);
    # the pads stopping more than this away from it hold something else (a neighbour, two rims of a stack) or the
    # item some other way than planned (its pose was off): every later plan's held item would be wrong.
    GRIP_WIDTH_TOLERANCE = 0.003  # m

    def _do_plan(self) -> str:
        """The task's strategies, in order, until one plans (executive/strategies.py)."""
        it, b = self.item, self.belief
        req = PlanRequest(it.obj, it.targets, it.staged, self.task, b, self.planner, self.arm.joint_positions,
                          self._escape, self._note, self._check_deadline, scene_objs=b.scene_objects())
        plan = plan_item(req, self.strategies, self.report.strategies)
        it.plan = plan
        if plan.slide is not None:
            if self.recorder is not None:
                self.recorder.plan(plan.slide.trajectories, self._sim_now())
            return "planned"
        pick, place = plan.pick, plan.place
        self._log("result", "planned", grasp=pick.grasp.spec.name, target=place.T_base_obj[:3, 3],
                  duration=sum(t.duration for t in pick.trajectories + place.trajectories), strategy=plan.strategy)
        if self.recorder is not None:
            self.recorder.plan(pick.trajectories + place.trajectories, self._sim_now())
        return "planned"

    def _try_harder(self, left: list[ObjectPose]) -> bool:
        """Nothing is left to try but `left` is still in the sink: when some of it only waits because every plan
        failed in this scene (attempts left, not given up), one more round on it with the planner working harder
        (strategies.harder_settings), once per run. True when that round starts (the scene counts as changed, so
        those items are candidates again); counted in the report's recovery_actions as `try_harder`."""
        b = self.belief
        if self.planner is None or self.settings_before_harder is not None:
            return False
        waiting = [q for q in left if (t := b.attempts_for(q)) is not None and t.plan_failures > 0
                   and t.count < M.MAX_ATTEMPTS_PER_OBJECT]
        if not waiting:
            return False
        self.settings_before_harder = self.planner.settings  # restored when the run ends (TaskRunner._finish)
        self.planner.settings = harder_settings(self.planner.settings)
        b.scene_changed()
        acts = self.report.recovery_actions
        acts["try_harder"] = acts.get("try_harder", 0) + 1
        self._log("note", "one more round with the planner working harder", items=[q.cls for q in waiting],
                  max_grasp_candidates=self.planner.settings.max_grasp_candidates,
                  max_occlusion=self.planner.settings.max_occlusion)
        return True

    def _note(self, kind: str, name: str, /, **payload) -> None:
        self._log(kind, name, **payload)

    def _do_execute(self) -> str:
        if self.item.slide is not None:
            return self._execute_slide()
        it = self.item
        pick, place, obj = it.pick, it.place, it.obj
        self.report.attempts += 1
        self.belief.record_attempt(obj)
        self.tracks.new_cycle()
        self._cmd("gripper.open", opening=pick.grasp.spec.opening)
        self.gripper.open(pick.grasp.spec.opening)
        self._run_trajectory(pick.approach)
        self._run_trajectory(pick.grasp_in)
        self._cmd("gripper.grasp", current_limit=self.opt.grasp_current)
        res = self.gripper.grasp(min(self.opt.grasp_current, self.gripper.max_current))
        self._log("result", "gripper.grasp", holding=res.holding, opening=res.opening, current=res.current)
        if not res.holding:  # verify with the gripper: is it holding?
            raise StepFailed("grasp_missed", f"the gripper closed on nothing grasping the {obj.cls}",
                             opening=res.opening)
        width = pick.grasp.spec.width
        if abs(res.opening - width) > self.GRIP_WIDTH_TOLERANCE:  # holding, but not the item as planned
            self._let_go_in_place(pick.grasp.spec.opening, res.opening)
            raise StepFailed("grasp_missed", f"the gripper closed at {1000 * res.opening:.1f} mm grasping the "
                             f"{obj.cls}, not at the grasp's {1000 * width:.1f} mm: not holding it as planned",
                             opening=res.opening, expected=width)
        self._run_trajectory(pick.lift, carrying=True)
        self._run_trajectory(place.transfer, carrying=True)
        try:
            self._run_trajectory(place.lower, carrying=True, guarded=True)
            stopped_short = self.arm.stopped_on_contact  # it met its support above the release pose
            if stopped_short and self._descent_left(place.lower) > self.RELEASE_IF_STOPPED_WITHIN:
                # met something well above its support (a neighbour, a rack wire): not a set-down; recovered
                # like a protective stop (the contact marked, back up, put down away from this target)
                self.tracks.stopped = place.lower
                raise StepFailed("contact", f"the {obj.cls} met something "
                                 f"{self._descent_left(place.lower):.3f} m above its release pose")
        except ProtectiveStopError as e:
            if not self._stopped_just_above(place.lower, e):
                raise
            stopped_short = True
        except StepFailed as e:
            if e.kind != "slip":
                raise
            return self._slipped_onto_target(place)
        if stopped_short:
            self._log("note", "set down on contact before the release pose", cls=obj.cls,
                      tcp=self.arm.tcp_pose()[:3, 3])
        opening = place.release_opening if place.release_opening is not None else pick.grasp.spec.opening
        self._cmd("gripper.open", opening=opening, release=True)
        self.gripper.open(opening)
        if stopped_short:  # back up the way it came down (the planned retreat starts at the release pose)
            self._retrace(place.lower, "retreat")
        else:
            self._run_trajectory(place.retreat)
        # Where it should rest: the release pose (turned as the planner chose) at the target's height (the
        # planner may release higher up when the gripper cannot reach lower; the object then drops).
        T_expected = np.array(place.T_base_obj, float)
        T_expected[2, 3] = min(T_expected[2, 3], float(place.target.T_base_obj[2, 3]))
        self._expect_placed(place.target, T_expected, it.staging)
        return "executed"

    def _slipped_onto_target(self, place) -> str:
        """The item left the gripper while being lowered onto its target: it fell the rest of the way down (at most
        the approach distance and the release height) onto its target. It is verified there as a placement is (gone
        from the sink, present at the target in the view from above it); not seen there, it is looked for around
        the target (Belief.record_unseen). Before, it was looked for as a drop: in a rack or on a pile in the drop
        zone it lies among placed items, where the drop-site look takes nothing for it (an item there is "one
        placed earlier") or takes another; the run ended "dropped ... neither in the sink nor placed" with it
        delivered, or the slot it stood in stayed free in the belief and the next item was sent into it."""
        it = self.item
        self.belief.dropped_at_target()
        self._log("note", "slipped out while lowered onto its target: verified there as placed", cls=it.obj.cls,
                  tcp=self.arm.tcp_pose()[:3, 3])
        self._retrace(place.lower, "retreat")  # back up the way it came down: free, the item fell below
        T_expected = np.array(place.T_base_obj, float)
        T_expected[2, 3] = min(T_expected[2, 3], float(place.target.T_base_obj[2, 3]))
        self._expect_placed(place.target, T_expected, it.staging)
        return "executed"

    def _let_go_in_place(self, planned: float, gripped: float) -> None:
        """Open where the grasp closed (nothing lifted yet): to the grasp's planned opening, or just wider than the
        pads stand where they stopped wider than that (a gripper lets go only when it opens)."""
        opening = min(max(planned, gripped + 0.002), self.gripper.max_opening)
        self._cmd("gripper.open", opening=opening, why="not holding the item as planned: let go")
        self.gripper.open(opening)

    def _execute_slide(self) -> str:
        """Close the fingers, press on the item, slide it, go back up; the re-scan (verify) sees where it went."""
        sl, obj = self.item.slide, self.item.obj
        t = self.belief.record_slide(obj)
        self.report.slides += 1
        self._cmd("gripper.open", opening=0.0, why="closed fingers press on the item")
        self.gripper.open(0.0)
        for traj in sl.trajectories:
            try:
                self._run_trajectory(traj)
            except ProtectiveStopError:
                if traj is sl.press or traj is sl.slide:  # the same belief would plan it again: not that slide
                    self.belief.record_slide_stopped(t, sl.T_base_press, sl.direction)
                raise
        self.item.plan = None
        self.belief.record_slid(t, sl.T_base_obj_after)  # the scene changed: what could not be planned may be now
        self._log("result", "slid", cls=obj.cls, to=sl.T_base_obj_after[:3, 3])
        return "executed"

    def _expect_placed(self, target, T_rest: np.ndarray, staging: bool, carried: bool = True) -> None:
        """The current object was set down at `target`, resting at T_rest: the next perception verifies it (gone
        from the sink, present there) and records it (staged for a regrasp when `staging`). `carried`: the gripper
        was polled holding it all the way from the lift to the target (a pick and place, or a slip in the lowering
        onto its target), so it is not where it was picked any more."""
        obj, b = self.item.obj, self.belief
        b.release(Released(obj, target, T_rest, None, staging, self.item.staged,
                           near_before=max(1, len(self._same_class_near(obj))), carried=carried))
        if self.planner is not None and b.map_base is not None:
            # the map still holds the points where it stood: nothing explains them now that it is gone
            b.set_map_base(self.planner.without_points_of(b.map_base, obj))
        if self.opt.verify_target_view:
            # a put-down after a fault too: what was let go there (perhaps not the item believed, which the sink
            # then still shows) must not be forgotten when only the sink is looked at, or the spot looks free
            b.released.target_view = self._target_view(T_rest[:3, 3])

    def _descent_left(self, lower: Trajectory) -> float:
        """How far (m) the TCP is above where the lowering `lower` ends."""
        return float(self.arm.tcp_pose()[2, 3] - self.planner.robot.fk_tcp(lower.q[-1])[2, 3])

    def _stopped_just_above(self, lower: Trajectory, e: ProtectiveStopError) -> bool:
        """The lowering was cut short (protective stop) within RELEASE_IF_STOPPED_WITHIN of its end: unlock and
        say so; the caller releases there. False (nothing done) otherwise."""
        left = self._descent_left(lower)
        if not 0.0 <= left <= self.RELEASE_IF_STOPPED_WITHIN or not self._holding():
            return False
        self._log("fault", "stopped_above_target", message=str(e), left_m=round(left, 4))
        self._cmd("arm.unlock_protective_stop", reason="stopped just above the release pose: releasing there")
        self.arm.unlock_protective_stop()
        return True
