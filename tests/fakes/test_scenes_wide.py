"""The wide generator: distractors with their own ground truth, sink fixtures that render and bear weight,
the second camera's intrinsics used for rendering, parametric dishware, and defaults that stay as they were."""

import json

import numpy as np
import pytest
from PIL import Image

from kitchenbot.executive.config import load_config
from kitchenbot.fakes.bop import generate_dataset
from kitchenbot.fakes.cameras import camera_model
from kitchenbot.fakes.dish_families import FAMILIES, sample_dishware
from kitchenbot.fakes.placement import settle
from kitchenbot.fakes.render import oakd_intrinsics, render
from kitchenbot.fakes.sink_fixtures import drain, faucet, rounded_corners
from kitchenbot.fakes.world import SimWorld
from kitchenbot.world.cell import Cell
from kitchenbot.world.inventory import Inventory
from kitchenbot.transforms import make_T, rot_x, transform_points


@pytest.fixture(scope="module")
def inventory():
    return Inventory.builtin()


def _kwargs():
    cfg = load_config()
    return cfg, {"T_flange_tcp": cfg.robot.tool.T_flange_tcp.matrix(), "T_flange_cam": cfg.T_flange_cam()}


def _looking_down(x, y, z):
    return make_T(rot_x(np.pi)[:3, :3], (x, y, z))


def test_a_distractor_appears_in_the_ground_truth_and_the_depth(tmp_path):
    cfg, kw = _kwargs()
    stats = generate_dataset(tmp_path, 1, 3, [np.asarray(cfg.scan_waypoints[1])], kw, 640, 480, distractors=2)
    assert stats["distractors"] == 2
    scene = tmp_path / "test" / "000000"
    gt = json.loads((scene / "scene_gt.json").read_text())["0"]
    info = json.loads((scene / "scene_gt_info.json").read_text())["0"]
    cam = json.loads((scene / "scene_camera.json").read_text())["0"]
    inv_ids = set(int(k) for k in json.loads((tmp_path / "models" / "models_info.json").read_text()))
    d_info = json.loads((tmp_path / "models_distractors" / "models_info.json").read_text())
    dis = [k for k, g in enumerate(gt) if g["obj_id"] not in inv_ids]
    assert len(dis) == 2 and all(str(gt[k]["obj_id"]) in d_info for k in dis)
    depth = np.asarray(Image.open(scene / "depth" / "000000.png"), np.float32) * cam["depth_scale"]  # mm
    K = np.asarray(cam["cam_K"]).reshape(3, 3)
    seen = 0
    for k in dis:
        mask = np.asarray(Image.open(scene / "mask_visib" / f"000000_{k:06d}.png")) > 0
        if info[k]["visib_fract"] < 0.1:
            continue
        seen += 1
        # Its depth pixels are where its model is: the posed model's depth range brackets the measured depth.
        T = make_T(np.asarray(gt[k]["cam_R_m2c"]).reshape(3, 3), np.asarray(gt[k]["cam_t_m2c"]) / 1000)
        ply = tmp_path / "models_distractors" / f"obj_{gt[k]['obj_id']:06d}.ply"
        import open3d as o3d
        from scipy.spatial import cKDTree

        o3d.utility.random.seed(1)
        surf = np.asarray(o3d.io.read_triangle_mesh(str(ply)).sample_points_uniformly(20000).points) / 1000
        surf = transform_points(T, surf)
        # Its depth pixels, back-projected, lie on its posed model: ground truth and depth agree.
        ys, xs = np.nonzero(mask & (depth > 0))
        assert len(xs) > 50
        z = depth[ys, xs] / 1000
        P = np.column_stack([(xs - K[0, 2]) * z / K[0, 0], (ys - K[1, 2]) * z / K[1, 1], z])
        dist, _ = cKDTree(surf).query(P)
        assert np.median(dist) < 0.004 and np.mean(dist < 0.01) > 0.9
    assert seen >= 1
    targets = json.loads((tmp_path / "test_targets_bop19.json").read_text())
    assert targets and all(t["obj_id"] in inv_ids for t in targets)  # distractors are not targets


