"""`kitchenbot doctor [--config FILE]`: check each configured device and say what to do when one fails.

Read-only: the UR arm is probed through RTDE receive + the dashboard server (no control script is uploaded,
nothing moves), the Dynamixel servo through PING and READs (no writes), the OAK-D by listing devices (it is not
booted). Fake devices are reported as simulated. Exit status 1 when a configured real device fails.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass

from kitchenbot.drivers.errors import DriverError


@dataclass
class DeviceReport:
    device: str  # arm | gripper | camera
    kind: str
    reachable: str  # "yes" | "no" | "simulated"
    model: str
    state: str
    fix: str = ""

    @property
    def failed(self) -> bool:
        return self.reachable == "no" or (self.reachable == "yes" and bool(self.fix))


def check_arm(cfg) -> DeviceReport:
    a = cfg.drivers.arm
    if a.kind == "fake":
        return DeviceReport("arm", "fake", "simulated", f"{cfg.robot.model} (simulated)", "fake arm over SimWorld")
    from kitchenbot.drivers.ur_rtde_arm import probe

    try:
        info = probe(a.host, a.frequency, timeout=a.connect_timeout)  # bounded on a silent or unreachable host
    except DriverError as e:
        return DeviceReport(
            "arm", a.kind, "no", "?", str(e),
            f"Power the controller, check drivers.arm.host ({a.host}) and the cable; `ping {a.host}`.",
        )  # fmt: skip
    fix = []
    if not info["streaming"]:
        fix.append("RTDE connected but its timestamp does not advance: restart the controller's RTDE service.")
    if info["safety"] != "normal":
        fix.append(f"Safety state is {info['safety']}: inspect the cell, then release/unlock on the pendant.")
    if info.get("remote_control") is False:  # None: PolyScope < 5.6 has no Remote Control mode to switch to
        fix.append("Switch the pendant to Remote Control so kitchenbot may upload its control script.")
    if "dashboard" in info:
        fix.append(f"Dashboard server {info['dashboard']}: enable it on the pendant (port 29999).")
    model = " ".join(x for x in (info.get("model"), info.get("polyscope")) if x) or "?"
    state = f"safety {info['safety']}, mode {info.get('robot_mode', '?')}, q {info['q']}"
    return DeviceReport("arm", a.kind, "yes", model, state, " ".join(fix))


def check_gripper(cfg) -> DeviceReport:
    g = cfg.drivers.gripper
    if g.kind == "fake":
        return DeviceReport("gripper", "fake", "simulated", "XM430 (simulated)", "fake Fin-Ray gripper over SimWorld")
    from kitchenbot.drivers.dynamixel_gripper import DynamixelGripper

    gripper = DynamixelGripper(
        g.port, g.baudrate, g.servo_id, closed_ticks=g.closed_ticks, open_ticks=g.open_ticks,
        max_opening=g.max_opening, current_limit_ma=g.current_limit_ma,
        min_packet_timeout_ms=max(100.0, g.min_packet_timeout_ms),
    )  # fmt: skip
    try:
        info = gripper.probe()
    except DriverError as e:
        if "another program has it open" in str(e):  # the port is opened exclusively: never talk over a run
            fix = f"Stop what holds {g.port} (a running kitchenbot or daemon, a Dynamixel Wizard), then run the doctor again."
        else:
            fix = (
                f"Plug in the U2D2 and 12 V supply; check drivers.gripper.port ({g.port}), baudrate ({g.baudrate}) "
                f"and servo_id ({g.servo_id}) with the Dynamixel Wizard."
            )
        return DeviceReport("gripper", g.kind, "no", "?", str(e), fix)
    fix = ""
    if info["hardware_error"]:
        fix = f"Hardware error '{info['hardware_error']}': remove the cause, then reboot the servo (gripper.reboot())."
    elif info["temperature_c"] >= gripper.temperature_warn_c:
        fix = "Servo is hot: let it cool before grasping."
    model = f"{info['model']} fw {info['firmware']}"
    state = (
        f"opening {info['opening_m'] * 1000:.1f} mm, torque {'on' if info['torque'] else 'off'}, "
        f"mode {info['operating_mode']}, {info['temperature_c']:.0f} degC, {info['voltage_v']:.1f} V"
    )
    return DeviceReport("gripper", g.kind, "yes", model, state, fix)


def check_camera(cfg) -> DeviceReport:
    c = cfg.drivers.camera
    if c.kind == "fake":
        return DeviceReport("camera", "fake", "simulated", "OAK-D-like (simulated)", f"raycast {c.width}x{c.height}")
    if c.kind == "replay":
        from kitchenbot.drivers.replay_camera import ReplayCamera

        folder = cfg.resolve_path(c.directory)
        cam = ReplayCamera(folder)
        try:
            cam.connect()
            first = cam.capture()
        except DriverError as e:
            return DeviceReport("camera", "replay", "no", "recording", str(e), f"Point drivers.camera.directory at a recording ({folder}).")
        w, h = first.size
        return DeviceReport("camera", "replay", "yes", "recording", f"{len(cam)} captures {w}x{h} in {folder}")
    from kitchenbot.drivers.oakd_camera import OakDCamera

    try:
        ids = OakDCamera.available_devices()
    except RuntimeError as e:
        ids, err = [], str(e)
    else:
        err = ""
    wanted = c.device_id
    if not ids or (wanted and wanted not in ids):
        from kitchenbot.drivers.oakd_camera import _no_device_message

        return DeviceReport(
            "camera", "oakd", "no", "?", err or _no_device_message(wanted, ids),
            "Plug the OAK-D into a USB3 port, install the udev rule, or fix drivers.camera.device_id.",
        )  # fmt: skip
    found = wanted or ids[0]
    return DeviceReport("camera", "oakd", "yes", f"OAK-D {found}", f"found, not booted ({c.width}x{c.height} @ {c.fps:g} fps)")


def run_checks(cfg) -> list[DeviceReport]:
    return [check_arm(cfg), check_gripper(cfg), check_camera(cfg)]


def print_reports(reports: list[DeviceReport], source: str) -> None:
    from rich.console import Console
    from rich.table import Table

    console = Console()
    if not console.is_terminal:
        console.width = 200  # logs and CI: room for the state column
    table = Table(title=f"kitchenbot doctor: {source}", show_lines=True)
    for col in ("device", "kind", "reachable", "model / firmware", "state", "what to do"):
        table.add_column(col, overflow="fold")
    colour = {"yes": "green", "no": "red", "simulated": "cyan"}
    for r in reports:
        reach = f"[{colour[r.reachable]}]{r.reachable}[/]"
        table.add_row(r.device, r.kind, reach, r.model, r.state, r.fix or ("-" if not r.failed else ""))
    console.print(table)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("doctor", help="check each configured device (arm, gripper, camera)")
    p.add_argument("--config", help="cell config YAML (default: the shipped simulation config)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from kitchenbot.executive.config import load_config

    cfg = load_config(args.config)
    reports = run_checks(cfg)
    print_reports(reports, cfg.source or "defaults")
    failed = [r for r in reports if r.failed]
    for r in failed:  # plain lines too: copyable, and never folded by the table
        print(f"{r.device} ({r.kind}): {r.state}")
        print(f"  what to do: {r.fix}")
    if failed:
        print(f"doctor: {', '.join(r.device for r in failed)} need attention")
        return 1
    print("doctor: all configured devices ok")
    return 0
