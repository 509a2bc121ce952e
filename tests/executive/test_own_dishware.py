"""Bring your own dishware: a BOP models/ folder with only meshes and models_info.json (dishware this project has
never seen, made in tests/conftest.py) runs a task end to end in the simulator: classes from the meshes' shapes,
grasps synthesised from them, scenes generated from that inventory."""

from __future__ import annotations

from kitchenbot.executive.config import InventoryConfig, load_config
from kitchenbot.executive.runner import run_task


def test_sink_pick_places_dishware_it_has_never_seen(own_dishware, tmp_path, state_dir):
    folder, _ = own_dishware
    cfg = load_config()
    cfg = cfg.model_copy(update={"inventory": InventoryConfig(models_dir=str(folder))})
    cfg.planning.grasp_cache_dir = str(tmp_path / "grasps")
    cfg.sim.min_objects = cfg.sim.max_objects = 3
    cfg.scan_waypoints = cfg.scan_waypoints[:1]
    rep = run_task(cfg, "sink-pick", 5, progress=False, oracle_perception=True, journal_path=False)
    assert rep.truth["start"]["in_sink"] == 3
    assert rep.truth["end"]["delivered"] == 3 and rep.truth["end"]["in_sink"] == 0, rep.message
    assert rep.collisions == 0 and rep.limit_violations == 0
    assert len(list((tmp_path / "grasps").glob("grasps_*.json"))) >= 1  # synthesised, and cached


def test_inventory_command_lists_classes_and_grasps(own_dishware, tmp_path, capsys):
    from kitchenbot.executive.cli import main

    folder, _ = own_dishware
    cfg = tmp_path / "cell.yaml"
    cfg.write_text(f"inventory:\n  models_dir: {folder}\n  classes: {{2: cup}}\n"
                   f"planning:\n  grasp_cache_dir: {tmp_path / 'grasps'}\n")
    assert main(["inventory", "--config", str(cfg)]) == 0
    out = capsys.readouterr().out.splitlines()
    rows = {int(line.split()[0]): line.split() for line in out[1:]}
    assert {k: r[2] for k, r in rows.items()} == {1: "plate", 2: "cup", 3: "mug", 4: "bowl"}
    assert rows[2][3] == "(config;" and rows[1][3] == "(shape;"
    assert all(int(r[r.index("grasps") - 1]) > 0 for r in rows.values())
