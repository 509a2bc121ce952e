"""The task runner: drives the state machine (executive/machine.py) over a RobotCell, a task, a perceiver and a
planner; journals before acting; records; reports.

    report = run_task(load_config(), "sink-to-dishwasher", seed=3, report_path="out/report.json")

One visit of a state = one handler call (``_do_<state>``) that returns the trigger to fire next. What the robot
believes (poses, the map, what it placed, attempts) is ``self.belief`` (executive/belief.py); the item in hand is
``self.item``. The states live in small mixins: plan and execute (executive/execution.py: the task's strategies,
executive/strategies.py), verify (executive/verification.py), recover (executive/recovery.py, applying the rules
of executive/recovery_rules.py), motions and captures (executive/motion.py). Driver errors and planning failures
become a :class:`Failure` (executive/failures.py) and the ``fault`` trigger. Motions are asynchronous and polled,
so ``request_stop`` acts at once and ``request_pause`` takes effect at the next safe point (a state boundary
with nothing in the gripper).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field

import numpy as np

from kitchenbot.drivers.errors import DriverError
from kitchenbot.executive import machine as M
from kitchenbot.executive.belief import Belief, as_pose
from kitchenbot.executive.execution import Execution, Item
from kitchenbot.executive.failures import Failure, StateTimeout, StepFailed, Stopped, classify  # noqa: F401
from kitchenbot.executive.journal import Journal
from kitchenbot.executive.motion import MotionTracks, Motions, SpareScans, spot_measured  # noqa: F401
from kitchenbot.executive.recovery import RecoveryActions
from kitchenbot.executive.report import RunReport
from kitchenbot.executive.stage_times import StageTimes
from kitchenbot.executive.strategies import aside_targets, strategies_for
from kitchenbot.executive.verification import Verification
from kitchenbot.executive.waiting import Chains
from kitchenbot.perception.pipeline import Perceiver
from kitchenbot.perception.types import ObjectPose, View
from kitchenbot.planning.types import NoFreeSlot, Trajectory  # noqa: F401

Listener = Callable[[dict], None]


# ---- options and report --------------------------------------------------------------------------------------------
@dataclass
class RunOptions:
    poll_period: float = 0.01  # s between motion polls (simulated seconds in simulation)
    grasp_current: float = 0.5  # A current limit when closing on an object
    scan_speed: float = 1.0  # rad/s for direct scan moves when planning is unavailable
    capture_retries: int = 2  # extra captures at a waypoint after a dropped frame / bad depth
    min_valid_depth: float = 0.3  # fraction of pixels with depth for a usable view
    # ...for a view aimed at one spot (a placement, a drop site): a rack's wires and the open dishwasher leave
    # much of the image without depth (edges, grazing angles) while the spot itself is measured; a failed
    # camera gives none at all
    min_valid_depth_spot: float = 0.1
    gone_radius: float = 0.02  # m: a same-class object this close to the picked one means it is still there
    max_reconnects: int = 3
    verify_target_view: bool = True  # capture at the retreat pose and check the object at its target
    # no re-scan after a placement its retreat view settles (executive/verification.py); False: always re-scan
    verify_without_rescan: bool = True
    # where an item may have moved with the pick (or it came off a stack): one view straight down at the pick spot
    # re-perceives that region instead of a re-scan, where it settles it: each of its items found again where it
    # was, nothing new (executive/verification.py; docs/executive.md, "Incremental perception")
    verify_region_view: bool = True
    confirm_empty_scans: int = M.CONFIRM_EMPTY_SCANS  # consecutive scans that must agree the sink is done


@dataclass
class Counters:
    """The run's counters the recovery rules read."""

    scan_failures: int = 0  # consecutive failed scans
    consecutive_recoveries: int = 0  # recoveries since the last verified placement
    empty_scans: int = 0  # consecutive scans with nothing left
    reconnects: int = 0
    scan_count: int = 0


@dataclass
class RunClock:
    """Wall and simulated time of the run, the current state and the current placement cycle."""

    t_start: float = field(default_factory=time.perf_counter)
    state_t0: float = field(default_factory=time.perf_counter)
    state_sim0: float | None = None
    state_cpu0: float = field(default_factory=time.thread_time)  # the runner thread's CPU time at the state's start
    cycle_t0: tuple = (0.0, 0.0, None)  # (wall, motion wall, sim) at the start of the placement cycle
    cycle_stages0: tuple = ({}, {})  # compute (wall, CPU) per stage at the start of the placement cycle
    deadline: float | None = None  # s the current state may take


