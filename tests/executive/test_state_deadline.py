"""A state's timeout in simulation counts the runner's own compute (thread CPU time) and simulated motion time,
not wall time: a loaded host must not time out a state that a robot computer would finish."""

from __future__ import annotations

import threading
import types

import pytest

from kitchenbot.executive import runner as R
from kitchenbot.executive.failures import StateTimeout


class Clocks:
    def __init__(self):
        self.wall, self.cpu, self.sim = 100.0, 5.0, 0.0


@pytest.fixture
def clocks(monkeypatch):
    c = Clocks()
    monkeypatch.setattr(R.time, "perf_counter", lambda: c.wall)
    monkeypatch.setattr(R.time, "thread_time", lambda: c.cpu)
    return c


def _runner(c: Clocks, simulated: bool):
    ns = types.SimpleNamespace(_stop=threading.Event(), state="select_grasp",
                               clock=R.RunClock(state_t0=c.wall, state_sim0=c.sim if simulated else None,
                                                state_cpu0=c.cpu, deadline=10.0))
    ns._sim_now = lambda: c.sim if simulated else None
    return ns


def test_simulation_ignores_wall_time_spent_waiting_for_the_cpu(clocks):
    r = _runner(clocks, simulated=True)
    clocks.wall += 1000.0  # the host was busy with other work
    clocks.cpu += 2.0
    clocks.sim += 3.0
    R.TaskRunner._check_deadline(r)  # 5 s of the runner's compute and motion: within 10 s


def test_simulation_times_out_on_compute_plus_simulated_motion(clocks):
    r = _runner(clocks, simulated=True)
    clocks.cpu += 6.0
    clocks.sim += 5.0
    with pytest.raises(StateTimeout, match="select_grasp"):
        R.TaskRunner._check_deadline(r)


def test_real_devices_time_out_on_wall_time(clocks):
    r = _runner(clocks, simulated=False)
    clocks.wall += 10.5  # e.g. blocked on a device: no CPU spent, still too long
    with pytest.raises(StateTimeout):
        R.TaskRunner._check_deadline(r)
