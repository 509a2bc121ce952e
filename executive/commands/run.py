"""`kitchenbot run TASK [--sim] [--seed N] [--config FILE] [--report FILE.json] [--record FILE.rrd]`.

TASK is one of the tasks (sink-pick, sink-to-dishwasher, cup-stacking) or `home` (the explicit home action
that clears the journal's homing requirement after an interrupted run). `--diagram` prints the state machine.
Exit codes: 0 succeeded, 1 failed, 3 stopped, 4 homing required, 5 homing failed, 2 bad input.
"""

from __future__ import annotations

import argparse
import sys

TASK_NAMES = ["sink-pick", "sink-to-dishwasher", "cup-stacking"]


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("run", help="run a task (or `home`) on the configured cell")
    p.add_argument("task", nargs="?", choices=TASK_NAMES + ["home"], help="what to do")
    p.add_argument("--sim", action="store_true", help="use the simulated cell (fake drivers) whatever the config says")
    p.add_argument("--seed", type=int, default=None, help="simulated scene seed (default: config sim.seed)")
    p.add_argument("--config", help="cell config YAML (default: the shipped simulation config)")
    p.add_argument("--report", help="write the run report JSON here")
    p.add_argument("--record", help="write a rerun recording (.rrd) here")
    p.add_argument("--dataset", help="append every scan as a BOP scene under this folder "
                                     "(default for real runs: $KITCHENBOT_STATE_DIR/dataset)")
    p.add_argument("--journal", help="run journal SQLite file (default: $KITCHENBOT_STATE_DIR/journal[-sim].sqlite)")
    p.add_argument("--oracle-perception", action="store_true",
                   help="simulation only: take object poses from the simulator's truth (labelled in the report)")
    p.add_argument("--objects", type=int, default=None, help="simulation: exactly this many objects in the sink")
    p.add_argument("--no-progress", action="store_true", help="no live progress view")
    p.add_argument("--diagram", action="store_true", help="print the state machine as mermaid and exit")
    p.set_defaults(func=run)


def load_run_config(args):
    from kitchenbot.executive.config import DriversConfig, load_config

    cfg = load_config(args.config)
    if args.sim:
        cfg = cfg.model_copy(update={"drivers": DriversConfig()})
    if getattr(args, "objects", None) is not None:
        cfg.sim.min_objects = cfg.sim.max_objects = args.objects
    return cfg


def run(args: argparse.Namespace) -> int:
    from kitchenbot.executive.machine import mermaid

    if args.diagram:
        print(mermaid())
        return 0
    if not args.task:
        print("kitchenbot run: error: TASK is required (or --diagram)", file=sys.stderr)
        return 2
    from rich.console import Console

    from kitchenbot.executive.journal import HomingRequired, default_journal_path
    from kitchenbot.executive.session import is_simulated, open_journal

    console = Console(stderr=True)
    cfg = load_run_config(args)
    sim = is_simulated(cfg)
    journal = open_journal(cfg, args.journal)
    for r in journal.recover():
        then = ("a new simulated cell starts with its arm at home" if sim else
                "the arm must be homed before any motion: `kitchenbot run home`")
        console.print(f"[yellow]run {r.id} ({r.task}) was interrupted[/yellow] (no end in the journal): {then}")
    if args.task == "home":
        return _home(cfg, args, journal, console)
    if args.oracle_perception and not sim:
        print("kitchenbot run: error: --oracle-perception needs the simulated cell (--sim)", file=sys.stderr)
        return 2
    from kitchenbot.executive.progress import print_summary
    from kitchenbot.executive.runner import run_task

    dataset = args.dataset
    if dataset is None and not sim:
        dataset = default_journal_path(False).parent / "dataset"
    try:
        if not sim:  # a simulated cell is assembled fresh, at home (build_runner journals that)
            journal.require_homed()
        report = run_task(cfg, args.task, args.seed, report_path=args.report, record_path=args.record,
                          progress=not args.no_progress and sys.stderr.isatty(),
                          oracle_perception=args.oracle_perception, journal_path=journal.path, dataset_dir=dataset)
    except HomingRequired as e:
        console.print(f"[red]refused:[/red] {e}")
        return 4
    print_summary(report, Console())
    if args.oracle_perception:
        console.print("[yellow]note: oracle perception (simulator truth), not the perception pipeline[/yellow]")
    return {"succeeded": 0, "stopped": 3}.get(report.status, 1)


def _home(cfg, args, journal, console) -> int:
    from kitchenbot.executive.assembly import assemble
    from kitchenbot.executive.runner import home_arm
    from kitchenbot.executive.session import is_simulated
    from kitchenbot.planning.pick_place import Planner

    from kitchenbot.drivers.errors import DriverError

    robot = assemble(cfg, args.seed)
    planner = Planner.from_config(cfg, robot.inventory)
    try:
        robot.connect()
        home_arm(robot, planner, journal, advance=robot.arm.step if is_simulated(cfg) else None)
    except (DriverError, RuntimeError) as e:
        console.print(f"[red]homing failed[/red]: {type(e).__name__}: {e}; motion stays refused")
        return 5
    finally:
        robot.disconnect()
    console.print("[green]homed[/green]: motion is accepted again")
    return 0