def test_rounded_corners_render_and_bear_weight(inventory):
    plain = SimWorld(Cell(), inventory)
    rounded = SimWorld(Cell(), inventory)
    for fx in rounded_corners(rounded.cell, 0.05, (0.7, 0.7, 0.7)):
        rounded.add_fixture(fx)
    (x0, y0, z0), _ = plain.cell.sink_interior
    K = oakd_intrinsics()
    T = _looking_down(x0 + 0.05, y0 + 0.05, 0.3)  # above the basin's corner
    a, b = render(plain, K, T, 640, 480), render(rounded, K, T, 640, 480)
    # Right below the camera, 5 cm from both walls: the floor in both basins.
    f = K[0, 0] / (0.3 - z0)  # pixels per metre on the floor
    assert np.allclose(a.depth[236:244, 316:324], 0.3 - z0, atol=1e-3)
    assert np.allclose(b.depth[236:244, 316:324], 0.3 - z0, atol=1e-3)
    # 1 cm from the wall at x0, level with the camera: the floor fillet's circular profile, 2 cm up.
    u = int(round(319.5 - 0.04 * f))
    h = 0.05 - np.sqrt(0.05**2 - (0.05 - (0.05 - (319.5 - u) / f)) ** 2)
    assert a.depth[240, u] == pytest.approx(0.3 - z0, abs=1e-3)
    assert b.depth[240, u] == pytest.approx(0.3 - z0 - h, abs=2e-3) and h > 0.015
    # Straight down 5 mm from both walls: inside the vertical fillet, whose top is level with the counter.
    T2 = _looking_down(x0 + 0.005, y0 + 0.005, 0.3)
    a2, b2 = render(plain, K, T2, 640, 480), render(rounded, K, T2, 640, 480)
    assert a2.depth[240, 320] == pytest.approx(0.3 - z0, abs=1e-3)
    assert b2.depth[240, 320] == pytest.approx(0.3, abs=1e-3)
    assert np.all(b.labels == 0)
    # A cup put down in the corner rests on the fillet, higher than on the plain floor.
    cup = inventory.by_name("cup")
    start = make_T(t=(x0 + 0.045, y0 + 0.045, 0.1))
    zs = []
    for w in (plain, rounded):
        uid = w.add_object(cup, start)
        zs.append(settle(w, uid, start, keep_inside=w.cell.sink_interior)[2, 3])
    assert zs[1] > zs[0] + 0.003


def test_faucet_and_drain_are_seen(inventory):
    w = SimWorld(Cell(), inventory)
    (x0, y0, z0), (x1, y1, _) = w.cell.sink_interior
    for fx in drain(w.cell, ((x0 + x1) / 2, 0.0)) + faucet(w.cell, 0.0, 0.28, 0.2):
        w.add_fixture(fx)
    K = oakd_intrinsics()
    r = render(w, K, _looking_down((x0 + x1) / 2, 0.0, 0.35), 640, 480)
    # The drain's strainer is 3.4 mm proud of the floor and darker than the basin.
    assert r.depth[240, 320] == pytest.approx(0.35 - z0 - 0.0034, abs=5e-4)
    assert r.rgb[235:245, 315:325].mean() < 100
    # Seen from above the faucet's column, its top is far nearer than the counter.
    r2 = render(w, K, _looking_down(x1 + w.cell.spec.sink.wall + 0.05, 0.0, 0.6), 640, 480)
    assert r2.depth[240, 320] == pytest.approx(0.6 - 0.28, abs=0.03)


def test_the_second_camera_model_is_what_renders(tmp_path):
    cfg, kw = _kwargs()
    generate_dataset(tmp_path, 1, 4, [np.asarray(cfg.scan_waypoints[1])], kw, 640, 480, camera="d435")
    K_d435 = camera_model("d435").intrinsics(640, 480)
    assert not np.allclose(K_d435, oakd_intrinsics())
    scene = tmp_path / "test" / "000000"
    cam = json.loads((scene / "scene_camera.json").read_text())["0"]
    assert np.allclose(np.asarray(cam["cam_K"]).reshape(3, 3), K_d435)
    assert json.loads((tmp_path / "camera.json").read_text())["fx"] == pytest.approx(K_d435[0, 0])
    # Each object's silhouette (bbox_obj: the object rendered alone) is its model projected through that K;
    # the OAK-D's K (fx 497 instead of 615) would make it ~20 % smaller.
    gt = json.loads((scene / "scene_gt.json").read_text())["0"]
    info = json.loads((scene / "scene_gt_info.json").read_text())["0"]
    inv_ = Inventory.load(tmp_path / "models")
    checked = 0
    for g, inf in zip(gt, info):
        x, y, w, h = inf["bbox_obj"]
        if w < 40 or x <= 0 or y <= 0 or x + w >= 640 or y + h >= 480:
            continue
        T = make_T(np.asarray(g["cam_R_m2c"]).reshape(3, 3), np.asarray(g["cam_t_m2c"]) / 1000)
        V = transform_points(T, np.asarray(inv_[g["obj_id"]].mesh.vertices))
        boxes = []
        for Kx in (K_d435, oakd_intrinsics()):
            uv = (V @ Kx.T)[:, :2] / V[:, 2:3]
            boxes.append(np.array([*uv.min(0), *(uv.max(0) - uv.min(0))]))
        assert np.all(np.abs(boxes[0] - (x, y, w, h)) < 3), (boxes[0], inf["bbox_obj"])
        assert abs(boxes[1][2] - w) > 0.1 * w
        checked += 1
    assert checked >= 1


