"""Piles as the simulator settles them (poses taken from task seeds): items touching, lying across each other,
nested mugs. Each case failed before: a fit between two items of one segment replacing the right one, a mug's
handle on the wrong side, a mug or cup upside down."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from kitchenbot.perception.synthetic import render, scan_poses
from kitchenbot.transforms import make_T

CUP, MUG = 4, 5


def _T(rotvec, t) -> np.ndarray:
    return make_T(Rotation.from_rotvec(rotvec).as_matrix(), t)


def _perceive(perceiver, inventory, cell, placed):
    views, _ = render(inventory, placed, scan_poses(cell), cell, noise=0.002)
    return perceiver.perceive(views).poses


def _nearest(poses, obj_id, T):
    mine = [p for p in poses if p.obj_id == obj_id]
    assert mine, f"no pose of model {obj_id}"
    return min(mine, key=lambda p: np.linalg.norm(p.T_base_obj[:3, 3] - T[:3, 3]))


def _errors(T_est, T_true) -> tuple[float, float]:
    """Origin distance (mm) and angle between the z axes (deg; 180 = upside down)."""
    return (1000 * float(np.linalg.norm(T_est[:3, 3] - T_true[:3, 3])),
            float(np.degrees(np.arccos(np.clip(T_est[:3, 2] @ T_true[:3, 2], -1, 1)))))


def _sink_scan_cams() -> list[np.ndarray]:
    """T_base_cam of the sink's three scan poses as the generated scenes of these tests were seen (printed rounded:
    the rotations orthonormalised)."""
    cams = [np.array(c + [[0.0, 0.0, 0.0, 1.0]]) for c in (
        [[-0.7206, -0.5434, 0.4307, 0.2619], [-0.6025, 0.7981, -0.001, 0.0008], [-0.3432, -0.2602, -0.9025, 0.3312]],
        [[0.3941, -0.9011, 0.1807, 0.4003], [-0.7665, -0.4308, -0.4764, 0.24], [0.5071, 0.0492, -0.8605, 0.3005]],
        [[-0.8802, -0.4382, 0.1821, 0.4009], [-0.3112, 0.8227, 0.4757, -0.2397], [-0.3583, 0.3621, -0.8605, 0.3003]])]
    for c in cams:
        u, _, vt = np.linalg.svd(c[:3, :3])
        c[:3, :3] = u @ vt
    return cams


def test_cup_lying_across_a_leaning_cup(perceiver, inventory, cell):
    """Sink-pick seed 29: a cup leaning 31 deg (in a cup under it, left out here) and a cup lying across it at
    110 deg, segmented as one instance. An upright fit between the two, scoring 0.01 less than the lying cup's
    exact fit, replaced it; the leftovers then gave an upside-down cup 27 mm off and a phantom."""
    placed = [(CUP, _T([-0.6032, -0.2757, -2.1247], [0.3982, 0.096, -0.0839])),
              (CUP, _T([-2.0692, -0.6923, -1.3048], [0.4265, 0.1304, -0.0152]))]
    poses = _perceive(perceiver, inventory, cell, placed)
    assert len(poses) == 2, [(p.obj_id, p.T_base_obj[:3, 3].round(3)) for p in poses]
    for _, T in placed:
        d, a = _errors(_nearest(poses, CUP, T).T_base_obj, T)
        assert d < 5 and a < 5, f"cup {T[:3, 3].round(3)}: {d:.1f} mm, axis {a:.1f} deg"


def test_mug_touching_a_cup_has_its_handle_on_the_right_side(perceiver, inventory, cell):
    """Seed 45: an upside-down mug whose handle touches a cup lying on its side. Yaw hypotheses were tried at the
    centroid of both; the fit put the handle toward the cup (origin 3 cm off: the mug's frame is its bounding box
    centre, the body's axis 1.7 cm from it)."""
    mug = _T([-2.0219, 2.3802, 0.0382], [0.6167, 0.1005, -0.1506])
    placed = [(MUG, mug), (CUP, _T([0.4634, -1.5697, 1.6479], [0.5918, -0.0012, -0.135]))]
    poses = _perceive(perceiver, inventory, cell, placed)
    p = _nearest(poses, MUG, mug)
    d, a = _errors(p.T_base_obj, mug)
    turn = np.degrees(np.arccos(np.clip(p.T_base_obj[:3, 0] @ mug[:3, 0], -1, 1)))
    assert d < 5 and a < 5 and turn < 15, f"mug: {d:.1f} mm, axis {a:.1f} deg, handle turned {turn:.0f} deg"


def test_mug_on_its_side_the_right_way_up(perceiver, inventory, cell):
    """Seed 45: a mug lying on its side was fitted with its opening where its base is (axis 177 deg off)."""
    mug = _T([-0.7795, -1.3806, 0.409], [0.3293, -0.0012, -0.147])
    poses = _perceive(perceiver, inventory, cell, [(MUG, mug)])
    d, a = _errors(_nearest(poses, MUG, mug).T_base_obj, mug)
    assert d < 5 and a < 10, f"mug: {d:.1f} mm, axis {a:.1f} deg"


def test_mug_nested_in_a_mug(perceiver, inventory, cell):
    """Seed 40: a mug leaning 16 deg in an upright one; the lower one's handle was fitted 1.5 cm off."""
    placed = [(MUG, _T([-0.0205, 0.0216, 0.5353], [0.5975, -0.1004, -0.1507])),
              (MUG, _T([-0.1032, 0.2584, 0.5365], [0.5999, -0.0982, -0.0597]))]
    poses = _perceive(perceiver, inventory, cell, placed)
    assert len(poses) == 2
    for _, T in placed:
        d, a = _errors(_nearest(poses, MUG, T).T_base_obj, T)
        assert d < 5 and a < 5, f"mug {T[:3, 3].round(3)}: {d:.1f} mm, axis {a:.1f} deg"



def test_mug_lying_on_two_mugs_keeps_its_handle_side():
    """Sink-pick seed 9 as the task's scan sees it: three mugs lying (75-80 deg) on each other over two bowls and a
    glass. The yaw sweep about the top mug's body axis scored 0.7 % higher with the handle on the other side (it
    took points of the mugs under it) and turned it half round: its frame 3 cm off, its lift blocked, 2 of 9
    items placed. A turn must now win clearly (Perceiver.YAW_SWEEP_MARGIN)."""
    from kitchenbot.executive.assembly import assemble
    from kitchenbot.executive.config import load_config
    from kitchenbot.perception.pipeline import Perceiver
    from kitchenbot.perception.types import View

    cfg = load_config()
    robot = assemble(cfg, 9)
    robot.connect()
    world = robot.world
    views = []
    for q in cfg.scan_waypoints:
        world.set_joints(np.asarray(q, float))
        f = robot.camera.capture()
        views.append(View(f.rgb, f.depth, f.K, world.T_base_flange() @ robot.T_flange_cam, f.stamp))
    poses = Perceiver(cfg.perception, robot.inventory, robot.cell).perceive(views).poses
    top = max((o for o in world.objects.values() if o.model.cls == "mug"), key=lambda o: o.T_base_obj[2, 3])
    d, a = _errors(_nearest(poses, MUG, top.T_base_obj).T_base_obj, top.T_base_obj)
    assert d < 5 and a < 5, f"top mug: {d:.1f} mm, axis {a:.1f} deg"


def _axes_pose(z, x, centre) -> np.ndarray:
    """Pose with object z along `z`, object x along `x` made orthogonal to it, origin at `centre`."""
    z = np.asarray(z, float) / np.linalg.norm(z)
    x = np.asarray(x, float) - (np.asarray(x, float) @ z) * z
    x /= np.linalg.norm(x)
    return make_T(np.column_stack([x, np.cross(z, x), z]), centre)


def test_a_pile_on_a_table_is_explained_item_by_item(perceiver, inventory, cell):
    """A development table scene rebuilt by hand: three bowls (one upright, one lying against it, one upside
    down), a side plate on a dinner plate, a cup, three glasses and two boxes on a board over the sink, all
    touching: one segment of ~120 k points. A right pose of one bowl explains under 20 % of that segment, so it
    was refused (`or_query < 0.2`) and the segment cut into 7 cm regions, which cut the items too: the side
    plate, a bowl and two glasses were lost. The share is now taken over the points within the model's reach,
    and what each pose leaves is fitted again."""
    import open3d as o3d

    items = [(1, _axes_pose([0.002, 0.008, 1], [-0.777, 0.629, -0.003], [0.563, 0.009, 0.016])),
             (2, _axes_pose([0.256, 0.018, 0.967], [-0.171, 0.985, 0.027], [0.484, 0.009, 0.031])),
             (3, _axes_pose([0.398, 0.265, -0.878], [-0.149, -0.926, -0.347], [0.35, -0.049, 0.07])),
             (3, _axes_pose([-0.21, 0.914, 0.348], [0.851, -0.004, 0.525], [0.339, 0.068, 0.066])),
             (3, _axes_pose([0.205, 0.043, 0.978], [0.832, 0.519, -0.197], [0.384, 0.008, 0.151])),
             (4, _axes_pose([-0.097, -0.242, -0.965], [-0.808, 0.586, -0.065], [0.525, -0.034, 0.074])),
             (6, _axes_pose([-0.196, 0.114, -0.974], [0.097, -0.986, -0.135], [0.556, 0.111, 0.091])),
             (6, _axes_pose([0.726, -0.473, -0.5], [0.687, 0.529, 0.498], [0.502, 0.147, 0.165])),
             (6, _axes_pose([0.093, -0.081, 0.992], [-0.524, 0.844, 0.118], [0.701, -0.019, 0.093]))]
    extra = []
    for size, T, colour in (((0.156, 0.04, 0.195), _axes_pose([0.751, -0.659, 0.04], [0.638, 0.74, 0.211],
                                                              [0.594, -0.029, 0.163]), (0.9, 0.8, 0.1)),
                            ((0.106, 0.055, 0.182), _axes_pose([0.635, 0.746, 0.203], [-0.757, 0.653, -0.031],
                                                               [0.594, -0.004, 0.216]), (0.8, 0.1, 0.1)),
                            ((0.7, 0.6, 0.02), make_T(np.eye(3), [0.5, 0.0, -0.01]), (0.6, 0.4, 0.25))):
        box = o3d.geometry.TriangleMesh.create_box(*size)
        box.translate(-np.asarray(size) / 2)
        box.transform(T)
        box.compute_vertex_normals()
        extra.append((box, colour))
    views, _ = render(inventory, items, scan_poses(cell, height=0.70), cell, noise=0.002, extra=extra)
    poses = perceiver.perceive(views).poses
    from kitchenbot.perception.metrics import adi
    for k in (1, 2, 3, 4, 6, 7):  # the side plate, the three bowls, the two glasses that are well seen
        oid, T = items[k]
        errs = [adi(p.T_base_obj, T, inventory[oid].points) for p in poses if p.obj_id == oid]
        assert errs and min(errs) < 0.1 * inventory[oid].diameter, (k, inventory[oid].name, [
            (p.cls, np.round(p.T_base_obj[:3, 3], 3)) for p in poses])


GLASS = 6


def test_a_glass_nested_in_a_glass_under_a_glass_lying_across_is_found(perceiver, inventory, cell):
    """A pile of three glasses (as generated sink scene 4790/1 settled it, seen from its three scan poses): one upright
    on the floor, one nested in it leaning 18 deg, one lying across the top. The nested glass's segment held part
    of the lying one and was fitted upside down (rejected); with no pose for the nested glass, the glass under it
    was rejected for the nested one's wall going on past its rim (`continued`). The points a pose rejected only by
    its surroundings leaves unexplained are fitted again (`Perceiver._fit_around_rejected`): all three found."""
    placed = [(GLASS, _T([0.0381, -0.0832, 2.9484], [0.3199, 0.1035, -0.138])),
              (GLASS, _T([0.2373, -0.3098, 2.3013], [0.3243, 0.0889, -0.0454])),
              (GLASS, _T([0.9431, -1.6897, 1.9199], [0.3368, 0.0366, 0.0346]))]
    cams = _sink_scan_cams()
    views, _ = render(inventory, placed, cams, cell, noise=0.002)
    poses = perceiver.perceive(views).poses
    assert len(poses) == 3, [(p.obj_id, p.T_base_obj[:3, 3].round(3)) for p in poses]
    for _, T in placed:
        d, a = _errors(_nearest(poses, GLASS, T).T_base_obj, T)
        assert d < 10 and a < 5, f"glass {T[:3, 3].round(3)}: {d:.1f} mm, axis {a:.1f} deg"


def test_a_region_of_a_blob_is_scored_with_the_rest_of_the_blob_confirming_its_surface(perceiver, inventory, cell):
    """A glass 12 cm long leaning 60 deg on a mug (as generated sink scene 505 settled them, seen from its three
    scan poses). When the pile it leans in is one segment that no model explains, the segment is cut into regions
    7 cm apart and each is fitted alone: the glass's surface lies in several regions, and on any one of them its
    right pose confirms a fraction of its visible surface (`or_model`), so no region gave a glass that passed the
    overlap gate (here the blob's largest region, part glass, part mug: 0.29 of the glass's visible surface). With the blob's other points as `context`, the right pose's visible surface is confirmed where
    the blob has it, and it passes; a pose slid 3 cm along the axis still scores below it, and the share of the
    region's own points it explains (`or_query`) is the same as without context."""
    from kitchenbot.perception.pipeline import _partition, _voxel_centres
    from kitchenbot.perception.register import Scorer, clean_depths
    from kitchenbot.perception.rgbd import backproject

    glass = _T([-0.2136, -1.0795, -1.129], [0.3888, 0.0051, -0.0091])
    placed = [(GLASS, glass), (MUG, _T([1.5738, -1.9195, -0.7704], [0.4218, -0.0771, -0.0815]))]
    cams = _sink_scan_cams()
    views, labels = render(inventory, placed, cams, cell, noise=0.002)
    vox = perceiver.settings.voxel_size
    blob = _voxel_centres(np.concatenate([backproject(v, lab >= 0)[0] for v, lab in zip(views, labels)]), vox)
    region = max((blob[r] for r in _partition(blob, 0.07)), key=len)  # part of the glass, part of the mug
    slid = glass.copy()
    slid[:3, 3] += 0.03 * glass[:3, 2]
    alone = Scorer(perceiver.database[GLASS], region, views, vox, depths=clean_depths(views))
    within = Scorer(perceiver.database[GLASS], region, views, vox, depths=clean_depths(views), context=blob)
    s_alone, q_alone, m_alone = alone(glass)[:3]
    s_in, q_in, m_in = within(glass)[:3]
    assert s_alone < perceiver.settings.min_overlap, (s_alone, m_alone)  # why the glass was missed
    assert s_in >= perceiver.settings.min_overlap and m_in > m_alone + 0.3, (s_in, m_in, m_alone)
    assert q_in == q_alone
    assert within(slid)[0] < s_in - 0.05, (within(slid)[0], s_in)
