"""`kitchenbot run`: the diagram, input errors, the homing interlock and exit codes."""

from __future__ import annotations

import json

from kitchenbot.executive.cli import main
from kitchenbot.executive.journal import Journal, default_journal_path
from kitchenbot.executive.machine import mermaid


def test_diagram(capsys):
    assert main(["run", "--diagram"]) == 0
    assert capsys.readouterr().out.strip() == mermaid()


def test_missing_task_and_oracle_without_sim(capsys, state_dir, tmp_path):
    assert main(["run"]) == 2
    cfg = tmp_path / "real.yaml"
    cfg.write_text("drivers:\n  arm: {kind: ur_rtde, host: 127.0.0.1}\n")
    assert main(["run", "sink-pick", "--config", str(cfg), "--oracle-perception"]) == 2
    assert "needs the simulated cell" in capsys.readouterr().err


def test_interrupted_run_exit_code_then_home_then_run(capsys, state_dir, tmp_path):
    j = Journal(default_journal_path(True))
    j.begin_run("sink-pick", 0)  # never ended: the process died
    j.close()
    assert main(["run", "cup-stacking", "--sim", "--objects", "1", "--no-progress"]) == 4
    err = capsys.readouterr().err
    assert "interrupted" in err and "homed" in err
    assert main(["run", "home", "--sim"]) == 0
    report = tmp_path / "r.json"
    rc = main(["run", "cup-stacking", "--sim", "--seed", "2", "--objects", "1", "--oracle-perception",
               "--no-progress", "--report", str(report)])
    d = json.loads(report.read_text())
    assert rc == {"succeeded": 0, "failed": 1}[d["status"]] and d["perception"] == "oracle"
    assert d["task"] == "cup-stacking" and isinstance(d["transitions"], list)
