"""`kitchenbot eval` on the real-frame sets (scripts/extract_real_frames.py) under tests/data/real/ or
$KITCHENBOT_REAL_DATA: it runs, reports every dishware object, and counts poses on the other objects.

The floor for each set is its `floor.json` ({"adi_recall_0.1d": x, "max_false_positives_on_distractors": n}),
set from what the pipeline achieves when the set is added; without one the test checks that eval runs and
reports per-object results. Skipped, saying so, when no set is present (none is committed yet: see
docs/perception.md, "Real frames")."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from kitchenbot.executive.cli import main

ROOT = Path(os.environ.get("KITCHENBOT_REAL_DATA", Path(__file__).resolve().parents[1] / "data" / "real"))
SETS = sorted(p for p in ROOT.glob("*") if (p / "models" / "models_info.json").is_file()) if ROOT.is_dir() else []


@pytest.mark.skipif(not SETS, reason=f"no real-frame sets under {ROOT} (docs/perception.md, 'Real frames')")
@pytest.mark.parametrize("dataset", SETS, ids=[p.name for p in SETS])
def test_eval_on_real_frames(dataset, tmp_path, monkeypatch):
    monkeypatch.setenv("HOME", str(tmp_path))
    names = json.loads((dataset / "models" / "grasps.json").read_text())["objects"]
    dishware = sorted(int(k) for k, v in names.items() if v.get("class") != "distractor")
    assert dishware, f"{dataset}: no dishware in models/grasps.json"
    rep = tmp_path / "r.json"
    rc = main(["eval", str(dataset), "--objects", *map(str, dishware), "--cell", "never", "--report", str(rep),
               "--no-progress"])
    assert rc == 0
    r = json.loads(rep.read_text())
    assert r["inventory"] == dishware and r["images"] >= 1
    assert set(r["per_object"]) <= {str(d) for d in dishware}
    assert r["objects"] >= 1  # the dishware was in view and evaluated
    floor = json.loads((dataset / "floor.json").read_text()) if (dataset / "floor.json").is_file() else {}
    assert r["adi_recall_0.1d"] >= floor.get("adi_recall_0.1d", 0.0), r["per_object"]
    assert r["false_positives_on_distractors"] <= floor.get("max_false_positives_on_distractors", 10**6), \
        r["false_positives_on_distractors_by_name"]
