"""The inventory: closed dishware meshes, BOP round trip, clear errors for broken input."""

import json

import numpy as np
import pytest

from kitchenbot.world.inventory import GraspSpec, Inventory, InventoryError


@pytest.fixture(scope="module")
def inventory():
    return Inventory.builtin()


def test_builtin_dishware_is_closed_with_wall_thickness(inventory):
    names = {m.name for m in inventory}
    assert {"dinner_plate", "side_plate", "bowl", "cup", "mug", "glass"} <= names
    for m in inventory:
        assert m.mesh.is_watertight(), m.name
        assert m.mesh.get_volume() > 0, m.name
        # BOP object frame: bounding-box centre at the origin.
        bb = m.mesh.get_axis_aligned_bounding_box()
        assert np.allclose(bb.get_center(), 0, atol=1e-9)
        # Hollow: the solid volume is far below the bounding volume.
        assert m.mesh.get_volume() < 0.3 * np.prod(m.extents), m.name
        assert m.extents.max() - 1e-9 <= m.diameter <= np.linalg.norm(m.extents) + 1e-9
    assert inventory.by_name("mug").symmetries_continuous == []
    assert inventory.by_name("cup").symmetries_continuous


def test_symmetry_transforms_keep_a_round_item(inventory):
    cup = inventory.by_name("cup")
    from scipy.spatial import cKDTree

    tree = cKDTree(cup.points)
    for S in cup.symmetry_transforms(12)[1:]:
        moved = cup.points @ S[:3, :3].T + S[:3, 3]
        assert np.median(tree.query(moved)[0]) < 0.003


def test_bop_round_trip(tmp_path):
    inventory = Inventory.builtin()
    T = np.eye(4)
    T[:3, 3] = (0.01, 0.0, 0.02)
    inventory[1].grasps = [GraspSpec("rim_00", T, opening=0.03, width=0.005)]
    inventory.save_bop(tmp_path / "models", tmp_path / "models" / "grasps.json")
    info = json.loads((tmp_path / "models" / "models_info.json").read_text())
    assert info["1"]["diameter"] == pytest.approx(inventory[1].diameter * 1000)
    loaded = Inventory.load(tmp_path / "models", tmp_path / "models" / "grasps.json")
    for m in inventory:
        l2 = loaded[m.obj_id]
        assert l2.name == m.name and l2.cls == m.cls and len(l2.grasps) == len(m.grasps)
        assert np.allclose(l2.extents, m.extents, atol=1e-6)
        assert bool(l2.symmetries_continuous) == bool(m.symmetries_continuous)
        assert np.allclose(np.asarray(l2.mesh.vertices), np.asarray(m.mesh.vertices), atol=1e-6)
    g = loaded[1].grasps[0]
    assert (g.name, g.opening, g.width) == ("rim_00", 0.03, 0.005) and np.allclose(g.T_obj_tcp, T)
    # Without a grasps file the models still load (e.g. someone else's BOP dataset).
    bare = Inventory.load(tmp_path / "models")
    assert bare[1].name == "obj_000001" and bare[1].grasps == []


def test_broken_inputs_name_the_file(tmp_path, inventory):
    with pytest.raises(InventoryError, match="models_info.json"):
        Inventory.load(tmp_path)
    inventory.save_bop(tmp_path / "m")
    (tmp_path / "m" / "obj_000003.ply").unlink()
    with pytest.raises(InventoryError, match="obj_000003.ply"):
        Inventory.load(tmp_path / "m")
    (tmp_path / "m" / "obj_000003.ply").write_text("ply\nformat ascii 1.0\nend_header\n")
    with pytest.raises(InventoryError, match="obj_000003.ply"):
        Inventory.load(tmp_path / "m")
    inventory.save_bop(tmp_path / "m")
    g = tmp_path / "grasps.json"
    g.write_text(json.dumps({"units": "m", "objects": {"1": {"grasps": [{"name": "a", "opening": 0.05}]}}}))
    with pytest.raises(InventoryError, match=r"grasps\.json: objects\.1\.grasps\[0\]: missing key 'T_obj_tcp'"):
        Inventory.load(tmp_path / "m", g)
    g.write_text(json.dumps({"units": "m", "objects": {"1": {"grasps": [
        {"name": "a", "opening": 0.05, "width": 0.01, "T_obj_tcp": [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}]}}}))
    with pytest.raises(InventoryError, match="rigid transform"):
        Inventory.load(tmp_path / "m", g)


def test_grasp_names_parse_to_their_base_and_kind():
    from kitchenbot.world.inventory import grasp_base_name, grasp_kind, tilted_name

    tilted = tilted_name("rim_03", np.radians(15))
    assert tilted == "rim_03_tilt+15"
    assert grasp_base_name(tilted) == "rim_03" and grasp_base_name("rim_03") == "rim_03"
    assert grasp_kind(tilted) == grasp_kind("rim_11") == "rim"
    assert grasp_kind("ap01_05_tilt-15") == "ap01"
    assert grasp_kind("ap003") is None and grasp_kind("side_left") is None
