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


def test_interrupted_real_run_refuses_motion_until_homed(capsys, state_dir, tmp_path):
    """A real arm keeps the interlock: no motion (not even a connection attempt) until homed."""
    cfg = tmp_path / "real.yaml"
    cfg.write_text("drivers:\n  arm: {kind: ur_rtde, host: 127.0.0.1}\n")
    j = Journal(default_journal_path(False))
    j.begin_run("sink-pick", 0)  # never ended: the process died
    j.close()
    assert main(["run", "sink-pick", "--config", str(cfg), "--no-progress"]) == 4
    err = capsys.readouterr().err
    assert "interrupted" in err and "homed" in err
    assert not Journal(default_journal_path(False)).homed


def test_interrupted_sim_run_is_reported_then_a_fresh_cell_runs(capsys, state_dir, tmp_path):
    """A simulated cell is assembled fresh with its arm at home: the interrupted run is reported, the new one
    runs, and the journal records the homing."""
    j = Journal(default_journal_path(True))
    j.begin_run("sink-pick", 0)  # never ended: the process died
    j.close()
    report = tmp_path / "r.json"
    rc = main(["run", "cup-stacking", "--sim", "--seed", "2", "--objects", "1", "--oracle-perception",
               "--no-progress", "--report", str(report)])
    d = json.loads(report.read_text())
    assert rc == {"succeeded": 0, "failed": 1}[d["status"]] and d["perception"] == "oracle"
    assert d["task"] == "cup-stacking" and isinstance(d["transitions"], list)
    assert "interrupted" in capsys.readouterr().err
    assert Journal(default_journal_path(True)).homed
