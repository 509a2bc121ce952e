"""`kitchenbot bench dynamixel`: round-trip times of the real dynamixel-sdk against the pty emulator, and how
long the DynamixelGripper takes to open and to grasp. Prints medians/p95 in milliseconds."""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path


def register(bs: argparse._SubParsersAction) -> None:
    p = bs.add_parser("dynamixel", help="dynamixel-sdk round trips and gripper open/grasp against the emulator")
    p.add_argument("--n", type=int, default=200, help="transactions per kind")
    p.add_argument("--report", type=Path)
    p.set_defaults(func=bench_dynamixel)


def _stats(samples: list[float]) -> dict:
    s = sorted(samples)
    return {
        "median_ms": round(statistics.median(s) * 1000, 3),
        "p95_ms": round(s[int(0.95 * (len(s) - 1))] * 1000, 3),
        "n": len(s),
    }


def bench_dynamixel(args: argparse.Namespace) -> int:
    from dynamixel_sdk import PacketHandler, PortHandler

    from kitchenbot.drivers.dynamixel_gripper import DxlPortHandler, DynamixelGripper
    from kitchenbot.fakes.dynamixel_emulator import DynamixelEmulator

    results: dict[str, dict] = {}
    with DynamixelEmulator(object_width=0.04) as emu:
        # The SDK's own PortHandler (busy-polls while waiting) and the driver's DxlPortHandler (select()).
        for label, port in (("sdk", PortHandler(emu.port)), ("dxl", DxlPortHandler(emu.port))):
            ph = PacketHandler(2.0)
            port.openPort()
            port.setBaudRate(57600)
            kinds = {
                "ping": lambda: ph.ping(port, 1),
                "read_present_25B": lambda: ph.readTxRx(port, 1, 122, 25),
                "write_goal_current": lambda: ph.write2ByteTxRx(port, 1, 102, 100),
            }
            for name, fn in kinds.items():
                samples, failures = [], 0
                cpu0 = time.process_time()
                for _ in range(args.n):
                    t0 = time.perf_counter()
                    out = fn()
                    samples.append(time.perf_counter() - t0)
                    failures += out[-2] != 0
                cpu = time.process_time() - cpu0
                results[f"{label}_{name}"] = {
                    **_stats(samples),
                    "failures": int(failures),
                    "client_cpu_per_wall": round(cpu / sum(samples), 2),
                }
            port.closePort()

        g = DynamixelGripper(emu.port, min_packet_timeout_ms=100)
        g.connect()
        opens, grasps = [], []
        for _ in range(5):
            t0 = time.perf_counter()
            g.open()
            opens.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            r = g.grasp(current_limit=0.5)
            grasps.append(time.perf_counter() - t0)
            assert r.holding, "the benchmark grasp should hold the 40 mm object"
        g.disconnect()
        results["gripper_open"] = _stats(opens)
        results["gripper_grasp_40mm"] = _stats(grasps)

    for name, r in results.items():
        extra = f"  failures {r['failures']}  client CPU/wall {r['client_cpu_per_wall']}" if "failures" in r else ""
        print(f"{name:26s} median {r['median_ms']:8.2f} ms   p95 {r['p95_ms']:8.2f} ms   n={r['n']}{extra}")
    if args.report:
        args.report.write_text(json.dumps(results, indent=1))
    return 0
