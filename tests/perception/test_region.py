"""Incremental perception (perception/region.py) on hand-made scenes: a camera looking straight down at a floor,
items as boxes of nearer depth, and a perceiver that reports what a hand-made "after the pick" scene holds."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pytest

from kitchenbot.perception.region import Region, coverage, match_known, merge_map, update_region
from kitchenbot.perception.types import ObjectPose, View

F, W, H = 400.0, 640, 480
CAM_Z = 1.0  # the camera 1 m above the floor (z = 0), looking down: it sees x in [-0.8, 0.8], y in [-0.6, 0.6]


def _view(boxes=(), holes=()) -> View:
    """Looking straight down from (0, 0, CAM_Z) at the floor; `boxes`: (x0, x1, y0, y1, top z) seen nearer;
    `holes`: (x0, x1, y0, y1) with no depth."""
    K = np.array([[F, 0, W / 2], [0, F, H / 2], [0, 0, 1]])
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])  # optical z down, x along base x
    T[:3, 3] = (0, 0, CAM_Z)
    u, v = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    x, y = (u - W / 2) / F * CAM_Z, -(v - H / 2) / F * CAM_Z  # where each pixel's ray meets the floor
    depth = np.full((H, W), CAM_Z, np.float32)
    for x0, x1, y0, y1, top in boxes:
        depth[(x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)] = CAM_Z - top
    for x0, x1, y0, y1 in holes:
        depth[(x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)] = 0.0
    return View(np.zeros((H, W, 3), np.uint8), depth, K, T)


def _pose(cls: str, x: float, y: float, z: float = 0.0, iid: int = 0) -> ObjectPose:
    T = np.eye(4)
    T[:3, 3] = (x, y, z)
    return ObjectPose(1, cls, T, 1.0, instance_id=iid)


@dataclass
class _Result:
    poses: list
    map_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))


class _Scene:
    """A perceiver that sees the hand-made scene `poses` (and `points`) in whatever view it is given."""

    def __init__(self, poses, points=None):
        self.poses, self.points = poses, np.zeros((0, 3)) if points is None else points
        self.calls = 0

    def perceive(self, views):
        assert len(views) == 1
        self.calls += 1
        return _Result(list(self.poses), self.points)


def _region(x=0.0, y=0.0, r=0.15) -> Region:
    return Region.around([(np.array([x, y, 0.0]), r)])


def test_region_contains_and_rejects_bad_input():
    reg = Region.around([(np.array([0.0, 0.0, 0.5]), 0.1), (np.array([0.3, 0.0, 0.0]), 0.05)])
    assert reg.contains(np.array([[0.05, 0, 3.0], [0.3, 0.04, -1.0], [0.2, 0, 0], [0.0, 0.2, 0]])).tolist() == \
        [True, True, False, False]
    with pytest.raises(ValueError):
        Region(np.zeros((2, 2)), np.array([0.1]))
    with pytest.raises(ValueError):
        Region(np.zeros((1, 2)), np.array([0.0]))


def test_a_neighbour_resting_on_the_picked_item_is_re_posed_and_the_rest_kept():
    """A cup rested on the picked plate at (0, 0) and slid off it to (0.1, 0): found again in the region and
    re-posed; a bowl away from the pick keeps its pose (the same object); nothing is re-scanned."""
    cup_before, bowl = _pose("cup", 0.02, 0.0, 0.03, 1), _pose("bowl", 0.5, 0.3, 0.0, 2)
    cup_after = _pose("cup", 0.10, 0.0, 0.0, 7)
    bowl_seen_now = _pose("bowl", 0.52, 0.31, 0.0, 8)  # outside the region: the view's fit of it is not taken
    scene = _Scene([cup_after, bowl_seen_now])
    upd = update_region(scene, None, [cup_before, bowl], _view(), _region(r=0.2), z_floor=0.0)
    assert upd.rescan is None and upd.coverage == 1.0
    assert upd.kept == [bowl] and upd.kept[0] is bowl
    assert upd.replaced == [cup_before] and upd.found == [cup_after] and upd.appeared == []
    assert [p.instance_id for p in upd.poses] == [2, 7]


def test_a_neighbour_that_left_the_region_asks_for_a_rescan():
    """The cup that leaned on the picked item fell out of the region: one view cannot tell where it went."""
    cup_before = _pose("cup", 0.05, 0.0, 0.03, 1)
    scene = _Scene([_pose("cup", 0.6, 0.0, 0.0, 7)])  # it rolled far away, out of the region
    upd = update_region(scene, None, [cup_before], _view(), _region(r=0.15), z_floor=0.0)
    assert upd.rescan is not None and "cup" in upd.rescan
    # nor is it taken for another item of another class
    upd = update_region(_Scene([_pose("glass", 0.05, 0.0, 0.0, 7)]), None, [cup_before], _view(), _region(),
                        z_floor=0.0)
    assert upd.rescan is not None


def test_an_item_dropped_into_the_region_is_caught():
    """A slip dropped a mug back near the pick spot: the region's view finds it, matched by no known item."""
    mug = _pose("mug", -0.05, 0.05, 0.0, 9)
    upd = update_region(_Scene([mug]), None, [], _view(), _region(), z_floor=0.0)
    assert upd.rescan is None and upd.appeared == [mug] and mug in upd.poses


