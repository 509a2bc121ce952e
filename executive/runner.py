"""The task runner: drives the state machine (executive/machine.py) over a RobotCell, a task, a perceiver and a
planner; journals before acting; records; reports.

    report = run_task(load_config(), "sink-to-dishwasher", seed=3, report_path="out/report.json")

One visit of a state = one handler call (``_do_<state>``) that returns the trigger to fire next. Driver errors
and planning failures become a :class:`Failure` (executive/failures.py) and the ``fault`` trigger; ``recover``
applies the recovery rules (docs/executive.md; the actions they take are in executive/recovery.py) and fires
``rescan``, ``retry`` or ``give_up``. Motions are asynchronous and polled,
so ``request_stop`` acts at once and ``request_pause`` takes effect at the next safe point (a state boundary
with nothing in the gripper).
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from kitchenbot.drivers.errors import DriverError, DriverTimeoutError, ProtectiveStopError
from kitchenbot.executive import machine as M
from kitchenbot.executive.failures import Failure, StateTimeout, StepFailed, Stopped, classify  # noqa: F401
from kitchenbot.executive.journal import Journal
from kitchenbot.executive.recovery import RecoveryActions
from kitchenbot.executive.verify import target_presence
from kitchenbot.perception.types import ObjectPose, View
from kitchenbot.planning.types import NoFreeSlot, Trajectory
from kitchenbot.tasks.base import DROP_HEIGHT

SLIDABLE = ("plate",)  # classes that nest flat in stacks and are slid sideways to free them

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
    confirm_empty_scans: int = M.CONFIRM_EMPTY_SCANS  # consecutive scans that must agree the sink is done


@dataclass
class RunReport:
    task: str
    status: str = "running"  # succeeded | failed | stopped
    objects_total: int = 0
    objects_done: int = 0
    attempts: int = 0
    recoveries: int = 0
    slides: int = 0  # items slid sideways to free them (the top plate of a nested stack)
    escapes: int = 0  # straight moves out of a stop within the collision margin (planning.escape)
    recovered_drops: int = 0  # items that slipped out over the counter, found there and picked up again
    state_time_s: dict = field(default_factory=dict)  # wall seconds per state
    state_sim_time_s: dict = field(default_factory=dict)  # simulated seconds per state (simulation only)
    transitions: list = field(default_factory=list)
    failures: list = field(default_factory=list)
    collisions: int | None = None  # counted by the fake arm
    limit_violations: int | None = None  # commands the safety limits refused
    protective_stops: int | None = None
    slips: int | None = None
    cycles: list = field(default_factory=list)  # per placement: compute_s, motion_s, object
    compute_time_s: float = 0.0  # wall seconds of everything but waiting for motions
    wall_time_s: float = 0.0
    sim_time_s: float | None = None
    seed: int | None = None
    run_id: int | None = None
    perception: str = "pipeline"  # pipeline | oracle (ground truth from the simulator)
    truth: dict | None = None  # simulation: what really happened
    message: str = ""
    safe: bool = True  # ended with the arm at a known safe pose

    def as_dict(self) -> dict:
        return asdict(self)

    def to_dict(self) -> dict:
        """Plain JSON types only (what the report file holds)."""
        return json.loads(json.dumps(self.as_dict(), default=_jsonable))

    def save(self, path: str | Path) -> None:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        Path(path).write_text(json.dumps(self.to_dict(), indent=2))


def _jsonable(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    return str(o)


@dataclass
class _Tried:
    """What happened to one object: executed grasp attempts, and planning failures since the scene last changed
    (an object under or behind others is unplannable until they are gone, so those failures are forgotten
    after each placement)."""
    cls: str
    pos: np.ndarray
    count: int = 0
    reasons: list = field(default_factory=list)
    plan_failures: int = 0
    plan_epoch: int = -1
    slides: int = 0

    def plan_failed(self, epoch: int) -> None:
        if self.plan_epoch != epoch:
            self.plan_epoch, self.plan_failures = epoch, 0
        self.plan_failures += 1

    def exhausted(self, epoch: int) -> bool:
        return self.count >= M.MAX_ATTEMPTS_PER_OBJECT or (
            self.plan_epoch == epoch and self.plan_failures >= M.MAX_PLAN_FAILURES_PER_SCENE)


@dataclass
class _Pending:
    """A placement executed but not yet verified."""

    obj: ObjectPose
    target: Any
    T_base_obj: np.ndarray
    target_view: View | None
    staging: bool = False  # set down upright on the counter to be grasped again (regrasp)
    staged: Any = None  # the tasks.Placed record this object was picked up from (a staged object)
    near_before: int = 1  # same-class objects within gone_radius of it in the scan it was picked from


def _spot_measured(view: View, p_base: np.ndarray, half: int = 20) -> float:
    """Fraction of pixels with depth in a (2 half + 1)^2 window around where `p_base` projects (0 when it does
    not project into the image, or lies nearer than 5 cm)."""
    p = (np.linalg.inv(view.T_base_cam) @ np.append(p_base, 1.0))[:3]
    if p[2] < 0.05:
        return 0.0
    u, v = (view.K @ p)[:2] / p[2]
    h, w = view.depth.shape
    u0, u1 = int(max(u - half, 0)), int(min(u + half + 1, w))
    v0, v1 = int(max(v - half, 0)), int(min(v + half + 1, h))
    if u0 >= u1 or v0 >= v1:
        return 0.0
    d = view.depth[v0:v1, u0:u1]
    return float(np.mean(np.isfinite(d) & (d > 0)))


# ---- the runner --------------------------------------------------------------------------------------------------------
class TaskRunner(RecoveryActions):
    def __init__(self, robot, task, perceiver, planner, *, journal: Journal | None = None, recorder=None,
                 dataset=None, listeners: list[Listener] | None = None, advance: Callable[[float], None] | None = None,
                 sim_clock: Callable[[], float] | None = None, fault_hook: Callable[[list], list] | None = None,
                 options: RunOptions | None = None, seed: int | None = None, perception_label: str = "pipeline",
                 truth: Callable[[str], dict] | None = None):
        self.robot = robot
        self.arm, self.gripper, self.camera = robot.arm, robot.gripper, robot.camera
        self.task = task
        self.perceiver = perceiver
        self.planner = planner
        self.journal = journal
        self.recorder = recorder
        self.dataset = dataset
        self.listeners = list(listeners or [])
        self.advance = advance or time.sleep  # simulation: the fake arm's clock tick
        self.sim_clock = sim_clock
        self.fault_hook = fault_hook
        self.opt = options or RunOptions()
        self.truth = truth
        self.owns_devices = False  # set by whoever assembled the cell for this run only (disconnect at the end)
        self.report = RunReport(task.name, seed=seed, perception=perception_label)
        self.machine_model = M.MachineModel()
        self.machine = M.build_machine(self.machine_model)
        self.run_id: int | None = None
        self._stop = threading.Event()
        self._pause = threading.Event()
        self._resume = threading.Event()
        self._arm_lock = threading.RLock()
        # per-run memory
        self.views: list[View] = []
        self.poses: list[ObjectPose] = []
        self.map_points: np.ndarray | None = None
        self.current: ObjectPose | None = None
        self.targets: list = []
        self.pick = None
        self.place = None
        self.pending: _Pending | None = None
        self.failure: Failure | None = None
        self.tried: list[_Tried] = []
        self.slide = None  # a planned slide (planning.types.SlidePlan) instead of a pick and place
        self.scene_epoch = 0  # placements so far (staging included): planning failures are per epoch
        self.unverified: list[str] = []  # gone from the sink but not seen at the target
        self.unplannable: list[ObjectPose] = []
        self.staged: list = []  # tasks.Placed: objects set down on the counter for a regrasp
        self.current_staged = None
        self.staging = False
        self.scan_failures = 0
        self.consecutive_recoveries = 0
        self.empty_scans = 0
        self.reconnects = 0
        self.scan_count = 0
        self.latest_images: dict[str, np.ndarray] = {}
        self._state_t0 = time.perf_counter()
        self._state_sim0 = self._sim_now()
        self._motion_wall = 0.0
        self._cycle_t0 = (time.perf_counter(), 0.0, self._sim_now())
        self._first_total: int | None = None
        self.dropped = 0  # items that left the gripper on the way (slips, let go over the cell after a fault)
        self._searching = False  # looking for a fallen item (see _search_drop_site)
        self._unseen_placement = None  # the record of a placement its check did not see (see _verify_pending)
        self._last_traj: Trajectory | None = None  # the last motion commanded (to retrace it after a stop)
        self._stopped_traj: Trajectory | None = None  # the motion the last protective stop cut short
        self.contact_points = np.zeros((0, 3))  # where stopped motions met something no model shows (see _mark_contact)
        self.contact_epochs = np.zeros(0, int)  # the scene_epoch each contact point was marked in
        self._map_base: np.ndarray | None = None  # the last perception's map points (map_points = these + contacts)
        self.prefer_instance: int | None = None  # perceived instance to try next (it blocks the last one tried)
        self.drop_site: np.ndarray | None = None  # where the tool was when the last item slipped out
        self._table_perceiver = None  # perception without the cell (the counter as a table top), for drop sites
        self._deadline: float | None = None
        self._t_start = time.perf_counter()

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
        rt.state_time_s[src] = rt.state_time_s.get(src, 0.0) + now - self._state_t0
        if sim is not None:
            rt.state_sim_time_s[src] = rt.state_sim_time_s.get(src, 0.0) + sim - self._state_sim0
        rec = {"trigger": trigger, "source": src, "dest": dest, "t": round(now - self._t_start, 4)}
        if sim is not None:
            rec["sim_t"] = round(sim, 3)
        self._log("transition", trigger, source=src, dest=dest)  # journaled before it happens
        getattr(self.machine_model, trigger)()
        rt.transitions.append(rec)
        self._state_t0, self._state_sim0 = now, sim
        self._deadline = self._timeout_deadline(dest)
        if self.recorder is not None:
            self.recorder.state(src, dest, trigger, sim)
        self._emit({"type": "transition", **rec, "objects_done": rt.objects_done, "objects_total": rt.objects_total})

    def _sim_now(self) -> float | None:
        return self.sim_clock() if self.sim_clock is not None else None

    def _timeout_deadline(self, state: str) -> float | None:
        return M.timeout_of(state)

    def _check_deadline(self) -> None:
        if self._stop.is_set():
            raise Stopped()
        limit = self._deadline
        if limit is None:
            return
        elapsed = time.perf_counter() - self._state_t0
        if self._state_sim0 is not None:
            elapsed += self._sim_now() - self._state_sim0
        if elapsed > limit:
            raise StateTimeout(f"state {self.state} exceeded its {limit:g} s timeout")

    # ---- the loop -----------------------------------------------------------------------------------------------
    def run(self) -> RunReport:
        self._t_start = time.perf_counter()
        self._deadline = None
        sim0 = self._sim_now()
        if self.journal is not None:
            if self.run_id is None:  # the daemon begins the journal's run itself, to answer with its id
                self.run_id = self.journal.begin_run(self.task.name, self.report.seed)  # raises HomingRequired
            self._log("note", "task", **self.task.describe())
        self.report.run_id = self.run_id
        if self.truth is not None:
            self._truth_start = self.truth("start")
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
        rt = self.report
        st = self.state
        rt.status = {"done": "succeeded", "stopped": "stopped"}.get(st, "failed")
        if st == "stopped":
            rt.message = rt.message or "stopped on request"
        now = time.perf_counter()
        rt.state_time_s[st] = rt.state_time_s.get(st, 0.0) + now - self._state_t0
        rt.wall_time_s = now - self._t_start
        rt.compute_time_s = rt.wall_time_s - self._motion_wall
        if sim0 is not None:
            rt.sim_time_s = self._sim_now() - sim0
        log = getattr(self.arm, "log", None)  # the fake arm's audit counters (simulation only)
        if log is not None:
            rt.collisions, rt.limit_violations = log.collisions, log.refused
            rt.protective_stops, rt.slips = log.protective_stops, log.slips
        remaining = len(self.task.remaining(self.poses)) if self.poses or rt.objects_done else 0
        rt.objects_total = max(rt.objects_total, rt.objects_done + remaining)
        if self.truth is not None:
            rt.truth = {"start": self._truth_start, "end": self.truth("end")}
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

    # ---- motion primitives (asynchronous + polled) ---------------------------------------------------------------
    def _wait_motion(self, what: str, expected_s: float, carrying: bool = False) -> None:
        """Poll a running motion until it ends (stop requests, time budget; `carrying`: the gripper too, so that an
        object slipping out stops the arm right above where it fell)."""
        t0 = time.perf_counter()
        s0 = self._sim_now()
        limit = 2.0 * expected_s + 5.0  # driver seconds
        while True:
            if self._stop.is_set():
                raise Stopped()
            with self._arm_lock:
                moving = self.arm.is_moving()
            if not moving:
                break
            if carrying and not self._holding():
                slipped = self._slipped(what)  # the tool is about above where it fell now, not after stopping
                self._cmd("arm.stop", reason=f"the held object slipped out during {what}")
                with self._arm_lock:
                    self.arm.stop()
                self._motion_wall += time.perf_counter() - t0
                raise slipped
            if self.advance is time.sleep:
                time.sleep(self.opt.poll_period)
            else:
                with self._arm_lock:  # the simulated controller's tick must not interleave with a stop()
                    self.advance(self.opt.poll_period)
            el = (self._sim_now() - s0) if s0 is not None else (time.perf_counter() - t0)
            if el > limit:
                self._cmd("arm.stop", reason=f"{what} overran its time budget")
                with self._arm_lock:
                    self.arm.stop()
                raise StateTimeout(f"{what}: still moving after {el:.1f} s (expected {expected_s:.1f} s)")
        with self._arm_lock:
            self.arm.wait(0.0)  # raises ProtectiveStopError / DeviceNotConnectedError if it ended badly
        self._motion_wall += time.perf_counter() - t0
        self._check_deadline()

    def _run_trajectory(self, traj: Trajectory, carrying: bool = False, guarded: bool = False) -> None:
        """Execute a planned trajectory and wait for it. `guarded` (set-down moves): a contact of the held item
        or a pad ends it early (`arm.stopped_on_contact`) instead of in a protective stop."""
        self._check_deadline()
        self._last_traj = traj
        self._cmd("arm.execute_trajectory", name=traj.name, n=len(traj), duration=traj.duration,
                  q_start=traj.q[0], q_end=traj.q[-1], **({"guarded": True} if guarded else {}))
        t0 = time.perf_counter()
        with self._arm_lock:
            self.arm.execute_trajectory(traj.times, traj.q, asynchronous=True, guarded=guarded)
        self._motion_wall += time.perf_counter() - t0  # the (simulated) controller's work, not ours
        try:
            self._wait_motion(f"trajectory {traj.name}", traj.duration, carrying)
        except ProtectiveStopError:
            self._stopped_traj = traj
            raise
        if carrying and not self._holding():  # it slipped out in the last poll period
            raise self._slipped(traj.name)
        self._log("result", "arm.execute_trajectory", name=traj.name, q=self.arm.joint_positions())

    def _move_joints(self, q: np.ndarray, what: str) -> None:
        """A collision-free planned joint motion (two tries: RRT-Connect is randomised). Without one the arm does
        not move: StepFailed("no_path"). Only a runner built without a planner moves directly."""
        q_now = self.arm.joint_positions()
        if np.max(np.abs(q_now - q)) < 1e-3:
            return
        if self.planner is not None:
            plan, escaped = None, False
            for _ in range(3):
                plan = self.planner.plan_move(q_now, q, objects=self._scene_objects(), map_points=self.map_points)
                if plan.ok:
                    self._run_trajectory(plan.trajectory)
                    return
                if plan.kind in ("start_in_collision", "goal_in_collision") and len(self.contact_points):
                    # the marks of a stop (_mark_contact) block where the arm is or must go: they have done their
                    # part (the arm backed off); a move the marks make impossible is planned without them
                    self._log("note", "contact marks dropped: they block the move", what=what, reason=str(plan))
                    self.contact_points, self.contact_epochs = np.zeros((0, 3)), np.zeros(0, int)
                    self.map_points = self._map_base
                    continue
                if plan.kind == "start_in_collision" and not escaped:
                    escaped = True  # stopped within the margin of something (a protective stop): jog out first
                    if self._escape():
                        q_now = self.arm.joint_positions()
            self._log("note", "no collision-free path; not moving", what=what, reason=str(plan))
            raise StepFailed("no_path", f"no collision-free path to {what}: {plan}")
        self._cmd("arm.move_joints", q=q, speed=self.opt.scan_speed, what=what)
        with self._arm_lock:
            self.arm.move_joints(q, speed=self.opt.scan_speed, accel=1.0, asynchronous=True)
        dist = float(np.max(np.abs(q - q_now)))
        self._wait_motion(what, dist / self.opt.scan_speed + 1.0)

    def _index_on(self, traj: Trajectory | None) -> int | None:
        """The sample of `traj` the arm stands at (within 0.01 rad per joint), or None if it is not on it."""
        if traj is None:
            return None
        d = np.max(np.abs(traj.q - self.arm.joint_positions()), axis=1)
        k = int(np.argmin(d))
        return k if d[k] < 0.01 else None

    def _retrace(self, traj: Trajectory | None, name: str) -> bool:
        """If the arm stands on `traj` (it was stopped along it), go back along it to its start: the way it came
        is free in the world as it is, whatever the perceived poses say. False if the arm is not on it."""
        k = self._index_on(traj)
        if k is None or k == 0:
            return False
        self._run_trajectory(Trajectory(traj.times[k] - traj.times[k::-1], traj.q[k::-1].copy(), name))
        return True

    def _slipped(self, what: str) -> StepFailed:
        """The held object slipped out: it fell straight down from about where the tool is now."""
        self.dropped += 1
        where = self.arm.tcp_pose()[:3, 3].copy()
        self.drop_site = where
        cls = self.current.cls if self.current is not None else "object"
        return StepFailed("slip", f"the {cls} slipped out during {what}", at=where)

    def _escape(self) -> bool:
        """The arm is within the collision margin of something (it stopped there): move the tool straight out
        (planning.escape), so that planned motions can start again. False if no safe straight way out exists."""
        held = self.pick.grasp if (self.pick is not None and self._holding()) else None
        plan = self.planner.plan_escape(self.arm.joint_positions(), self._scene_objects(), map_points=self.map_points,
                                        held=held)
        if not plan.ok:
            # Inside something as perceived (a pose error: the arm was stopped before real contact): back along
            # the motion that brought it here (not when looking for a fallen item: it may lie on that way now).
            last = self._last_traj
            if not self._searching and self._retrace(last, "retrace"):
                self._log("note", "retraced the stopped motion out of the collision margin", reason=str(plan),
                          motion=last.name)
                self.report.escapes += 1
                return True
            self._log("note", "no way out of the collision margin", reason=str(plan))
            return False
        self._log("note", "escaping the collision margin", **plan.timings_ms)
        self._run_trajectory(plan.trajectory)
        self.report.escapes += 1
        return True

    def _holding(self) -> bool:
        try:
            return bool(self.gripper.is_holding())
        except DriverError:
            return False

    # ---- capture ---------------------------------------------------------------------------------------------
    def _capture_view(self, where: str, key: str | None = None, spot: bool = False) -> View:
        """Capture with bounded retries on dropped frames and unusable depth; View with its camera pose. `spot`:
        a view aimed at one spot, usable with less of the image measured (RunOptions.min_valid_depth_spot)."""
        min_valid = self.opt.min_valid_depth_spot if spot else self.opt.min_valid_depth
        last: Exception | None = None
        for k in range(1 + self.opt.capture_retries):
            self._check_deadline()
            self._cmd("camera.capture", where=where, attempt=k)
            try:
                f = self.camera.capture()
            except DriverTimeoutError as e:
                last = e
                self._log("fault", "camera_timeout", where=where, message=str(e))
                continue
            valid = np.isfinite(f.depth) & (f.depth > 0)
            if valid.mean() < min_valid:
                last = StepFailed("bad_depth", f"{where}: only {valid.mean():.0%} of the depth image is valid")
                self._log("fault", "bad_depth", where=where, valid=float(valid.mean()))
                continue
            T_base_cam = self.arm.flange_pose() @ self.robot.T_flange_cam
            self.latest_images[key or where] = f.rgb  # the latest per waypoint / target view
            return View(f.rgb, f.depth, f.K, T_base_cam, f.stamp)
        assert last is not None
        raise last

    # ---- states ----------------------------------------------------------------------------------------------------
    def _scan(self) -> list[View]:
        views = []
        skipped: list[StepFailed] = []
        for k, q in enumerate(self.robot.config.scan_waypoints):
            try:
                self._move_joints(np.asarray(q, float), f"scan waypoint {k}")
            except StepFailed as e:  # blocked (e.g. by a pile on the counter): the other views still cover the sink
                if e.kind != "no_path":
                    raise
                skipped.append(e)
                continue
            views.append(self._capture_view(f"scan{self.scan_count}_wp{k}", f"scan_wp{k}"))
        if not views:
            raise skipped[0]
        self.scan_count += 1
        if self.dataset is not None:
            self.dataset.write_scan(views)
        if self.recorder is not None:
            self.recorder.views(views, self._sim_now())
        return views

    def _perceive(self) -> None:
        self._cmd("perceive", views=len(self.views))
        res = self.perceiver.perceive(self.views)
        self._check_deadline()  # perception cannot be interrupted: its timeout is checked when it returns
        poses = list(res.poses)
        if self.fault_hook is not None:
            poses = self.fault_hook(poses)
        self.poses = poses
        self.unplannable: list[ObjectPose] = []  # failed to plan with these poses
        self._map_base = getattr(res, "map_points", None)
        self.map_points = self._with_contacts(self._map_base)
        self._log("result", "perceive", objects=[{"obj_id": p.obj_id, "cls": p.cls, "xyz": p.T_base_obj[:3, 3],
                                                  "score": p.score} for p in poses])
        if self.recorder is not None:
            self.recorder.perception(res, poses, self._sim_now())
        self._verify_pending()
        if self._first_total is None:
            # the task's own objects (remaining() may also list items to move out of their way first)
            self._first_total = sum(1 for p in self.task.remaining(poses) if self.task.wants(p))
            self.report.objects_total = self._first_total
        self._emit({"type": "progress", "objects_done": self.report.objects_done,
                    "objects_total": max(self.report.objects_total,
                                         self.report.objects_done + len(self.task.remaining(poses)))})

    def _do_scan(self) -> str:
        self.views = self._scan()
        self.scan_failures = 0
        return "scanned"

    def _do_perceive(self) -> str:
        self._perceive()
        return "perceived"

    def _tried_for(self, p: ObjectPose, create: bool = False) -> _Tried | None:
        for t in self.tried:
            if t.cls == p.cls and np.linalg.norm(t.pos - p.T_base_obj[:3, 3]) < 0.04:
                return t
        if create:
            t = _Tried(p.cls, p.T_base_obj[:3, 3].copy())
            self.tried.append(t)
            return t
        return None

    def _candidates(self, this_scan: bool = False) -> list[ObjectPose]:
        """Objects with attempts left; `this_scan`: also not yet failed to plan with the current perception
        (the same poses give the same answer: try the others first, this one again after the next scan)."""
        out = []
        for p in self.task.remaining(self.poses):
            t = self._tried_for(p)
            if t is None or not t.exhausted(self.scene_epoch):
                if not (this_scan and any(p is q for q in self.unplannable)):
                    out.append(p)
        return out

    def _do_select_grasp(self) -> str:
        self.pick = self.place = self.slide = None
        self.current_staged, self.staging = None, False
        for st in list(self.staged):  # staged objects first: they wait on the counter for their regrasp
            obj = self.task.as_pose(st)
            t = self._tried_for(obj)
            if t is not None and t.exhausted(self.scene_epoch):
                continue
            targets = self.task.targets(obj)
            if isinstance(targets, NoFreeSlot):
                self._tried_for(obj, create=True).count = M.MAX_ATTEMPTS_PER_OBJECT
                continue
            self.current, self.targets, self.current_staged = obj, targets, st
            self._log("note", "selected", obj_id=obj.obj_id, cls=obj.cls, xyz=obj.T_base_obj[:3, 3], staged=True)
            return "selected"
        cands = self._candidates(this_scan=True)
        prefer, self.prefer_instance = self.prefer_instance, None
        if prefer is not None and prefer >= 0:
            if not any(p.instance_id == prefer for p in cands):
                # an item the task does not want lies on the one it does (a glass on a mug on a cup): it is
                # moved out of the way (the task's targets for it) if it is in the sink and not tried out
                extra = [p for p in self.poses if p.instance_id == prefer and self.task.in_sink(p)]
                t = self._tried_for(extra[0]) if extra else None
                if extra and (t is None or not t.exhausted(self.scene_epoch)):
                    cands.insert(0, extra[0])
            cands.sort(key=lambda p: p.instance_id != prefer)  # stable: otherwise the task's order
        for obj in cands:
            targets = self.task.targets(obj)
            if isinstance(targets, NoFreeSlot):
                t = self._tried_for(obj, create=True)
                t.count = M.MAX_ATTEMPTS_PER_OBJECT
                t.reasons.append(str(targets))
                self._log("note", "no_target", cls=obj.cls, reason=str(targets))
                continue
            self.current, self.targets = obj, targets
            self._log("note", "selected", obj_id=obj.obj_id, cls=obj.cls, xyz=obj.T_base_obj[:3, 3],
                      targets=[t.T_base_obj[:3, 3] for t in targets])
            self._emit({"type": "progress", "object": obj.cls, "objects_done": self.report.objects_done,
                        "objects_total": self.report.objects_total})
            return "selected"
        return "nothing_left"

    def _scene_objects(self) -> list[ObjectPose]:
        """Perceived objects plus what the task put down; a perceived object where we put one down is that one."""
        placed = self.task.obstacles()
        pend = self.pending
        if pend is not None:  # released but not verified yet: it is at its target, no longer where it was seen
            placed.append(ObjectPose(pend.obj.obj_id, pend.obj.cls, pend.T_base_obj, 1.0, instance_id=99_999))
        seen = [p for p in self.poses if not (pend is not None and p is pend.obj) and not any(p.cls == o.cls and np.linalg.norm(p.T_base_obj[:3, 3] - o.T_base_obj[:3, 3]) < 0.04
                           for o in placed)]
        return seen + placed

    def _staged_pick(self, q, scene_objs, obj):
        """(pick, staging targets) to set `obj` down on the counter (in a pose the task chooses for its targets)
        and grasp it again from there, where its next pick offers other grasps; None when it is already staged,
        needs no regrasp, or no staging spot is reachable.

        Tried when no grasp of it as it lies reaches the target orientation; for a task that says so
        (Task.stage_when_blocked) also when the full place plan finds the release the grasp filter accepted
        unreachable (a lying mug, sink-to-dishwasher seed 30), and when every grasp that reaches the target has its
        lift blocked a second time (the first time the blocker is picked first): tilted plates whose on-edge
        grasps' lifts hit a neighbour (sink-to-dishwasher seed 30, while sink-pick, which takes any grasp, cleared
        the same sink)."""
        if self.current_staged is not None or not self.task.needs_regrasp(self.targets, obj):
            return None
        stage = self.task.staging_targets(obj, self.targets)
        if isinstance(stage, NoFreeSlot):
            return None
        self._cmd("plan_pick", cls=obj.cls, staging=[t.T_base_obj[:3, 3] for t in stage])
        staged_pick = self.planner.plan_pick(q, scene_objs, target=obj, map_points=self.map_points,
                                             place_target=stage)
        self._check_deadline()
        if not staged_pick.ok:
            return None
        self.staging = True
        return staged_pick, stage

    def _do_plan(self) -> str:
        """Pick (only grasps that can also reach one of the targets) then place (first feasible target)."""
        obj = self.current
        q = self.arm.joint_positions()
        scene_objs = self._scene_objects()
        self._cmd("plan_pick", cls=obj.cls, targets=[t.T_base_obj[:3, 3] for t in self.targets])
        pick = self.planner.plan_pick(q, scene_objs, target=obj, map_points=self.map_points,
                                      place_target=self.targets)
        if not pick.ok and pick.kind == "start_in_collision" and self._escape():
            q = self.arm.joint_positions()
            pick = self.planner.plan_pick(q, scene_objs, target=obj, map_points=self.map_points,
                                          place_target=self.targets)
        self._check_deadline()
        targets = self.targets
        tried = self._tried_for(obj)
        if not pick.ok and (pick.kind == "no_feasible_placement" or (
                self.task.stage_when_blocked and pick.kind == "cartesian_path_failed" and tried is not None
                and pick.kind in tried.reasons)):
            staged = self._staged_pick(q, scene_objs, obj)
            if staged is not None:
                pick, targets = staged
        if not pick.ok and pick.kind == "no_collision_free_grasp" and obj.cls in SLIDABLE \
                and self.current_staged is None:
            # Nested in a stack (the top plate): no pinch fits under its lip. Slide it sideways with the closed
            # fingers first; the next scan sees it overhanging the one below, where a lip pinch fits.
            t = self._tried_for(obj, create=True)
            if t.slides < M.MAX_SLIDES_PER_OBJECT:
                self._cmd("plan_slide", cls=obj.cls)
                slide = self.planner.plan_slide(q, scene_objs, obj, map_points=self.map_points)
                self._check_deadline()
                if slide.ok:
                    self.slide = slide
                    self._log("result", "planned slide", direction=slide.direction, distance=slide.distance,
                              to=slide.T_base_obj_after[:3, 3])
                    if self.recorder is not None:
                        self.recorder.plan(slide.trajectories, self._sim_now())
                    return "planned"
                self._log("note", "no slide", reason=str(slide))
        if not pick.ok:
            raise StepFailed("planning", f"no pick plan for the {obj.cls}: {pick}", planning_kind=pick.kind,
                             blocking=pick.details.get("blocking"))
        others = [p for p in scene_objs if p is not obj and not (obj.instance_id >= 0 and p.instance_id == obj.instance_id)]
        self._cmd("plan_place", grasp=pick.grasp.spec.name, staging=self.staging)
        place = self.planner.plan_place(pick.end, pick.grasp, targets, objects=others, map_points=self.map_points)
        if not place.ok and place.kind == "no_feasible_placement" and not self.staging and self.task.stage_when_blocked:
            # The grasp filter judged a release reachable that the full place plan is not (a lying mug, seed 30):
            # as when no grasp passes that filter, stage it for a regrasp.
            staged = self._staged_pick(q, scene_objs, obj)
            if staged is not None:
                pick, targets = staged
                self._cmd("plan_place", grasp=pick.grasp.spec.name, staging=self.staging)
                place = self.planner.plan_place(pick.end, pick.grasp, targets, objects=others,
                                                map_points=self.map_points)
        if not place.ok:
            raise StepFailed("planning", f"no place plan for the {obj.cls}: {place}", planning_kind=place.kind)
        self.pick, self.place = pick, place
        self._log("result", "planned", grasp=pick.grasp.spec.name, target=place.T_base_obj[:3, 3],
                  duration=sum(t.duration for t in pick.trajectories + place.trajectories))
        if self.recorder is not None:
            self.recorder.plan(pick.trajectories + place.trajectories, self._sim_now())
        return "planned"

    def _do_execute(self) -> str:
        if self.slide is not None:
            return self._execute_slide()
        pick, place, obj = self.pick, self.place, self.current
        self.report.attempts += 1
        self._tried_for(obj, create=True).count += 1
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
        self._run_trajectory(pick.lift, carrying=True)
        self._run_trajectory(place.transfer, carrying=True)
        try:
            self._run_trajectory(place.lower, carrying=True, guarded=True)
            stopped_short = self.arm.stopped_on_contact  # it met its support above the release pose
            if stopped_short and self._descent_left(place.lower) > self.RELEASE_IF_STOPPED_WITHIN:
                # met something well above its support (a neighbour, a rack wire): not a set-down; recovered
                # like a protective stop (the contact marked, back up, put down away from this target)
                self._stopped_traj = place.lower
                raise StepFailed("contact", f"the {obj.cls} met something "
                                 f"{self._descent_left(place.lower):.3f} m above its release pose")
        except ProtectiveStopError as e:
            if not self._stopped_just_above(place.lower, e):
                raise
            stopped_short = True
        if stopped_short:
            self._log("note", "set down on contact before the release pose", cls=obj.cls,
                      tcp=self.arm.tcp_pose()[:3, 3])
        self._cmd("gripper.open", opening=pick.grasp.spec.opening, release=True)
        self.gripper.open(pick.grasp.spec.opening)
        if stopped_short:  # back up the way it came down (the planned retreat starts at the release pose)
            self._retrace(place.lower, "retreat")
        else:
            self._run_trajectory(place.retreat)
        # Where it should rest: the release pose (turned as the planner chose) at the target's height (the
        # planner may release higher up when the gripper cannot reach lower; the object then drops).
        T_expected = np.array(place.T_base_obj, float)
        T_expected[2, 3] = min(T_expected[2, 3], float(place.target.T_base_obj[2, 3]))
        self._expect_placed(place.target, T_expected, self.staging)
        if self.opt.verify_target_view:
            self.pending.target_view = self._target_view(T_expected[:3, 3])
        return "executed"

    def _expect_placed(self, target, T_rest: np.ndarray, staging: bool) -> None:
        """The current object was set down at `target`, resting at T_rest: the next perception verifies it (gone
        from the sink, present there) and records it (staged for a regrasp when `staging`)."""
        obj = self.current
        self.pending = _Pending(obj, target, T_rest, None, staging, self.current_staged,
                                near_before=max(1, len(self._same_class_near(obj))))
        if self.planner is not None and self._map_base is not None:
            # the map still holds the points where it stood: nothing explains them now that it is gone
            self._map_base = self.planner.without_points_of(self._map_base, obj)
            c = self.contact_points
            self.map_points = np.vstack([self._map_base, c]) if len(c) else self._map_base

    # A lowering stopped by contact this close above its release pose has set the item down on its support (the
    # held item sat lower in the fingers than its perceived pose said): it is let go there, as from a guarded move.
    RELEASE_IF_STOPPED_WITHIN = 0.03  # m of TCP descent left

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

    def _target_view(self, where: np.ndarray) -> View | None:
        """A view of the item just placed at `where`: from the retreat pose, else from straight above it (a rack
        below the counter is closer to the retreating camera than the depth camera's 20 cm minimum). None when
        neither gives one: the re-scan still verifies the sink side."""
        key = f"target{self.report.attempts}"
        try:
            view = self._capture_view(key, "target", spot=True)
            seen = _spot_measured(view, where)
            if seen >= 0.5:
                return view
            self._log("note", "no target view from the retreat pose", reason=f"{seen:.0%} of the spot has depth")
        except (DriverTimeoutError, StepFailed) as e:
            self._log("note", "no target view from the retreat pose", reason=str(e))
        try:
            why = self._look_down_at(where)
            if not why:
                return self._capture_view(key + "_above", "target", spot=True)
            self._log("note", "no target view", reason=why)
        except (DriverTimeoutError, StepFailed) as e:
            self._log("note", "no target view", reason=str(e))
        return None

    def _execute_slide(self) -> str:
        """Close the fingers, press on the item, slide it, go back up; the re-scan (verify) sees where it went."""
        sl, obj = self.slide, self.current
        t = self._tried_for(obj, create=True)
        t.slides += 1
        self.report.slides += 1
        self._cmd("gripper.open", opening=0.0, why="closed fingers press on the item")
        self.gripper.open(0.0)
        for traj in sl.trajectories:
            self._run_trajectory(traj)
        self.slide = None
        t.pos = sl.T_base_obj_after[:3, 3].copy()  # it is the same item over there (bounded slides)
        self.scene_epoch += 1  # the scene changed: what could not be planned may be now
        self._log("result", "slid", cls=obj.cls, to=sl.T_base_obj_after[:3, 3])
        return "executed"

    def _do_verify(self) -> str:
        """Re-scan (the first perception after a placement verifies it) and decide: next object, done, give up."""
        self.views = self._scan()
        self._perceive()
        cands = self._candidates()
        staged_left = [st for st in self.staged
                       if not (self._tried_for(self.task.as_pose(st)) or _Tried("", np.zeros(3))).exhausted(
                           self.scene_epoch)]
        if cands or staged_left:
            self.empty_scans = 0
            return "next_object"
        left = self.task.remaining(self.poses)
        if left:
            why = []
            for q in left:
                t = self._tried_for(q)
                rs = sorted(set(t.reasons)) if t is not None else []
                why.append(f"{q.cls} ({', '.join(rs) or 'no attempts left'})")
            self.report.message = f"{len(left)} object(s) left in the sink: " + "; ".join(why)
            self.report.safe = self._make_safe()
            return "give_up"
        self.empty_scans += 1
        if self.empty_scans < self.opt.confirm_empty_scans:
            return "next_object"
        problems = []
        if self.unverified:
            problems.append(f"{len(self.unverified)} placement(s) not verified at the target: "
                            f"{', '.join(self.unverified)}")
        if self.staged:
            problems.append(f"{len(self.staged)} object(s) left on the counter after a regrasp failed: "
                            f"{', '.join(st.cls for st in self.staged)}")
        # First-scan items neither in the sink nor placed: as many as were dropped on the way (slips, a held item
        # let go over the cell) are lost; any more were never there (a duplicate detection in the first scan
        # that no later scan confirmed): noted, not a failure.
        missing = (self._first_total or 0) - self.report.objects_done - len(self.unverified) - len(self.staged)
        lost = min(max(missing, 0), self.dropped)
        if lost > 0:
            problems.append(f"{lost} object(s) dropped during the run are neither in the sink nor placed "
                            "(out of reach?)")
        if missing - lost > 0:
            self.report.message = (f"{missing - lost} first-scan detection(s) never confirmed by a later scan "
                                   "(duplicates?)")
        if problems:
            self.report.message = "sink empty, but " + "; ".join(problems)
            self.report.safe = self._make_safe()
            return "give_up"
        return "complete"

    def _same_class_near(self, obj: ObjectPose) -> list[ObjectPose]:
        return [q for q in self.poses if q.cls == obj.cls and
                np.linalg.norm(q.T_base_obj[:3, 3] - obj.T_base_obj[:3, 3]) < self.opt.gone_radius]

    def _verify_pending(self) -> None:
        """Verify the last placement against fresh poses: gone from the sink, present at its target."""
        p = self.pending
        if p is None:
            return
        self.pending = None
        # Gone when fewer same-class objects are seen there than before the pick: the top plate of a stack
        # leaves the one nested below it within gone_radius.
        near = self._same_class_near(p.obj)
        still = near if len(near) >= p.near_before else []
        presence = None
        if p.target_view is not None:
            presence = target_presence(p.target_view, self.robot.inventory[p.obj.obj_id], p.T_base_obj)
        self._log("result", "verify", still_in_sink=len(still), presence=presence.as_dict() if presence else None)
        seen_there = presence is not None and presence.decided and presence.present
        if still and not seen_there:
            raise StepFailed("verify_failed", f"the {p.obj.cls} is still in the sink")
        if still:  # seen at its target: what is still counted at its old spot is the item under it or a duplicate
            self._log("note", "placed, though an item of its class is still seen where it was", cls=p.obj.cls)
        if presence is not None and presence.decided and not presence.present:
            # Gone from the sink but not seen where it should be (tipped over, fell): something is likely
            # there, so it stays an obstacle at its target; the report counts it as unverified.
            self.unverified.append(p.obj.cls)
            if p.staged is not None:
                self.task.unplace(p.staged.instance_id)
                self.staged = [s for s in self.staged if s is not p.staged]
            self._unseen_placement = self.task.record_placed(p.obj, p.target, p.T_base_obj)
            # it may have tipped or fallen off a stack next to its target: the recovery looks there from above
            # (as for a slip), and an item found there is picked up again (its record at the target goes)
            self.drop_site = np.array(p.T_base_obj[:3, 3], float)
            raise StepFailed("verify_failed", f"the {p.obj.cls} was not seen at its target "
                             f"({presence.agree:.0%} of {presence.pixels} px agree)")
        T_settled = p.T_base_obj.copy()
        if presence is not None and presence.decided:
            T_settled[2, 3] += presence.dz  # where it came to rest (it was released a little above)
        if p.staging:
            # Set down on the flat counter, it rests DROP_HEIGHT below its target pose (which stands it on the
            # counter); the depth fit's dz put an upside-down cup 1.5 cm below where it rested (oracle seed 46),
            # and its next grasps, planned on that pose, hit the counter.
            T_settled[2, 3] = float(p.target.T_base_obj[2, 3]) - DROP_HEIGHT
        if p.staged is not None:  # it left its staging spot
            self.task.unplace(p.staged.instance_id)
            self.staged = [s for s in self.staged if s is not p.staged]
        placed = self.task.record_placed(p.obj, p.target, T_settled)
        self.scene_epoch += 1
        if p.staging:
            # A new item on that spot: attempts are kept per class and place (_tried_for), and the grasp attempts
            # of an earlier item staged there (now in the rack) would count against this one (dishwasher seed 4:
            # the fourth cup staged on the spot three had used was never picked up again).
            self.tried = [t for t in self.tried
                          if not (t.cls == p.obj.cls and np.linalg.norm(t.pos - T_settled[:3, 3]) < 0.04)]
            self.staged.append(placed)
            self._log("note", "staged for a regrasp", cls=p.obj.cls, xyz=T_settled[:3, 3])
        self.consecutive_recoveries = 0
        if not p.staging:
            self.report.objects_done += int(self.task.wants(p.obj))  # not an item only moved out of the way
            w0, m0, s0 = self._cycle_t0
            wall, sim = time.perf_counter(), self._sim_now()
            self.report.cycles.append({"object": p.obj.cls, "wall_s": round(wall - w0, 3),
                                       "compute_s": round((wall - w0) - (self._motion_wall - m0), 3),
                                       "motion_sim_s": round(sim - s0, 3) if sim is not None else None})
            self._cycle_t0 = (wall, self._motion_wall, sim)
            self._emit({"type": "placed", "object": p.obj.cls, "objects_done": self.report.objects_done,
                        "objects_total": self.report.objects_total})

    def _do_recover(self) -> str:
        f = self.failure
        self.report.recoveries += 1
        if f.kind != "planning":  # planning failures are bounded per object; these count towards giving up
            self.consecutive_recoveries += 1
        self._log("note", "recover", kind=f.kind, state=f.state)
        if f.kind in ("estop", "error") or self.consecutive_recoveries > M.MAX_CONSECUTIVE_RECOVERIES:
            # an emergency stop needs a person; an unexpected error is a bug: neither is retried
            self.report.message = f"gave up after {f.kind}: {f.message}"
            self.report.safe = f.kind != "estop" and self._make_safe()
            return "give_up"
        self._restore_devices(f)
        if f.kind in ("camera_timeout", "bad_depth"):
            self.scan_failures += 1
            if self.scan_failures >= M.MAX_SCAN_RETRIES:
                self.report.message = f"camera keeps failing: {f.message}"
                self.report.safe = self._make_safe()
                return "give_up"
        if f.state in ("plan", "select_grasp") and self.current is not None:
            t = self._tried_for(self.current, create=True)  # skipped until the scene changes
            t.plan_failed(self.scene_epoch)
            t.reasons.append(f.details.get("planning_kind", f.kind))
        elif f.state in ("execute", "verify") and self.current is not None:
            self._tried_for(self.current, create=True).reasons.append(f.kind)  # counted when executed
        if f.kind == "planning" and f.state == "plan":
            if self.current is not None and self.current_staged is None:
                self.unplannable.append(self.current)
            # the planner names the item lying on this one (or in the way of its lift): that one next
            self.prefer_instance = f.details.get("blocking")
            return "retry"  # the next object with the same perception; this one again after the next scan
        stopped = (self._stopped_traj.name if f.kind in ("protective_stop", "contact") and self._stopped_traj
                   else None)
        lift_marks = None
        if stopped == "lift":  # put down from where it stopped, not back in the pile; marked after the put-down
            lift_marks = self._contact_sliver(self._stopped_traj) if self.planner is not None else None
            self._stopped_traj = None
        elif stopped:
            self._back_off()
        if self._holding():  # not again where the held item was just stopped on its way down to its target
            self._put_down_held(avoid_place_target=stopped in ("transfer", "lower"))
        if lift_marks is not None:  # the next try at this item lifts clear of what it met
            self._add_contact_marks(lift_marks)
        self._back_out()
        if self.drop_site is not None:  # it slipped out, or was let go over the cell: look where it fell
            self._search_drop_site()
        return "rescan"


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
