"""A daemon on a small simulated cell for the operator page's browser tests (test_operator_page.py).

    python operator_sim_daemon.py PORT STATE_DIR        (token from KITCHENBOT_TOKEN)

The cell: seed 0's sink reduced to one cup (conftest._cup_world), one scan waypoint, oracle perception; so a run
takes seconds. Runs of ``sink-pick`` are *held*: the simulated clock stops at the first motion of their first
execute state (the grasp is planned and drawn, the arm is on its way) until STOP, so a test finds the run still
running whatever the machine's speed, and a kill -9 always lands mid-run. Other tasks run freely.
"""

from __future__ import annotations

import os
import sys
import threading
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

from conftest import _cup_world, _small_config  # noqa: E402

from kitchenbot.executive.assembly import assemble  # noqa: E402
from kitchenbot.executive.daemon import create_app  # noqa: E402
from kitchenbot.executive.journal import Journal  # noqa: E402
from kitchenbot.executive.session import build_runner  # noqa: E402

HELD_TASK = "sink-pick"


def hold_in_execute(runner) -> None:
    """Stop the simulated clock at the first motion of the execute state until a stop is requested."""
    tick, stop = runner.advance, runner.request_stop
    stopped = threading.Event()

    def request_stop() -> None:
        stopped.set()  # release the held tick first: request_stop waits for the arm lock the tick holds
        stop()

    def advance(dt: float) -> None:
        if runner.state == "execute":
            stopped.wait()
        tick(dt)

    runner.advance, runner.request_stop = advance, request_stop


def main() -> None:
    port, state_dir = int(sys.argv[1]), Path(sys.argv[2])
    import uvicorn

    cfg = _small_config(waypoints=1)
    journal = Journal(state_dir / "journal-sim.sqlite")

    def factory(task, seed, oracle):
        robot = assemble(cfg, world=_cup_world(cfg, 1))
        runner = build_runner(cfg, task, 0, robot=robot, oracle_perception=True, journal=journal)
        if task == HELD_TASK:
            hold_in_execute(runner)
        return runner

    app = create_app(cfg, token=os.environ["KITCHENBOT_TOKEN"], journal=journal, runner_factory=factory)
    uvicorn.run(app, host="127.0.0.1", port=port, log_level="warning")


if __name__ == "__main__":
    main()