# ---- the runner --------------------------------------------------------------------------------------------------------
class TaskRunner(Execution, Verification, RecoveryActions, Motions):
    def __init__(self, robot, task, perceiver, planner, *, journal: Journal | None = None, recorder=None,
                 dataset=None, listeners: list[Listener] | None = None, advance: Callable[[float], None] | None = None,
                 sim_clock: Callable[[], float] | None = None, fault_hook: Callable[[list], list] | None = None,
                 options: RunOptions | None = None, seed: int | None = None, perception_label: str = "pipeline",
                 truth: Callable[[str], dict] | None = None):
        # wiring (set once)
        self.robot, self.task, self.perceiver, self.planner = robot, task, perceiver, planner
        self.journal, self.recorder, self.dataset = journal, recorder, dataset
        self.listeners = list(listeners or [])
        self.advance = advance or time.sleep  # simulation: the fake arm's clock tick
        self.sim_clock, self.fault_hook, self.truth = sim_clock, fault_hook, truth
        self.opt = options or RunOptions()
        self.strategies = strategies_for(task)
        self.owns_devices = False  # set by whoever assembled the cell for this run only (disconnect at the end)
        self.machine_model = M.MachineModel()
        self.machine = M.build_machine(self.machine_model)
        self._stop, self._pause, self._resume = threading.Event(), threading.Event(), threading.Event()
        self._arm_lock = threading.RLock()
        # the run
        self.report = RunReport(task.name, seed=seed, perception=perception_label)
        self.run_id: int | None = None
        self.belief = Belief()
        self.item = Item()
        self.failure: Failure | None = None
        self.views: list[View] = []
        self.spare_scans: SpareScans | None = None  # views for the scans that confirm the sink empty (_scan)
        self.latest_images: dict[str, np.ndarray] = {}
        self.counts = Counters()
        self.tracks = MotionTracks()
        self.stages = StageTimes(self.tracks, "idle")  # compute per stage (executive/stage_times.py)
        self.clock = RunClock(state_sim0=self._sim_now())
        self.clock.cycle_t0 = (time.perf_counter(), 0.0, self._sim_now())
        self.table_perceiver = None  # perception without the cell (the counter as a table top), for drop sites
        self.settings_before_harder = None  # the planner's settings before the last, harder round (Execution._try_harder)
        self.truth_start: dict | None = None

    @property
    def arm(self):
        return self.robot.arm

    @property
    def gripper(self):
        return self.robot.gripper

    @property
    def camera(self):
        return self.robot.camera

    # ---- control from other threads --------------------------------------------------------------------------------
    @property
    def state(self) -> str:
        return self.machine_model.state

    def request_stop(self) -> None:
        """Stop now: the arm decelerates immediately; the run ends in `stopped`."""
        self._stop.set()
        self._resume.set()
        if self.journal is not None:
            self.journal.event(self.run_id, "command", "arm.stop", self.state, reason="stop requested")
        with self._arm_lock:
            try:
                self.arm.stop()
            except DriverError:
                pass

    def request_pause(self) -> None:
        self._resume.clear()
        self._pause.set()

    def request_resume(self) -> None:
        self._pause.clear()
        self._resume.set()

    # ---- journal / events --------------------------------------------------------------------------------------
    def _emit(self, ev: dict) -> None:
        for fn in self.listeners:
            try:
                fn(ev)
            except Exception:  # noqa: BLE001 - a broken listener must not stop the robot's task
                pass

    def _log(self, kind: str, name: str, /, **payload) -> None:
        if self.journal is not None:
            self.journal.event(self.run_id, kind, name, self.state, **payload)

    def _cmd(self, name: str, /, **payload) -> None:
        """Journal a device command BEFORE sending it."""
        self._log("command", name, **payload)

    def _fire(self, trigger: str) -> None:
        src = self.state
        dest = next(d for t, s, d in M.TRANSITIONS if t == trigger and (s == src or (not isinstance(s, str) and src in s)))
        now = time.perf_counter()
        sim = self._sim_now()
        rt = self.report
        ck = self.clock
        rt.state_time_s[src] = rt.state_time_s.get(src, 0.0) + now - ck.state_t0
        if sim is not None:
            rt.state_sim_time_s[src] = rt.state_sim_time_s.get(src, 0.0) + sim - ck.state_sim0
        rec = {"trigger": trigger, "source": src, "dest": dest, "t": round(now - ck.t_start, 4)}
        if sim is not None:
            rec["sim_t"] = round(sim, 3)
        self._log("transition", trigger, source=src, dest=dest)  # journaled before it happens
        getattr(self.machine_model, trigger)()
        rt.transitions.append(rec)
        self.stages.enter(dest)
        ck.state_t0, ck.state_sim0, ck.state_cpu0 = now, sim, time.thread_time()
        ck.deadline = M.timeout_of(dest)
        if self.recorder is not None:
            self.recorder.state(src, dest, trigger, sim)
        self._emit({"type": "transition", **rec, "objects_done": rt.objects_done, "objects_total": rt.objects_total})

    def _sim_now(self) -> float | None:
        return self.sim_clock() if self.sim_clock is not None else None

    def _check_deadline(self) -> None:
        if self._stop.is_set():
            raise Stopped()
        ck = self.clock
        if ck.deadline is None:
            return
        if ck.state_sim0 is None:  # real devices: wall time, whatever it was spent on
            elapsed = time.perf_counter() - ck.state_t0
        else:
            # Simulation: the runner thread's CPU time (its compute) plus simulated time (its motions). Wall time
            # would make the timeout depend on what else the machine runs, and a loaded host would time out
            # states that a robot computer would finish.
            elapsed = time.thread_time() - ck.state_cpu0 + self._sim_now() - ck.state_sim0
        if elapsed > ck.deadline:
            raise StateTimeout(f"state {self.state} exceeded its {ck.deadline:g} s timeout")

    # ---- the loop -----------------------------------------------------------------------------------------------
    def run(self) -> RunReport:
        self.clock.t_start = time.perf_counter()
        self.clock.deadline = None
        self.stages = StageTimes(self.tracks, self.state)
        self.clock.cycle_t0 = (self.clock.t_start, self.tracks.wall, self._sim_now())
        self.clock.cycle_stages0 = ({}, {})
        sim0 = self._sim_now()
        if self.journal is not None:
            if self.run_id is None:  # the daemon begins the journal's run itself, to answer with its id
                self.run_id = self.journal.begin_run(self.task.name, self.report.seed)  # raises HomingRequired
            self._log("note", "task", **self.task.describe())
        self.report.run_id = self.run_id
        if self.truth is not None:
            self.truth_start = self.truth("start")
        try:
            for dev in (self.arm, self.gripper, self.camera):
                if not dev.is_connected:
                    self._cmd(f"{type(dev).__name__}.connect")
                    dev.connect()
            self._fire("start")
            self._loop()
        except Exception as e:  # noqa: BLE001 - anything unexpected: journal it, make safe, fail
            self._log("fault", "unhandled", error=f"{type(e).__name__}: {e}")
            self.report.message = f"unhandled {type(e).__name__}: {e}"
            if self.state not in M.TERMINAL:
                self.report.safe = self._make_safe()
                if self.state in M.WORKING:
                    self._fire("give_up")
        finally:
            self._finish(sim0)
        return self.report

    def _loop(self) -> None:
        while self.state not in M.TERMINAL:
            if self._stop.is_set():
                self._fire("stop")
                break
            if self._pause.is_set() and self.state in M.WORKING and not self._holding():
                self._fire("pause")
                self._emit({"type": "paused"})
                self._resume.wait()
                if self._stop.is_set():
                    self._fire("stop")
                    break
                self._fire("resume")
                continue
            state = self.state
            try:
                trigger = getattr(self, f"_do_{state}")()
            except Stopped:
                self._fire("stop")
                break
            except Exception as e:  # noqa: BLE001 - every failure goes through the recovery rules
                self.failure = classify(e, state)
                self.report.failures.append(asdict(self.failure))
                self._log("fault", self.failure.kind, message=self.failure.message, details=self.failure.details)
                self._emit({"type": "fault", "kind": self.failure.kind, "message": self.failure.message})
                if state == "recover":
                    self.report.message = f"gave up: recovery itself failed ({self.failure.kind}: " \
                                          f"{self.failure.message})"
                    self.report.safe = self._make_safe()
                    trigger = "give_up"
                else:
                    trigger = "fault"
            self._fire(trigger)

    def _finish(self, sim0) -> None:
        rt, st, b = self.report, self.state, self.belief
        if self.settings_before_harder is not None:  # a planner passed in may plan the next run
            self.planner.settings, self.settings_before_harder = self.settings_before_harder, None
        rt.status = {"done": rt.done_status, "stopped": "stopped"}.get(st, "failed")
        if st == "stopped":
            rt.message = rt.message or "stopped on request"
        now = time.perf_counter()
        rt.state_time_s[st] = rt.state_time_s.get(st, 0.0) + now - self.clock.state_t0
        rt.wall_time_s = now - self.clock.t_start
        rt.compute_time_s = rt.wall_time_s - self.tracks.wall
        rt.compute_by_stage_s = {k: round(v, 4) for k, v in self.stages.totals().items() if v > 0}
        rt.compute_cpu_by_stage_s = {k: round(v, 4) for k, v in self.stages.cpu_totals().items() if v > 0}
        rt.compute_cpu_time_s = round(sum(rt.compute_cpu_by_stage_s.values()), 4)
        if sim0 is not None:
            rt.sim_time_s = self._sim_now() - sim0
        rt.items_per_minute = rt.rate(rt.objects_done)
        log = getattr(self.arm, "log", None)  # the fake arm's audit counters (simulation only)
        if log is not None:
            rt.collisions, rt.limit_violations = log.collisions, log.refused
            rt.protective_stops, rt.slips = log.protective_stops, log.slips
        remaining = len(self.task.remaining(b.poses)) if b.poses or rt.objects_done else 0
        rt.objects_total = max(rt.objects_total, rt.objects_done + remaining)
        if self.truth is not None:
            rt.truth = {"start": self.truth_start, "end": self.truth("end")}
        rt.state_time_s = {k: round(v, 4) for k, v in rt.state_time_s.items()}
        rt.state_sim_time_s = {k: round(v, 4) for k, v in rt.state_sim_time_s.items()}
        if self.journal is not None and self.run_id is not None:
            self.journal.end_run(self.run_id, rt.status, rt.as_dict() | {"transitions": rt.transitions}, safe=rt.safe)
        if self.recorder is not None:
            self.recorder.close()
        if self.owns_devices:
            self.robot.disconnect()
        self._emit({"type": "finished", "status": rt.status, "objects_done": rt.objects_done,
                    "objects_total": rt.objects_total})

    # ---- scan, perceive, select ---------------------------------------------------------------------------------
    def _perceive(self) -> None:
        self._cmd("perceive", views=len(self.views))
        with self.stages.within("perceive"):
            if isinstance(self.perceiver, Perceiver) and self.belief.poses:
                # a re-scan: poses tracked (perception/track.py), kept where their map did not change; rest: full
                res = self.perceiver.perceive(self.views, priors=list(self.belief.poses),
                                              prior_map=self.belief.map_base)
            else:
                res = self.perceiver.perceive(self.views)
        self._check_deadline()  # perception cannot be interrupted: its timeout is checked when it returns
        poses = list(res.poses)
        if self.fault_hook is not None:
            poses = self.fault_hook(poses)
        b = self.belief
        b.perceived(poses, getattr(res, "map_points", None), self.task.pending_items(poses),
                    self.robot.cell.sink_interior)
        self._log("result", "perceive", objects=[{"obj_id": p.obj_id, "cls": p.cls, "xyz": p.T_base_obj[:3, 3],
                                                  "score": p.score} for p in poses],
                  tracked=getattr(res, "tracked", 0), kept=getattr(res, "kept", 0))
        if self.recorder is not None:
            self.recorder.perception(res, poses, self._sim_now())
        self._verify_pending()
        if b.first_total is None:
            # the task's own objects (remaining() may also list items to move out of their way first)
            b.record_first_total(sum(1 for p in self.task.remaining(poses) if self.task.wants(p)))
            self.report.objects_total = b.first_total
        self._emit({"type": "progress", "objects_done": self.report.objects_done,
                    "objects_total": max(self.report.objects_total,
                                         self.report.objects_done + len(self.task.remaining(poses)))})

    def _do_scan(self) -> str:
        self.views = self._scan()
        self.counts.scan_failures = 0
        return "scanned"

    def _do_perceive(self) -> str:
        self._perceive()
        return "perceived"

    def _candidates(self, this_scan: bool = False) -> list[ObjectPose]:
        return self._ordered(this_scan, None)[0]

    def _ordered(self, this_scan: bool, prefer: int | None) -> tuple[list[ObjectPose], list[ObjectPose]]:
        """(objects with attempts left, those tried for another's sake). `this_scan`: not yet failed to plan with the
        current perception (the same poses give the same answer); one that waits for what pins it: the deepest item
        of its chain instead (executive/waiting.py); `prefer` (an instance id) first: an item the task does not want
        lying on one it does (a glass on a mug on a cup) is moved out of the way if it is in the sink."""
        b = self.belief
        fresh = lambda p: not (this_scan and any(p is q for q in b.unplannable))  # noqa: E731
        cands = [p for p in self.task.remaining(b.poses) if not b.exhausted(p) and fresh(p)]
        first = next((p for p in b.poses if prefer is not None and prefer >= 0 and p.instance_id == prefer), None)
        usable = lambda p: any(p is q for q in cands) or (self.task.in_sink(p) and (fresh(p) or p is first) and (  # noqa: E731
            not b.exhausted(p) or aside_targets(self.task, b, p) is not None))
        return Chains(b.waits, b.scene_objects(), b.marks, usable).order(cands, first)

    def _do_select_grasp(self) -> str:
        b = self.belief
        self.item = Item()
        for st in b.staged_waiting():  # staged objects first: they wait on the counter for their regrasp
            if b.needs_look(st):  # where it settled when let go, not where it was put down
                st = self._look_at_staged(st)
                if st is None:  # a found drop the look disproved: looked for again, the record gone
                    continue
            obj = as_pose(st)
            targets = self.task.targets(obj, b)
            if isinstance(targets, NoFreeSlot):
                if not self._candidates():  # else it waits: a plate placed frees the room kept for it
                    b.give_up_on(obj, str(targets))
                continue
            self.item = Item(obj, targets, st)
            self._log("note", "selected", obj_id=obj.obj_id, cls=obj.cls, xyz=obj.T_base_obj[:3, 3], staged=True)
            return "selected"
        cands, for_others = self._ordered(True, b.take_preferred())
        for obj in cands:
            targets = self.task.targets(obj, b)
            if isinstance(targets, NoFreeSlot):
                aside = aside_targets(self.task, b, obj) if any(obj is q for q in for_others) else None
                if aside is not None:
                    b.record_set_aside(obj)
                    self.item = Item(obj, aside)
                    self._log("note", "selected to set aside", obj_id=obj.obj_id, cls=obj.cls, reason=str(targets),
                              xyz=obj.T_base_obj[:3, 3], targets=[t.T_base_obj[:3, 3] for t in aside])
                    return "selected"
                b.no_room(obj, str(targets))  # tried again when the room changes
                self._log("note", "no_target", cls=obj.cls, reason=str(targets))
                continue
            self.item = Item(obj, targets)
            self._log("note", "selected", obj_id=obj.obj_id, cls=obj.cls, xyz=obj.T_base_obj[:3, 3],
                      targets=[t.T_base_obj[:3, 3] for t in targets])
            self._emit({"type": "progress", "object": obj.cls, "objects_done": self.report.objects_done,
                        "objects_total": self.report.objects_total})
            return "selected"
        return "nothing_left"


