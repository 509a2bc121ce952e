"""`kitchenbot config check [FILE]` / `kitchenbot config show [FILE]`."""

from __future__ import annotations

import argparse

import yaml


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("config", help="validate or print a cell configuration")
    p.add_argument("action", choices=["check", "show"])
    p.add_argument("file", nargs="?", help="config YAML (default: the shipped simulation config)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from kitchenbot.executive.config import load_config

    cfg = load_config(args.file)
    if args.action == "check":
        print(f"{cfg.source}: ok (robot {cfg.robot.model}, arm {cfg.drivers.arm.kind}, "
              f"gripper {cfg.drivers.gripper.kind}, camera {cfg.drivers.camera.kind})")
    else:
        print(yaml.safe_dump(cfg.model_dump(mode="json"), sort_keys=False))
    return 0