def test_a_region_the_view_does_not_measure_asks_for_a_rescan():
    scene = _Scene([])
    upd = update_region(scene, None, [], _view(holes=[(-0.2, 0.2, -0.2, 0.0)]), _region(), z_floor=0.0)
    assert upd.rescan is not None and upd.coverage < 0.8 and scene.calls == 0  # not perceived at all
    far = Region.around([(np.array([2.0, 0.0, 0.0]), 0.1)])  # out of the image
    assert coverage(_view(), far, 0.0) == 0.0


def test_a_straddling_item_is_left_to_its_kept_pose():
    """A plate whose origin lies outside the region, seen again inside its border: not added twice."""
    plate = _pose("plate", 0.17, 0.0, 0.0, 3)
    upd = update_region(_Scene([_pose("plate", 0.145, 0.0, 0.0, 5)]), None, [plate], _view(), _region(),
                        z_floor=0.0)
    assert upd.rescan is None and upd.poses == [plate]


def test_the_map_is_replaced_where_the_view_sees_and_kept_where_it_cannot():
    """Known points: one outside the region (kept), one inside the view now sees past (the picked item's: gone),
    one inside under a nearer surface (kept: the view cannot see it), one inside where there is no depth (kept).
    The view's own points: inside the region taken, outside not."""
    known = np.array([[0.5, 0.0, 0.05],      # outside
                      [0.0, 0.0, 0.05],      # inside; the view sees the floor behind it: it is gone
                      [0.08, 0.0, 0.02],     # inside, under a box whose top is at 0.1
                      [-0.08, 0.0, 0.05]])   # inside, in a hole of the depth image
    view = _view(boxes=[(0.05, 0.12, -0.03, 0.03, 0.10)], holes=[(-0.12, -0.05, -0.03, 0.03)])
    seen = np.array([[0.08, 0.0, 0.10], [0.6, 0.0, 0.0]])
    out = merge_map(known, seen, view, _region(r=0.15))
    rows = {tuple(np.round(p, 3)) for p in out}
    assert rows == {(0.5, 0.0, 0.05), (0.08, 0.0, 0.02), (-0.08, 0.0, 0.05), (0.08, 0.0, 0.1)}


def test_match_known_pairs_by_class_nearest_first():
    a, b = _pose("cup", 0.0, 0.0, iid=1), _pose("cup", 0.2, 0.0, iid=2)
    f1, f2, f3 = _pose("cup", 0.19, 0.0, iid=3), _pose("cup", 0.01, 0.0, iid=4), _pose("plate", 0, 0, iid=5)
    pairs, lost, extra = match_known([a, b], [f1, f2, f3])
    assert lost == [] and extra == [f3] and pairs == [(a, f2), (b, f1)]
    pairs, lost, extra = match_known([a, b], [f2])
    assert pairs == [(a, f2)] and lost == [b] and extra == []


