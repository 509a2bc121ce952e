"""What ur_rtde's control script (``rtde_control``, uploaded to the script port) does on the controller, for
the commands the driver uses, as a state machine run once per control cycle.

The register protocol (from the script ur_rtde 1.6.5 ships): the client writes a command id to input int
register 0 (+ offset 0 or 24) and its arguments to input int/double registers 1.. / 0..; the script reports
on output int register 0 (1 = ready for a command, 2 = done with it), results on output int 1 / doubles 0..,
and async progress on output int 2: bits 24-30 operation id (incremented when an operation starts), 16-22 a
write counter, bit 15 running, bits 0-14 progress. Realtime commands (servoj, speedj, ...) are taken every
cycle and only answered with "ready"; all others run once (the client then writes 0 and the script is ready
again). Synchronous moves block the script's main loop until the robot arrives. An asynchronous move runs in
a thread that starts on the next cycle.
"""

from __future__ import annotations

import numpy as np

try:
    from .robot import Brake, JointMove, LinearMove, ServoTrack, T_to_pose, pose_to_T
except ImportError:  # run as a script in the emulator process (see controller.py)
    from robot import Brake, JointMove, LinearMove, ServoTrack, T_to_pose, pose_to_T  # type: ignore[no-redef]

READY, DONE = 1, 2
REALTIME = {24, 11, 9, 10, 6, 25, 26, 27, 38, 58, 66, 67, 68, 69, 70, 71}
NAMES = {1: "moveJ", 2: "moveJ_IK", 3: "moveL", 4: "moveL_FK", 11: "servoJ", 15: "speedStop", 16: "servoStop",
         17: "setPayload", 29: "setTcp", 31: "triggerProtectiveStop", 33: "stopL", 34: "stopJ",
         35: "setWatchdog", 36: "isPoseWithinSafetyLimits", 37: "isJointsWithinSafetyLimits",
         40: "getTCPOffset", 255: "stopScript"}
STOP_DECEL_ON_KILL = 4.0  # rad/s^2: a killed move thread leaves the robot braking


