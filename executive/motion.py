"""Motion and capture primitives of the task runner: asynchronous moves polled to their end (stop requests, time
budgets, a held item slipping out), planned joint moves, retracing a stopped motion, escaping the collision
margin, captures with bounded retries, and looking straight down at a spot.

A mixin of TaskRunner (executive/runner.py): it uses the runner's devices, planner, belief and journal; what it
remembers of the motions lives in ``self.tracks`` (:class:`MotionTracks`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from kitchenbot.drivers.errors import DriverError, DriverTimeoutError, ProtectiveStopError
from kitchenbot.executive.failures import StateTimeout, StepFailed, Stopped
from kitchenbot.executive.recovery_strategies import recover_with
from kitchenbot.perception.types import View
from kitchenbot.planning.types import Trajectory
from kitchenbot.transforms import make_T, rot_z


@dataclass
class MotionTracks:
    last: Trajectory | None = None  # the last motion commanded (to retrace it after a stop)
    stopped: Trajectory | None = None  # the motion the last protective stop cut short
    last_from_contact: bool = False  # the last motion began by leaving a release (never retraced: see below)
    searching: bool = False  # looking for a fallen item (see RecoveryActions._search_drop_site)
    tries: dict = field(default_factory=dict)  # recovery strategy (kind/name) -> runs this cycle
    wall: float = 0.0  # wall seconds spent waiting for motions
    cpu: float = 0.0  # process CPU seconds spent meanwhile (in simulation: stepping the simulated arm)

    def waited(self, t0: float, c0: float) -> None:
        """Count the wait since perf_counter() `t0` / process_time() `c0` as waiting for a motion."""
        self.wall += time.perf_counter() - t0
        self.cpu += time.process_time() - c0

    def new_cycle(self) -> None:
        """A pick starts: every recovery strategy has its tries again (executive/recovery_strategies.py)."""
        self.tries.clear()


def spot_measured(view: View, p_base: np.ndarray, half: int = 20) -> float:
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


@dataclass
class SpareScans:
    """Views captured at the scan waypoints beside a scan's own (TaskRunner._scan, `frames`), each set what a later
    scan of the same waypoints would capture while `token` (TaskRunner._scene_token) is unchanged."""

    sets: list[list[View]]
    token: tuple


class Motions:
    def _wait_motion(self, what: str, expected_s: float, carrying: bool = False) -> None:
        """Poll a running motion until it ends (stop requests, time budget; `carrying`: the gripper too, so that an
        object slipping out stops the arm right above where it fell)."""
        t0, c0 = time.perf_counter(), time.process_time()
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
                self.tracks.waited(t0, c0)
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
        self.tracks.waited(t0, c0)
        self._check_deadline()

    def _run_trajectory(self, traj: Trajectory, carrying: bool = False, guarded: bool = False,
                        from_contact: bool = False) -> None:
        """Execute a planned trajectory and wait for it. `guarded` (set-down moves): a contact of the held item
        or a pad ends it early (`arm.stopped_on_contact`) instead of in a protective stop. `from_contact`: it
        begins by leaving where the tool let go of an item (never retraced to get out of the margin)."""
        self._check_deadline()
        self.tracks.last, self.tracks.last_from_contact = traj, from_contact
        self._cmd("arm.execute_trajectory", name=traj.name, n=len(traj), duration=traj.duration,
                  q_start=traj.q[0], q_end=traj.q[-1], **({"guarded": True} if guarded else {}))
        t0, c0 = time.perf_counter(), time.process_time()
        with self._arm_lock:
            self.arm.execute_trajectory(traj.times, traj.q, asynchronous=True, guarded=guarded)
        self.tracks.waited(t0, c0)  # the (simulated) controller's work, not ours
        try:
            self._wait_motion(f"trajectory {traj.name}", traj.duration, carrying)
        except ProtectiveStopError:
            self.tracks.stopped = traj
            raise
        if carrying and not self._holding():  # it slipped out in the last poll period
            raise self._slipped(traj.name)
        self._log("result", "arm.execute_trajectory", name=traj.name, q=self.arm.joint_positions())

    # RRT-Connect's time budget grows by this factor after each timeout of one move: a search cut short by its
    # wall-clock budget (a narrow way out, a loaded computer) gets longer, not the same budget again.
    TIMEOUT_GROWTH = 2.0

    def _move_joints(self, q: np.ndarray, what: str) -> None:
        """A collision-free planned joint motion (three tries: RRT-Connect is randomised; after a timeout with a
        longer budget). Without one the arm does not move: StepFailed("no_path"). Only a runner built without a
        planner moves directly."""
        q_now = self.arm.joint_positions()
        if np.max(np.abs(q_now - q)) < 1e-3:
            return
        b = self.belief
        if self.planner is not None:
            plan, escaped, scale, tries, narrowed = None, None, 1.0, 0, set()
            opening, read = None, False
            while tries < 3:
                tries += 1
                plan = self.planner.plan_move(q_now, q, objects=b.scene_objects(), map_points=b.map_points,
                                              timeout_scale=scale, opening=opening)
                if plan.ok:
                    self._run_trajectory(plan.trajectory, from_contact="left_start_pairs" in plan.timings_ms)
                    return
                if plan.kind == "start_in_collision" and not read:
                    # the pads where they are (a release leaves them at the opening they let go with, narrower
                    # than the fully open pads plans assume): the way out the tool came in is checked with them
                    read = True
                    opening = None if self._holding() else self._opening()
                    if opening is not None:
                        tries -= 1  # (a try of its own)
                        continue
                if plan.kind == "planner_timeout":
                    scale *= self.TIMEOUT_GROWTH
                if plan.kind in ("start_in_collision", "goal_in_collision") and len(b.contact_points) \
                        and plan.kind not in narrowed:
                    # the marks of a stop (RecoveryActions._mark_contact) block where the arm is or must go: those
                    # the arm's own bodies stand in there (within the margin) have done their part (the arm backed
                    # off, or let go there); the others stay. They mark something real beside the arm (what a
                    # stopped lift met; an item let go over a stack lies there now): a move planned without them
                    # left the tool standing among the marks and went straight through what they marked.
                    narrowed.add(plan.kind)
                    q_at = q_now if plan.kind == "start_in_collision" else q
                    at = self.planner.points_at_robot(q_at, b.contact_points)
                    if at.any():
                        n = b.drop_contacts(where=at)
                        tries -= 1  # (a try of its own)
                        self._log("note", "contact marks dropped: they block the move", what=what, reason=str(plan),
                                  dropped=n, left=len(b.contact_points))
                        continue
                if plan.kind == "start_in_collision" and escaped is None:
                    # stopped within the margin of something (a protective stop): jog out first
                    escaped = recover_with(self, "start_in_collision")
                    if escaped:
                        q_now = self.arm.joint_positions()
            self._log("note", "no collision-free path; not moving", what=what, reason=str(plan))
            # the pairs within the margin where the arm stands (a start it could not leave): in the run's report
            blocking = [list(p) for p in plan.details.get("pairs", [])] if plan.kind == "start_in_collision" else []
            extra = {"blocking_pairs": blocking} if blocking else {}
            why = ""
            if escaped is not None and not escaped:  # why no recovery strategy got it out
                extra["escape"] = escaped.reason()
                why = f" (no way out of the margin: {escaped.reason()})"
            raise StepFailed("no_path", f"no collision-free path to {what}: {plan}{why}", **extra)
        self._cmd("arm.move_joints", q=q, speed=self.opt.scan_speed, what=what)
        with self._arm_lock:
            self.arm.move_joints(q, speed=self.opt.scan_speed, accel=1.0, asynchronous=True)
        dist = float(np.max(np.abs(q - q_now)))
        self._wait_motion(what, dist / self.opt.scan_speed + 1.0)

    MARKS_BLOCKING_RADIUS = 0.12  # m around the arm's axis and tool: marks there may close the way out

    def _arm_points(self, q: np.ndarray, step: float = 0.03) -> np.ndarray:
        """Points every 3 cm along the arm's chain of joint origins to the TCP at `q` (base frame)."""
        robot = self.planner.robot
        P = [np.asarray(T)[:3, 3] for T in robot.joint_placements(q)] + [robot.fk_tcp(q)[:3, 3]]
        out = [P[0]]
        for a, c in zip(P[:-1], P[1:]):
            n = max(1, int(np.ceil(np.linalg.norm(c - a) / step)))
            out.extend(a + (c - a) * (k / n) for k in range(1, n + 1))
        return np.asarray(out)

    def _move_joints_via(self, q: np.ndarray, what: str, via: np.ndarray) -> None:
        """_move_joints; when it finds no path, by way of `via` (home: a pose the planner connects easily to the
        rest). A place can leave the arm on another IK branch (elbow flipped, wrists turned by a full turn), from
        where a search with a bounded budget finds no way to a scan waypoint while one to home exists."""
        try:
            self._move_joints(q, what)
        except StepFailed as e:
            if e.kind != "no_path" or np.max(np.abs(self.arm.joint_positions() - via)) < 1e-3:
                raise
            self._log("note", "no path; going by way of home", what=what, reason=str(e))
            self._move_joints(via, f"home (on the way to {what})")
            self._move_joints(q, what)

    def _index_on(self, traj: Trajectory | None) -> int | None:
        """The sample of `traj` the arm stands at (within 0.01 rad per joint), or None if it is not on it."""
        if traj is None:
            return None
        d = np.max(np.abs(traj.q - self.arm.joint_positions()), axis=1)
        k = int(np.argmin(d))
        return k if d[k] < 0.01 else None

    def _retrace(self, traj: Trajectory | None, name: str, short_of: float = 0.0) -> bool:
        """If the arm stands on `traj` (it was stopped along it), go back along it to its start: the way it came
        is free in the world as it is, whatever the perceived poses say. `short_of` (m): stop where the tool is
        still that far from the start (a lift's start holds its item against what it stood on). False if the
        arm is not on it."""
        k = self._index_on(traj)
        if k is None or k == 0:
            return False
        j = 0
        if short_of > 0.0 and self.planner is not None:
            fk = self.planner.robot.fk_tcp
            p0 = fk(traj.q[0])[:3, 3]
            while j < k and np.linalg.norm(fk(traj.q[j])[:3, 3] - p0) < short_of:
                j += 1
            if j >= k:  # stopped within `short_of` of the start: already there (a one-sample path is no motion)
                return True
        back = slice(k, j - 1 if j > 0 else None, -1)
        self._run_trajectory(Trajectory(traj.times[k] - traj.times[back], traj.q[back].copy(), name))
        return True

    def _slipped(self, what: str) -> StepFailed:
        """The held object slipped out: it fell straight down from about where the tool is now."""
        where = self.arm.tcp_pose()[:3, 3].copy()
        obj = self.item.obj
        self.belief.record_dropped(where, self.item.staged, obj.cls if obj is not None else None, self._held_points())
        return StepFailed("slip", f"the {obj.cls if obj is not None else 'object'} slipped out during {what}",
                          at=where)

    def _held_points(self) -> np.ndarray | None:
        """The held item's model points (base frame) where the grasp holds it now (the tool's pose and the grasp's
        T_tcp_obj); None where the item or its grasp is not known."""
        it = self.item
        pick = it.pick
        if it.obj is None or pick is None or it.obj.obj_id not in self.robot.inventory.models:
            return None
        T = self.arm.tcp_pose() @ np.asarray(pick.grasp.T_tcp_obj, float)
        return self.robot.inventory[it.obj.obj_id].points @ T[:3, :3].T + T[:3, 3]

    def _escape(self) -> bool:
        """The arm is within the collision margin of something (it stopped there): the strategies for a start
        within the margin, in order (executive/recovery_strategies.py: a straight move out, else back along a
        last motion that started clear of any contact). False if none got it out."""
        return bool(recover_with(self, "start_in_collision"))

    def _opening(self) -> float | None:
        """The gripper's pad distance (m), None when it cannot be read."""
        try:
            return float(self.gripper.opening())
        except DriverError:
            return None

    def _holding(self) -> bool:
        try:
            return bool(self.gripper.is_holding())
        except DriverError:
            return False

    def _scan(self, frames: int = 1) -> list[View]:
        """Visit the scan waypoints and capture a view at each. `frames` > 1: as many views at each waypoint; the
        sets after the first are kept (``self.spare_scans``) for the scans that confirm the sink empty after this
        one: they would visit the very same joint configurations of a scene nothing touched in between
        (executive/verification.py, ``_confirming_scan``)."""
        sets: list[list[View]] = [[] for _ in range(max(1, frames))]
        skipped: list[StepFailed] = []
        home = np.asarray(self.robot.config.robot.home, float)
        self.spare_scans = None
        for k, q in enumerate(self.robot.config.scan_waypoints):
            try:
                self._move_joints_via(np.asarray(q, float), f"scan waypoint {k}", home)
            except StepFailed as e:  # blocked (e.g. by a pile on the counter): the other views still cover the sink
                if e.kind != "no_path":
                    raise
                skipped.append(e)
                continue
            sets[0].append(self._capture_view(f"scan{self.counts.scan_count}_wp{k}", f"scan_wp{k}"))
            try:
                for j, views in enumerate(sets[1:], 1):
                    views.append(self._capture_view(f"scan{self.counts.scan_count + j}_wp{k}", f"scan_wp{k}"))
            except (DriverError, StepFailed) as e:  # no spare frame here: no spare scans (each must be complete)
                self._log("note", "no spare views for the confirming scans", reason=str(e))
                sets = sets[:1]
        if not sets[0]:
            raise skipped[0]
        self._record_scan(sets[0])
        if len(sets) > 1:
            self.spare_scans = SpareScans(sets[1:], self._scene_token())
        return sets[0]

    def _record_scan(self, views: list[View]) -> None:
        """A scan's views taken: counted, written to the dataset and the recording."""
        self.counts.scan_count += 1
        if self.dataset is not None:
            self.dataset.write_scan(views)
        if self.recorder is not None:
            self.recorder.views(views, self._sim_now())

    def _scene_token(self) -> tuple:
        """What changes when the arm may have touched the scene or another scan was taken: grasp attempts (every
        pick, placement and put-down follows one), slides, scans. Not the belief's scene epoch: the perception of the
        scan itself records the placement it verifies."""
        return (self.report.attempts, self.report.slides, self.counts.scan_count)

    def _capture_view(self, where: str, key: str | None = None, spot: bool = False) -> View:
        """Capture with bounded retries on dropped frames and unusable depth; View with its camera pose. `spot`:
        a view aimed at one spot, usable with less of the image measured (RunOptions.min_valid_depth_spot)."""
        min_valid = self.opt.min_valid_depth_spot if spot else self.opt.min_valid_depth
        last: Exception | None = None
        for k in range(1 + self.opt.capture_retries):
            self._check_deadline()
            self._cmd("camera.capture", where=where, attempt=k)
            try:
                with self.stages.within("capture"):  # in simulation: rendering the simulated camera
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

    # Where the camera looks down from at a drop site or a target (m above the counter top), highest first: far
    # enough for the OAK-D's 20 cm minimum depth and for the view to cover where a falling item may roll; lower
    # ones where the arm does not reach that high over the far end of a rack.
    LOOK_DOWN_HEIGHTS = (0.50, 0.40, 0.30)

    def _look_down_at(self, site: np.ndarray) -> str:
        """Put the camera straight above `site`, looking down, by a planned collision-free motion. Returns "" when
        there, else why not."""
        planner = self.planner
        home = np.asarray(self.robot.config.robot.home, float)
        R_down = planner.robot.fk_tcp(home)[:3, :3]  # home points the tool down
        d_cam = (np.linalg.inv(planner.robot.T_flange_tcp) @ self.robot.T_flange_cam)[:3, 3]  # camera in tcp frame
        scene = planner.scene(self.belief.scene_objects(), self.belief.map_points)
        why = "no collision-free camera pose above it"
        tries = 0
        for height in self.LOOK_DOWN_HEIGHTS:
            p_cam = np.array([site[0], site[1], height])
            for yaw in np.radians([0.0, 90.0, -90.0, 180.0]):
                R = rot_z(yaw)[:3, :3] @ R_down
                for q in planner.robot.ik_all(make_T(R, p_cam - R @ d_cam), self.arm.joint_positions()):
                    if not scene.valid(q):
                        continue
                    try:
                        self._move_joints(q, "look down")
                        return ""
                    except StepFailed as e:
                        why = str(e)
                        tries += 1
                        if tries >= 3:  # each is up to three RRT-Connect queries
                            return why
        return why

    def _target_view(self, where: np.ndarray) -> View | None:
        """A view of the item just placed at `where`: from the retreat pose, else from straight above it (a rack
        below the counter is closer to the retreating camera than the depth camera's 20 cm minimum). None when
        neither gives one: the re-scan still verifies the sink side."""
        key = f"target{self.report.attempts}"
        try:
            view = self._capture_view(key, "target", spot=True)
            seen = spot_measured(view, where)
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