def test_an_item_found_again_is_seen_at_least_as_fully_as_before():
    """One view confirms less of an item than the scan's three did: the pick did not bury it."""
    known = _pose("cup", 0.0, 0.05, iid=1)
    known.visible_fraction = 0.4
    seen = _pose("cup", 0.01, 0.05, iid=2)
    seen.visible_fraction = 0.15
    upd = update_region(_Scene([seen]), None, [known], _view(), _region(), z_floor=0.0)
    assert upd.rescan is None and upd.found[0].visible_fraction == 0.4

def test_the_pipeline_fits_only_the_region(perceiver, inventory, cell):
    """The real pipeline with `region=`: one view of four items, a region around two of them; only those two are
    fitted (and right), the rest of the view is left unfitted; update_region keeps the other two known poses."""
    from kitchenbot.perception.metrics import adi
    from kitchenbot.perception.synthetic import render, resting_pose, scan_poses

    placed = [(4, resting_pose(inventory, 4, 0.45, 0.09, 0.3, cell)),  # cup
              (2, resting_pose(inventory, 2, 0.56, -0.06, 0.0, cell)),  # side plate
              (5, resting_pose(inventory, 5, 0.38, -0.11, 1.0, cell)),  # mug
              (6, resting_pose(inventory, 6, 0.62, 0.12, 0.0, cell, upside_down=True))]  # glass
    views, _ = render(inventory, placed, scan_poses(cell)[1:2], cell, noise=0.002)
    region = Region.around([(placed[0][1][:3, 3], 0.06), (placed[2][1][:3, 3], 0.06)])  # the cup and the mug
    res = perceiver.perceive(views, region=region.contains)
    assert sorted(p.obj_id for p in res.poses) == [4, 5]
    for p in res.poses:
        T = dict(placed)[p.obj_id]
        assert adi(p.T_base_obj, T, inventory[p.obj_id].points) < 0.1 * inventory[p.obj_id].diameter
    known = [ObjectPose(oid, inventory[oid].cls, T, 1.0, instance_id=k) for k, (oid, T) in enumerate(placed)]
    upd = update_region(perceiver, None, known, views[0], region, z_floor=float(placed[1][1][2, 3]) - 0.01,
                        min_coverage=0.5)
    assert upd.rescan is None and upd.kept == [known[1], known[3]]
    assert sorted(p.obj_id for p in upd.found) == [4, 5] and upd.appeared == []


def test_an_item_found_where_it_was_keeps_its_known_pose_and_one_that_moved_is_reported():
    """One view's fit of an item that did not move is not taken over the scan's: the known pose object stays.
    One found farther off than pose tracking's tolerances (1 cm, 8 deg) is reported as moved, with the view's pose
    in the merged poses; a symmetric model's turn about its axis is no move."""
    still, shifted, spun = _pose("cup", 0.0, 0.05, iid=1), _pose("bowl", 0.08, -0.05, iid=2), \
        _pose("plate", -0.08, -0.05, iid=3)
    seen_still = _pose("cup", 0.004, 0.05, iid=11)  # 4 mm off: a fit's noise
    seen_shifted = _pose("bowl", 0.08, -0.02, iid=12)  # 3 cm off: it moved
    seen_spun = _pose("plate", -0.08, -0.05, iid=13)
    c, s = np.cos(1.0), np.sin(1.0)
    seen_spun.T_base_obj[:2, :2] = [[c, -s], [s, c]]  # turned 57 deg about its own axis
    upd = update_region(_Scene([seen_still, seen_shifted, seen_spun]), None, [still, shifted, spun], _view(),
                        _region(r=0.2), z_floor=0.0, symmetric=lambda p: p.cls == "plate")
    assert upd.rescan is None
    assert [(k.instance_id, f.instance_id) for k, f in upd.moved] == [(2, 12)]
    assert any(p is still for p in upd.poses) and any(p is spun for p in upd.poses)
    assert sorted(p.instance_id for p in upd.poses) == [1, 3, 12]
    # without knowing the plate is symmetric, its turn is a move
    upd = update_region(_Scene([seen_still, seen_spun]), None, [still, spun], _view(), _region(r=0.2), z_floor=0.0)
    assert [k.instance_id for k, _ in upd.moved] == [3]
