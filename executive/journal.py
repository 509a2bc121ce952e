"""The run journal: SQLite (WAL, synchronous=FULL), written BEFORE the executive acts.

Every run, state transition, device command and its result is a row committed to disk before the action it
describes is taken (write-ahead), so after a crash or a kill the last rows say what the robot was doing.
A run that has no end row is *interrupted*: on the next start :meth:`Journal.recover` marks it so and the
journal refuses motion (:meth:`require_homed`) until an explicit home action succeeds (:meth:`mark_homed`).

Written on the standard library's sqlite3: nothing else is needed for an append-only log with one writer.
"""

from __future__ import annotations

import json
import os
import sqlite3
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

SCHEMA = """
CREATE TABLE IF NOT EXISTS runs (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    task TEXT NOT NULL,
    seed INTEGER,
    started REAL NOT NULL,
    ended REAL,
    status TEXT NOT NULL DEFAULT 'running',
    report TEXT
);
CREATE TABLE IF NOT EXISTS events (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    run_id INTEGER,
    t REAL NOT NULL,
    kind TEXT NOT NULL,
    state TEXT,
    name TEXT NOT NULL,
    payload TEXT
);
CREATE TABLE IF NOT EXISTS robot (
    key TEXT PRIMARY KEY,
    value TEXT NOT NULL
);
"""


class HomingRequired(RuntimeError):
    """A previous run was interrupted (crash/kill): no motion is accepted until the arm is homed."""


@dataclass
class RunRecord:
    id: int
    task: str
    seed: int | None
    started: float
    ended: float | None
    status: str
    report: dict | None

    def as_dict(self) -> dict:
        return {"id": self.id, "task": self.task, "seed": self.seed, "started": self.started,
                "ended": self.ended, "status": self.status, "report": self.report}


def _json(obj: Any) -> str:
    return json.dumps(obj, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o))


class Journal:
    """One SQLite file; safe to share between the daemon's threads (one connection, a lock)."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._lock = threading.RLock()
        self._db = sqlite3.connect(str(self.path), check_same_thread=False, isolation_level=None)
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.execute("PRAGMA synchronous=FULL")
        self._db.executescript(SCHEMA)

    def close(self) -> None:
        with self._lock:
            self._db.close()

    # ---- writes (each one committed before returning) -----------------------------------------------------
    def _write(self, sql: str, args: tuple) -> int:
        with self._lock:
            cur = self._db.execute(sql, args)  # autocommit: durable on return (synchronous=FULL)
            return int(cur.lastrowid)

    def begin_run(self, task: str, seed: int | None) -> int:
        self.require_homed()
        run_id = self._write("INSERT INTO runs(task, seed, started) VALUES (?, ?, ?)", (task, seed, time.time()))
        self._set("homed", "0")  # the arm may leave a known pose from here on
        return run_id

    def end_run(self, run_id: int, status: str, report: dict | None = None, safe: bool = True) -> None:
        """Close a run. `safe`: the arm ended at a known safe pose (else homing is required first)."""
        with self._lock:
            self._db.execute("UPDATE runs SET ended=?, status=?, report=? WHERE id=?",
                             (time.time(), status, _json(report) if report is not None else None, run_id))
            if safe:
                self._set("homed", "1")

    def event(self, run_id: int | None, kind: str, name: str, state: str | None = None, /, **payload: Any) -> int:
        """kind: transition | command | result | fault | note."""
        return self._write("INSERT INTO events(run_id, t, kind, state, name, payload) VALUES (?, ?, ?, ?, ?, ?)",
                           (run_id, time.time(), kind, state, name, _json(payload) if payload else None))

    def _set(self, key: str, value: str) -> None:
        self._write("INSERT INTO robot(key, value) VALUES (?, ?) ON CONFLICT(key) DO UPDATE SET value=excluded.value",
                    (key, value))

    # ---- crash recovery ------------------------------------------------------------------------------------
    def recover(self) -> list[RunRecord]:
        """Mark runs without an end as interrupted (call once at start-up); returns them."""
        with self._lock:
            open_runs = self.runs(status="running")
            for r in open_runs:
                self._db.execute("UPDATE runs SET status='interrupted', ended=? WHERE id=?", (time.time(), r.id))
                self._db.execute(
                    "INSERT INTO events(run_id, t, kind, state, name, payload) VALUES (?, ?, 'note', NULL, ?, NULL)",
                    (r.id, time.time(), "interrupted: found without an end on restart; homing required"))
            if open_runs:
                self._set("homed", "0")
            return [self.run(r.id) for r in open_runs]

    @property
    def homed(self) -> bool:
        with self._lock:
            row = self._db.execute("SELECT value FROM robot WHERE key='homed'").fetchone()
        return row is None or row[0] == "1"

    def require_homed(self) -> None:
        with self._lock:
            running = self._db.execute("SELECT id FROM runs WHERE status='running'").fetchall()
        if running:
            raise HomingRequired(f"run {running[0][0]} has no end in the journal {self.path} (crashed or still "
                                 "running elsewhere); restart to mark it interrupted, then home the arm")
        if not self.homed:
            raise HomingRequired(f"the last run was interrupted (journal {self.path}); no motion until the arm is "
                                 "homed: `kitchenbot run home` or POST /home")

    def mark_homed(self) -> None:
        self.event(None, "result", "homed")
        self._set("homed", "1")

    # ---- reads ------------------------------------------------------------------------------------------------
    def runs(self, status: str | None = None, limit: int = 1000) -> list[RunRecord]:
        sql = "SELECT id, task, seed, started, ended, status, report FROM runs"
        args: tuple = ()
        if status:
            sql += " WHERE status=?"
            args = (status,)
        sql += " ORDER BY id DESC LIMIT ?"
        with self._lock:
            rows = self._db.execute(sql, args + (limit,)).fetchall()
        return [RunRecord(r[0], r[1], r[2], r[3], r[4], r[5], json.loads(r[6]) if r[6] else None) for r in rows]

    def run(self, run_id: int) -> RunRecord | None:
        with self._lock:
            r = self._db.execute("SELECT id, task, seed, started, ended, status, report FROM runs WHERE id=?",
                                 (run_id,)).fetchone()
        return RunRecord(r[0], r[1], r[2], r[3], r[4], r[5], json.loads(r[6]) if r[6] else None) if r else None

    def events(self, run_id: int | None = None, kind: str | None = None) -> list[dict]:
        sql, args, cond = "SELECT id, run_id, t, kind, state, name, payload FROM events", [], []
        if run_id is not None:
            cond.append("run_id=?")
            args.append(run_id)
        if kind is not None:
            cond.append("kind=?")
            args.append(kind)
        if cond:
            sql += " WHERE " + " AND ".join(cond)
        with self._lock:
            rows = self._db.execute(sql + " ORDER BY id", args).fetchall()
        return [{"id": r[0], "run_id": r[1], "t": r[2], "kind": r[3], "state": r[4], "name": r[5],
                 "payload": json.loads(r[6]) if r[6] else {}} for r in rows]


def default_journal_path(sim: bool) -> Path:
    """`$KITCHENBOT_STATE_DIR` (default ~/.local/state/kitchenbot)/journal[-sim].sqlite: simulated runs keep
    their own journal so a crashed simulation never blocks the real arm, and vice versa."""
    base = Path(os.environ.get("KITCHENBOT_STATE_DIR", Path.home() / ".local" / "state" / "kitchenbot"))
    return base / ("journal-sim.sqlite" if sim else "journal.sqlite")
