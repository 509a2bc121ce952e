"""Where a run's compute goes: seconds per stage, not counting the time spent waiting for motions.

A stage is the state the runner is in (scan, select_grasp, plan, execute, verify, recover, ...), except while it
captures a view (``capture``: on real devices the camera's frame time, in simulation rendering the simulated
camera) or runs perception (``perceive``: every call of the perceiver, in whatever state). Waiting for a motion
is not compute (``MotionTracks.wall`` / ``.cpu`` say how long it was), so each stage's share is its wall time
minus the motion waits within it. CPU time (the process's, all threads) is kept beside wall time: on a loaded
machine wall time grows with the load, CPU time much less.

    st = StageTimes(motions)          # motions: anything with .wall and .cpu (seconds spent waiting for motions)
    st.enter("plan")                  # the runner's state changed
    with st.within("perceive"):       # a nested activity, back to the state's stage after it
        ...
    st.totals(), st.cpu_totals()      # seconds per stage so far (the open stage included)
"""

from __future__ import annotations

import time
from contextlib import contextmanager


class StageTimes:
    def __init__(self, motions, stage: str = "idle"):
        self._motions = motions
        self._wall: dict[str, float] = {}
        self._cpu: dict[str, float] = {}
        self._stage = stage
        self._mark = self._now()

    def _now(self) -> tuple[float, float, float, float]:
        return time.perf_counter(), time.process_time(), self._motions.wall, self._motions.cpu

    def _close(self) -> None:
        """Add the open stretch (since the last mark) to the current stage."""
        now = self._now()
        t0, c0, mw0, mc0 = self._mark
        self._wall[self._stage] = self._wall.get(self._stage, 0.0) + (now[0] - t0) - (now[2] - mw0)
        self._cpu[self._stage] = self._cpu.get(self._stage, 0.0) + (now[1] - c0) - (now[3] - mc0)
        self._mark = now

    @property
    def stage(self) -> str:
        return self._stage

    def enter(self, stage: str) -> None:
        """From now on the time counts for `stage`."""
        self._close()
        self._stage = stage

    @contextmanager
    def within(self, stage: str):
        """Count the block's time for `stage`, then go back to the stage before it."""
        before = self._stage
        self.enter(stage)
        try:
            yield
        finally:
            self.enter(before)

    def totals(self) -> dict[str, float]:
        """Compute wall seconds per stage so far."""
        self._close()
        return dict(self._wall)

    def cpu_totals(self) -> dict[str, float]:
        """Compute CPU seconds (process) per stage so far."""
        self._close()
        return dict(self._cpu)


def diff(now: dict[str, float], before: dict[str, float], digits: int = 4) -> dict[str, float]:
    """Per stage: `now` - `before` (stages with nothing spent left out)."""
    out = {k: round(v - before.get(k, 0.0), digits) for k, v in now.items()}
    return {k: v for k, v in out.items() if v > 0.0}
