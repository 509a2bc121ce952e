"""`kitchenbot bench tasks` prints a summary and writes per-run numbers (a one-scene smoke run)."""

from __future__ import annotations

import json

from kitchenbot.executive.cli import main


def test_bench_tasks_writes_summary(tmp_path, state_dir, capsys):
    out = tmp_path / "bench.json"
    assert main(["bench", "tasks", "--tasks", "cup-stacking", "--seeds", "1", "--start", "2", "--objects", "1",
                 "--oracle-perception", "--json", str(out)]) == 0
    d = json.loads(out.read_text())
    run = d["runs"][0]
    assert run["task"] == "cup-stacking" and run["perception"] == "oracle" and run["status"] in ("succeeded", "failed")
    s = d["summary"]["cup-stacking"]
    assert s["runs"] == 1 and s["wanted"] == run["wanted"] and s["placed"] == run["delivered"]
    assert s["collisions"] == (run["collisions"] or 0)
    assert "objects placed" in capsys.readouterr().out
