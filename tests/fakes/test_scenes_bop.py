"""Random sink scenes and the BOP writer: plausible scenes, consistent ground truth."""

import json

import numpy as np
import pytest
from PIL import Image

from kitchenbot.executive.config import load_config
from kitchenbot.fakes.bop import generate_dataset
from kitchenbot.fakes.scenes import generate_scene
from kitchenbot.transforms import make_T, transform_points
from kitchenbot.world.inventory import Inventory


@pytest.fixture(scope="module")
def inventory():
    return Inventory.builtin()


def test_same_seed_same_scene(inventory):
    a, b = generate_scene(3, inventory), generate_scene(3, inventory)
    assert [o.model.name for o in a.objects.values()] == [o.model.name for o in b.objects.values()]
    for oa, ob in zip(a.objects.values(), b.objects.values()):
        assert np.allclose(oa.T_base_obj, ob.T_base_obj)


def test_interpenetration_check_detects_overlap(inventory):
    """The occupancy test below can fail: a cup pushed into a bowl's wall is caught."""
    import open3d as o3d

    bowl, cup = inventory.by_name("bowl"), inventory.by_name("cup")
    s = o3d.t.geometry.RaycastingScene()
    s.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(bowl.mesh))
    pts = transform_points(make_T(t=(0.03, 0, 0)), cup.points).astype(np.float32)
    occ = s.compute_occupancy(o3d.core.Tensor(pts)).numpy()
    sd = np.abs(s.compute_signed_distance(o3d.core.Tensor(pts)).numpy())
    assert ((occ > 0.5) & (sd > 0.001)).mean() > 0.01


def test_scenes_are_in_the_sink_and_do_not_interpenetrate(inventory):
    counts, styles = [], set()
    for seed in range(6):
        w = generate_scene(seed, inventory)
        styles.add(w.cell.spec.sink.style)
        counts.append(len(w.objects))
        lo, hi = w.cell.sink_interior
        for uid, o in w.objects.items():
            V = transform_points(o.T_base_obj, np.asarray(o.model.mesh.vertices))
            assert np.all(V[:, :2] > lo[:2] - 0.002) and np.all(V[:, :2] < hi[:2] + 0.002)
            assert V[:, 2].min() > lo[2] - 0.003
            # No other object's surface points lie inside this one's walls (occupancy by ray parity; walls
            # are 2.5-5 mm thick, so "inside by more than 1 mm" means interpenetration).
            others = np.vstack([transform_points(p.T_base_obj, p.model.points[::4])
                                for u, p in w.objects.items() if u != uid] or [np.zeros((0, 3))])
            if len(others) == 0:
                continue
            import open3d as o3d

            single = o3d.t.geometry.RaycastingScene()
            single.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(w.object_mesh(uid)))
            occ = single.compute_occupancy(o3d.core.Tensor(others.astype(np.float32))).numpy()
            sd = np.abs(single.compute_signed_distance(o3d.core.Tensor(others.astype(np.float32))).numpy())
            inside = (occ > 0.5) & (sd > 0.001)
            assert inside.mean() < 0.002, f"seed {seed}: objects interpenetrate"
    assert min(counts) >= 3 and max(counts) <= 10
    assert styles == {"stainless", "ceramic"}


def test_bop_ground_truth_projects_into_masks(tmp_path):
    cfg = load_config()
    kwargs = {"T_flange_tcp": cfg.robot.tool.T_flange_tcp.matrix(), "T_flange_cam": cfg.T_flange_cam()}
    stats = generate_dataset(tmp_path, 1, 5, [np.asarray(q) for q in cfg.scan_waypoints], kwargs, 320, 240)
    assert stats["images"] == 3
    inv = Inventory.load(tmp_path / "models", tmp_path / "models" / "grasps.json")
    assert len(inv) == 6 and inv.by_name("mug").cls == "mug"  # grasps are planning's, not the dataset's
    sd = tmp_path / "test" / "000000"
    cams = json.loads((sd / "scene_camera.json").read_text())
    gts = json.loads((sd / "scene_gt.json").read_text())
    infos = json.loads((sd / "scene_gt_info.json").read_text())
    checked = 0
    for im_id, recs in gts.items():
        K = np.array(cams[im_id]["cam_K"]).reshape(3, 3)
        depth = np.asarray(Image.open(sd / "depth" / f"{int(im_id):06d}.png")) * cams[im_id]["depth_scale"] / 1000.0
        for k, (rec, info) in enumerate(zip(recs, infos[im_id])):
            if info["visib_fract"] < 0.5:
                continue
            mask = np.asarray(Image.open(sd / "mask_visib" / f"{int(im_id):06d}_{k:06d}.png")) > 0
            T = make_T(np.array(rec["cam_R_m2c"]).reshape(3, 3), np.array(rec["cam_t_m2c"]) / 1000.0)
            pts = transform_points(T, inv[rec["obj_id"]].points)
            uv = (pts @ K.T)[:, :2] / pts[:, 2:3]
            u, v = np.round(uv[:, 0]).astype(int), np.round(uv[:, 1]).astype(int)
            ok = (u >= 0) & (u < 320) & (v >= 0) & (v < 240)
            # Points that are visible (not behind something): their depth matches the depth image.
            z = pts[ok, 2]
            d = depth[v[ok], u[ok]]
            front = (d > 0) & (np.abs(d - z) < 0.004)
            assert front.sum() > 20
            assert mask[v[ok][front], u[ok][front]].mean() > 0.95
            checked += 1
    assert checked >= 3