class ControlScript:
    def __init__(self, regs: dict, robot, offset: int, log, now=lambda: 0.0, thread_start_delay: float = 0.0):
        self.regs, self.robot, self.offset, self.log = regs, robot, offset, log
        self.now = now  # controller time
        self.thread_start_delay = thread_start_delay  # extra latency before a `run`ed thread begins (busy script)
        self.keep_running = True
        self.executing = False
        self.blocking = None  # the motion a synchronous command waits for
        self.move_motion = None  # motion of the async move thread
        self.move_pending = None  # started on the next cycle
        self.servo: ServoTrack | None = None
        self.wr_count = 0
        self.op_id = 0
        self.request_protective_stop = False
        self.write_async(-1)
        self.out_int(0, READY)

    # ---- registers ----------------------------------------------------------------------------------
    def in_int(self, i: int) -> int:
        return int(self.regs.get(f"input_int_register_{i + self.offset}", 0))

    def in_double(self, i: int) -> float:
        return float(self.regs.get(f"input_double_register_{i + self.offset}", 0.0))

    def in_vec(self, i: int) -> list[float]:
        return [self.in_double(i + k) for k in range(6)]

    def out_int(self, i: int, v: int) -> None:
        self.regs[f"output_int_register_{i + self.offset}"] = int(v)

    def out_double(self, i: int, v: float) -> None:
        self.regs[f"output_double_register_{i + self.offset}"] = float(v)

    def write_async(self, value: int) -> None:
        self.wr_count = 0 if self.wr_count + 1 > 127 else self.wr_count + 1
        if value == 0:
            self.op_id = 0 if self.op_id + 1 > 127 else self.op_id + 1
        reg = self.wr_count * 65536 + self.op_id * 16777216
        if value >= 0:
            reg += min(value, 32767) + 32768
        self.out_int(2, reg)

    # ---- the main loop, one control cycle -------------------------------------------------------------
    def cycle(self) -> None:
        self._run_move_thread()
        if self.blocking is not None:
            if self.robot.motion is self.blocking:
                return
            self.blocking = None
            self.out_int(0, DONE)
            return
        cmd = self.in_int(0)
        if cmd in REALTIME:
            self._realtime(cmd)
            self.out_int(0, READY)
        elif cmd == 0:
            self.executing = False
            self.out_int(0, READY)
        elif not self.executing:
            self.executing = True
            self.log(NAMES.get(cmd, f"cmd{cmd}"))
            self._process(cmd)
            if cmd == 255:
                self.keep_running = False
            elif self.blocking is None:
                self.out_int(0, DONE)

    def _run_move_thread(self) -> None:
        if self.move_pending is not None and self.now() >= self.move_pending[1]:
            # `run move_thread()` from an earlier cycle begins now
            m, self.move_pending = self.move_pending[0], None
            self.write_async(0)
            self.move_motion = m
            self.robot.motion = m
        elif self.move_motion is not None and self.robot.motion is not self.move_motion:
            self.move_motion = None
            self.write_async(-1)

    def _stop_async_move(self) -> None:
        """Kill the move thread: the robot brakes (along its path) and the operation is reported finished."""
        if self.move_motion is not None or self.move_pending is not None:
            self.move_pending = None
            if self.move_motion is not None and self.robot.motion is self.move_motion:
                self.move_motion.brake = STOP_DECEL_ON_KILL
            self.move_motion = None
            self.write_async(-1)

    def _start_move(self, motion, asynchronous: bool) -> None:
        self._stop_async_move()
        self._end_servo()
        if asynchronous:
            self.move_pending = (motion, self.now() + self.thread_start_delay)
        else:
            self.robot.motion = motion
            self.blocking = motion

    def _end_servo(self) -> None:
        if self.servo is not None and self.robot.motion is self.servo:
            self.robot.motion = None
        self.servo = None

    # ---- commands -------------------------------------------------------------------------------------
    def _realtime(self, cmd: int) -> None:
        if cmd == 11:  # servoj
            q, t, la, g = self.in_vec(0), self.in_double(8), self.in_double(9), self.in_double(10)
            if self.servo is None or self.robot.motion is not self.servo:
                self._stop_async_move()
                self.servo = ServoTrack(q, t, la, g)
                self.robot.motion = self.servo
            else:
                self.servo.update(q, t, la, g)

    def _process(self, cmd: int) -> None:
        r = self.robot
        if cmd == 1:  # movej
            q, v, a = self.in_vec(0), self.in_double(6), self.in_double(7)
            self._start_move(JointMove(r.q, q, v, a), self.in_int(1) == 1)
        elif cmd == 3:  # movel
            pose, v, a = self.in_vec(0), self.in_double(6), self.in_double(7)
            self._start_move(LinearMove(r, pose_to_T(pose), v, a), self.in_int(1) == 1)
        elif cmd in (33, 34):  # stopl / stopj
            decel, asynchronous = self.in_double(0), self.in_int(1) == 1
            self._stop_async_move()
            self._end_servo()
            moving = r.motion is not None
            if moving and hasattr(r.motion, "brake"):
                r.motion.brake = decel  # decelerate along the path
            elif moving:
                r.motion = Brake(decel)
            if moving and not asynchronous:
                self.blocking = r.motion
        elif cmd in (15, 16):  # speed_stop / servo_stop: stop the thread, brake with the given deceleration
            decel = self.in_double(0) or 10.0
            if self.servo is not None and r.motion is self.servo:
                r.motion = Brake(decel)
            self.servo = None
        elif cmd == 17:  # set_payload; a zero cog keeps the current one
            mass, cog = self.in_double(0), [self.in_double(1), self.in_double(2), self.in_double(3)]
            r.payload = mass
            if any(cog):
                r.payload_cog = cog
        elif cmd == 29:  # set_tcp
            r.tcp = pose_to_T(self.in_vec(0))
        elif cmd == 36:  # is_within_safety_limits(pose)
            self.out_int(1, 1 if r.within_safety_limits(self.in_vec(0)) else 0)
        elif cmd == 37:
            q = np.asarray(self.in_vec(0))
            ok = np.all(q >= np.asarray(r.model.joint_lower)) and np.all(q <= np.asarray(r.model.joint_upper))
            self.out_int(1, 1 if ok else 0)
        elif cmd == 40:  # get_tcp_offset
            for i, v in enumerate(T_to_pose(r.tcp)):
                self.out_double(i, v)
        elif cmd == 31:
            self.request_protective_stop = True
        # 255 (stop script) and anything else: nothing to do here