# ---- the entry point used by the CLI, the demo and the daemon ------------------------------------------------------
def home_arm(robot, planner, journal: Journal | None, advance=None) -> None:
    """The explicit home action: a planned (else direct) joint move to the configured home, gripper open;
    clears the journal's homing requirement."""
    arm = robot.arm
    for dev in (robot.arm, robot.gripper):
        if not dev.is_connected:
            dev.connect()
    from kitchenbot.drivers.arm import SafetyState

    if arm.safety_state() is SafetyState.PROTECTIVE_STOP:
        arm.unlock_protective_stop()
    home = np.asarray(robot.config.robot.home, float)
    if journal is not None:
        journal.event(None, "command", "home", q=home)
    q = arm.joint_positions()
    plan = planner.plan_move(q, home) if planner is not None else None
    if plan is not None and plan.ok:
        arm.execute_trajectory(plan.trajectory.times, plan.trajectory.q, asynchronous=True)
    else:
        arm.move_joints(home, speed=0.5, accel=1.0, asynchronous=True)
    tick = advance or time.sleep
    while arm.is_moving():
        tick(0.02)
    arm.wait(0.0)
    if robot.gripper.error() is not None:
        robot.gripper.reboot()
    robot.gripper.open()
    if journal is not None:
        journal.mark_homed()


def run_task(config, task_name: str, seed: int | None = None, report_path=None, record_path=None,
             progress: bool = True, *, oracle_perception: bool = False, journal_path=None, dataset_dir=None,
             listeners: list[Listener] | None = None, robot=None, options: RunOptions | None = None,
             runner_hook: Callable[[TaskRunner], None] | None = None) -> RunReport:
    """Assemble the cell from `config` (fake drivers over a simulated kitchen where configured), run `task_name`,
    write the report JSON / rerun recording when asked, and return the report."""
    from kitchenbot.executive.session import build_runner

    runner = build_runner(config, task_name, seed, record_path=record_path, oracle_perception=oracle_perception,
                          journal_path=journal_path, dataset_dir=dataset_dir, listeners=listeners, robot=robot,
                          options=options)
    if runner_hook is not None:
        runner_hook(runner)
    if progress:
        from kitchenbot.executive.progress import LiveProgress

        with LiveProgress(runner) as live:
            runner.listeners.append(live.on_event)
            report = runner.run()
    else:
        report = runner.run()
    if report_path is not None:
        report.save(report_path)
    return report
