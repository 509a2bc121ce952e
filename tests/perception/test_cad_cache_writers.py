"""The CAD database's cache file: two processes saving the same entry at once both succeed."""

import os

import numpy as np

from kitchenbot.perception import database
from kitchenbot.perception.database import CadDatabase


def test_two_processes_saving_the_same_cache_entry_at_once_both_succeed(tmp_path, monkeypatch):
    """Process A has written its temporary file when process B (another pid) saves the same entry and renames
    its file into place; A's rename must still find its own file (with one shared temporary name, B had taken it:
    FileNotFoundError, a failed perceive in a benchmark that started the three tasks at once)."""
    path = tmp_path / "cad_0123456789abcdef.npz"
    db = CadDatabase({}, "0123456789abcdef")
    save = np.savez_compressed
    pid = os.getpid()
    nested = []

    def save_then_other_process_saves(file, *args, **kwargs):
        save(file, *args, **kwargs)
        if not nested:  # while A is between its write and its rename, B (pid + 1) saves the same entry
            nested.append(1)
            monkeypatch.setattr(os, "getpid", lambda: pid + 1)
            db._save(path)
            monkeypatch.setattr(os, "getpid", lambda: pid)

    monkeypatch.setattr(database.np, "savez_compressed", save_then_other_process_saves)
    db._save(path)
    assert nested and path.is_file()
    assert CadDatabase._load(path, db.key).entries == {}
    assert sorted(p.name for p in tmp_path.iterdir()) == [path.name]  # no temporary file left behind
