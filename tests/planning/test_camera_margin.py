"""The wrist camera keeps the full collision margin from items and voxels in the grasp and release scenes.

Traced (issue 18): a bowl held by a tilted rim pinch was lowered into a rack slot; at the end of the lowering the
camera housing, 15-19 cm from the TCP, came down onto the top edge of a plate standing on edge two slots away. The
plate was a record of an item put down earlier, 4.4 mm lower than the real plate (the placement check searches the
height in 5 mm steps), and the release scene checked the camera, like the pads, with the 2 mm grasp margin: the
planner saw 2.5 mm between the camera and the record, the simulator a contact. Unlike the pads and the palm, the
camera never has to come close to anything. Hand-made after that scene: the arm where the lowering ended, the
plate record standing on edge in the lower rack."""

from __future__ import annotations

import coal
import numpy as np
import pinocchio as pin
import pytest

from kitchenbot.perception.types import ObjectPose

Q_LOWERED = np.array([1.29704, -0.94621, 1.95243, -2.31297, -0.82198, 1.19277])  # the end of the lowering
ON_EDGE = np.array([[0.0, 0.0, -1.0], [0.5, -0.86603, 0.0], [-0.86603, -0.5, 0.0]])  # axis level along base x


def _plate(planner, dz: float = 0.0) -> ObjectPose:
    m = planner.inventory.by_name("dinner_plate")
    T = np.eye(4)
    T[:3, :3] = ON_EDGE
    T[:3, 3] = (0.0325, -0.57, -0.14843 + dz)
    return ObjectPose(m.obj_id, m.cls, T, 1.0, instance_id=10001)


def _camera_clearance(scene, q, item: str = "obj:10001") -> float:
    """Exact distance (m) between the camera housing and the item's mesh at q (min_distance uses boxes)."""
    pin.updateGeometryPlacements(scene.model, scene.data, scene.gm, scene.gd, np.asarray(q, float))
    k = next(k for k, p in enumerate(scene.pair_names) if set(p) == {"camera", item})
    p = scene.gm.collisionPairs[k]
    geo = scene.gm.geometryObjects
    return coal.distance(geo[p.first].geometry, scene.gd.oMg[p.first], geo[p.second].geometry, scene.gd.oMg[p.second],
                         coal.DistanceRequest(), coal.DistanceResult())


def test_the_camera_keeps_the_full_margin_from_a_record_in_the_release_scene(planner):
    scene = planner.scene([_plate(planner)], None)
    release = scene.for_release(None)
    d = _camera_clearance(release, Q_LOWERED)
    assert 0.0 < d < planner.settings.collision_margin, f"the situation: the camera {d * 1000:.1f} mm from the plate"
    # before: checked with the 2 mm grasp margin, the pose was free
    assert not release.valid(Q_LOWERED)
    assert ("camera", "obj:10001") in release.colliding_pairs(Q_LOWERED) or \
        ("obj:10001", "camera") in release.colliding_pairs(Q_LOWERED)
    # and in a grasp scene likewise
    assert not scene.for_grasp(None).valid(Q_LOWERED)


def test_the_pads_palm_and_held_item_keep_the_grasp_margin_and_the_camera_keeps_it_from_the_cell(planner):
    release = planner.scene([_plate(planner)], None).for_release(None)
    margins = {p: release.gd.collisionRequests[k].security_margin for k, p in enumerate(release.pair_names)}
    s = planner.settings
    for (a, b), m in margins.items():
        parts = {a, b}
        if "camera" in parts and any(x.startswith(("obj:", "voxels")) for x in parts):
            assert m == pytest.approx(s.collision_margin), (a, b)
        elif parts & {"pad_a", "pad_b", "palm", "camera", "held"}:
            assert m == pytest.approx(s.grasp_margin), (a, b)
        else:
            assert m == pytest.approx(s.collision_margin), (a, b)


def test_a_plate_a_centimetre_clear_of_the_camera_leaves_the_pose_free(planner):
    release = planner.scene([_plate(planner, dz=-0.012)], None).for_release(None)
    assert _camera_clearance(release, Q_LOWERED) > planner.settings.collision_margin
    assert release.valid(Q_LOWERED)
