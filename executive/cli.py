"""`kitchenbot` command line. Each subcommand lives in ``executive/commands/<name>.py`` and exposes
``register(subparsers)``; this file only assembles them, so one command's imports never slow another."""

from __future__ import annotations

import argparse
import importlib
import sys

# Order shown in --help. A module that does not exist yet is simply not offered.
COMMANDS = ["run", "demo", "scenes", "eval", "bench", "calibrate", "daemon", "doctor", "models", "inventory", "config", "docs"]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="kitchenbot",
        description="Clear dishware from a kitchen sink with a UR arm, a Fin-Ray gripper and a wrist RGB-D camera.",
    )
    from kitchenbot import __version__

    parser.add_argument("--version", action="version", version=f"kitchenbot {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        try:
            module = importlib.import_module(f"kitchenbot.executive.commands.{name}")
        except ModuleNotFoundError as e:
            if e.name == f"kitchenbot.executive.commands.{name}":
                continue
            raise
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except Exception as e:  # noqa: BLE001 - the CLI's last line of defence: a message, not a traceback
        from kitchenbot.executive.config import ConfigError

        if isinstance(e, (ConfigError, FileNotFoundError, ValueError)) and not getattr(args, "debug", False):
            print(f"kitchenbot {args.command}: error: {e}", file=sys.stderr)
            return 2
        raise


if __name__ == "__main__":
    sys.exit(main())