def test_default_generation_is_unchanged(tmp_path):
    cfg, kw = _kwargs()
    stats = generate_dataset(tmp_path, 1, 2, [np.asarray(cfg.scan_waypoints[1])], kw, 640, 480)
    assert stats["distractors"] == 0 and stats["inventory"] == 6
    assert not (tmp_path / "models_distractors").exists()
    meta = json.loads((tmp_path / "test" / "000000" / "scene_sim.json").read_text())
    assert set(meta) == {"seed", "style", "objects"}
    assert np.allclose(np.asarray(json.loads((tmp_path / "test" / "000000" / "scene_camera.json").read_text())["0"]
                                  ["cam_K"]).reshape(3, 3), oakd_intrinsics())


def test_dishware_families_are_closed_and_graspable():
    from kitchenbot.planning.grasp_synthesis import ensure_grasps
    from kitchenbot.world.inventory import Inventory

    models = sample_dishware(np.random.default_rng(0), 50)
    assert len(models) == len(FAMILIES)
    assert not any(m.grasps for m in models)  # the world model carries no grasps; planning synthesises them
    ensure_grasps(Inventory(models))
    for m in models:
        ext = m.extents
        assert 0.04 < ext.max() < 0.30, (m.name, ext)
        assert m.grasps, m.name
        assert m.mesh.is_edge_manifold(), m.name
        assert (m.cls in ("mug",)) == (not m.is_rotationally_symmetric), m.name
    by = {m.name.rsplit("_", 1)[0]: m for m in models}
    assert by["stemmed_glass"].extents[2] > 0.14  # stem + bowl
    assert by["saucer"].extents[0] < 0.17 and by["deep_plate"].extents[2] > 0.03


def test_generator_rejects_bad_options(tmp_path):
    cfg, kw = _kwargs()
    with pytest.raises(ValueError, match="variety"):
        generate_dataset(tmp_path, 1, 0, [], kw, variety="narrow")
    with pytest.raises(ValueError, match="camera"):
        generate_dataset(tmp_path, 1, 0, [], kw, camera="webcam")
    with pytest.raises(ValueError, match="distractors"):
        generate_dataset(tmp_path, 1, 0, [], kw, distractors=-1)


def test_table_scenes_stand_on_a_board_with_no_sink(tmp_path):
    """--surface table: every item (dishware and distractors) rests on the board over the basin (z >= 0), the
    board is in the depth, the camera stands 25 cm higher, and the scene names no cell."""
    from kitchenbot.fakes.bop import TABLE_CAMERA_LIFT
    from kitchenbot.fakes.scenes import SceneOptions, generate_scene

    cfg, kw = _kwargs()
    with pytest.raises(ValueError, match="surface"):
        generate_scene(0, options=SceneOptions(surface="shelf"), world_kwargs=kw)
    stats = generate_dataset(tmp_path, 1, 5, [np.asarray(cfg.scan_waypoints[1])], kw, 640, 480, distractors=2,
                             surface="table", camera="d435")
    assert stats["distractors"] == 2 and stats["objects"] >= 5
    scene = tmp_path / "test" / "000000"
    meta = json.loads((scene / "scene_sim.json").read_text())
    assert meta["surface"] == "table" and "cell" not in meta and "table_top" in meta["fixtures"]
    gt = json.loads((scene / "scene_gt.json").read_text())["0"]
    cam = json.loads((scene / "scene_camera.json").read_text())["0"]
    T_cam_base = make_T(np.asarray(cam["cam_R_w2c"]).reshape(3, 3), np.asarray(cam["cam_t_w2c"]) / 1000)
    T_base_cam = np.linalg.inv(T_cam_base)
    world = SimWorld(Cell(), Inventory.builtin(), **kw)
    world.set_joints(np.asarray(cfg.scan_waypoints[1], float))
    assert abs(T_base_cam[2, 3] - world.T_base_cam()[2, 3] - TABLE_CAMERA_LIFT) < 1e-6
    for g in gt:  # every object's origin above the board's top (no item sits in the basin, 20 cm down)
        T = T_base_cam @ make_T(np.asarray(g["cam_R_m2c"]).reshape(3, 3), np.asarray(g["cam_t_m2c"]) / 1000)
        assert T[2, 3] > -0.005, g
    K = np.asarray(cam["cam_K"]).reshape(3, 3)
    assert abs(K[0, 0] - camera_model("d435").intrinsics(640, 480)[0, 0]) < 1e-6
