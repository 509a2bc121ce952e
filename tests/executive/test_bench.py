"""`kitchenbot bench tasks` prints a summary and writes per-run numbers (a one-scene smoke run)."""

from __future__ import annotations

import json

import pytest

from kitchenbot.executive.cli import main


def test_bench_tasks_writes_summary(tmp_path, state_dir, capsys):
    out = tmp_path / "bench.json"
    assert main(["bench", "tasks", "--tasks", "cup-stacking", "--seeds", "1", "--start", "0", "--objects", "1",
                 "--oracle-perception", "--json", str(out)]) == 0
    d = json.loads(out.read_text())
    run = d["runs"][0]
    assert run["task"] == "cup-stacking" and run["perception"] == "oracle" and run["status"] in ("succeeded", "failed")
    s = d["summary"]["cup-stacking"]
    assert s["runs"] == 1 and s["wanted"] == run["wanted"] and s["placed"] == run["delivered"]
    assert s["collisions"] == (run["collisions"] or 0)
    assert s["protective_stops"] == (run["protective_stops"] or 0)
    # (scene 0 with one object: one cup) the strategies of the run, summed: every attempt was planned by one
    assert s["strategies"] == run["strategies"] and "direct_pick" in s["strategies"]
    assert sum(c["planned"] for c in s["strategies"].values()) >= run["attempts"]
    out = capsys.readouterr().out
    assert "objects placed" in out and "strategies (cup-stacking; planned/tried): direct_pick" in out
    # items per minute: placed (truth) per minute of simulated time plus compute, and compute split by stage
    assert s["items_per_minute"] == pytest.approx(60.0 * run["delivered"] / (run["sim_s"] + run["compute_s"]))
    assert "items per minute (cup-stacking)" in out and "compute per cycle by stage (cup-stacking" in out
    if run["delivered"]:
        assert set(s["cycle_stage_means_s"]) >= {"plan", "execute"}


def test_robot_cpu_per_cycle_leaves_out_the_simulated_camera_only():
    from kitchenbot.bench.tasks import robot_cpu_per_cycle
    runs = [{"compute_cpu_per_cycle_s": [2.0, None, 1.0],
             "cycle_stages_cpu_s": [{"capture": 0.5, "plan": 1.0, "perceive": 0.5}, {}, {"plan": 1.0}]},
            {"compute_cpu_per_cycle_s": [3.0], "cycle_stages_cpu_s": [{"capture": 0.25}]}]
    assert robot_cpu_per_cycle(runs) == pytest.approx([1.5, 1.0, 2.75])
    assert robot_cpu_per_cycle([{}]) == []
