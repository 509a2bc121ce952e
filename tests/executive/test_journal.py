"""The run journal: durable rows, interrupted runs found after a kill, no motion until homed."""

from __future__ import annotations

import os
import sqlite3
import subprocess
import sys

import pytest

from kitchenbot.executive.journal import HomingRequired, Journal


def test_pragmas_and_rows(tmp_path):
    j = Journal(tmp_path / "j.sqlite")
    assert j._db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    assert j._db.execute("PRAGMA synchronous").fetchone()[0] == 2  # FULL
    rid = j.begin_run("sink-pick", 3)
    j.event(rid, "transition", "start", "idle", source="idle", dest="scan")
    j.event(rid, "command", "arm.move_joints", "scan", q=[0.0] * 6, name="payload may use reserved words")
    j.end_run(rid, "succeeded", {"objects_done": 2})
    r = j.run(rid)
    assert (r.task, r.seed, r.status, r.report["objects_done"]) == ("sink-pick", 3, "succeeded", 2)
    ev = j.events(rid)
    assert [e["kind"] for e in ev] == ["transition", "command"]
    assert ev[1]["payload"]["name"] == "payload may use reserved words"
    # another connection (another process after a crash) sees everything already committed
    other = sqlite3.connect(str(tmp_path / "j.sqlite"))
    assert other.execute("SELECT COUNT(*) FROM events").fetchone()[0] == 2


CRASH = """
import os, sys
from kitchenbot.executive.journal import Journal
j = Journal(sys.argv[1])
rid = j.begin_run("sink-to-dishwasher", 1)
j.event(rid, "command", "arm.execute_trajectory", "execute", name="transfer")
os._exit(9)  # killed mid-motion: no end row
"""


def test_killed_run_is_reported_interrupted_and_blocks_motion_until_homed(tmp_path):
    path = tmp_path / "j.sqlite"
    p = subprocess.run([sys.executable, "-c", CRASH, str(path)], env=os.environ.copy())
    assert p.returncode == 9
    j = Journal(path)
    with pytest.raises(HomingRequired):
        j.require_homed()  # still "running" in the file
    interrupted = j.recover()
    assert [r.task for r in interrupted] == ["sink-to-dishwasher"] and interrupted[0].status == "interrupted"
    last = j.events(interrupted[0].id)[-2]
    assert last["name"] == "arm.execute_trajectory" and last["payload"]["name"] == "transfer"
    with pytest.raises(HomingRequired, match="homed"):
        j.begin_run("sink-pick", 0)
    assert j.recover() == []  # reported once
    j.mark_homed()
    rid = j.begin_run("sink-pick", 0)
    assert j.run(rid).status == "running"


def test_unsafe_end_requires_homing(tmp_path):
    j = Journal(tmp_path / "j.sqlite")
    rid = j.begin_run("cup-stacking", 0)
    j.end_run(rid, "failed", safe=False)
    assert not j.homed
    with pytest.raises(HomingRequired):
        j.require_homed()
