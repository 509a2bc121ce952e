"""An item that slipped out above the drop zone and came to rest on an item the robot placed there is found by the
look at its drop site, not taken for that placed item.

The look keeps out what perception finds where something was placed (a placed plate seen again is not the dropped
item, whatever perception calls it). That used to be decided in x-y alone: a glass lying on its side on a pile of
two placed plates, its centre 3 cm from theirs, was perceived as a glass where it lay and dropped as "a plate seen
again"; the run ended `failed` with the glass "not seen again", although it lay in the drop zone in view.
Now a found item that lies on the placed one (the planner's geometry, Planner.items_on) is not that one."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from kitchenbot.executive.execution import Item
from kitchenbot.fakes.placement import drop_onto
from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.types import PlaceTarget
from kitchenbot.transforms import make_T

PILE_XY = np.array([0.154, 0.506])  # in the drop zone of the shipped cell


def _pile_of_placed_plates(runner, world, n: int = 2) -> list[np.ndarray]:
    """`n` plates put down one on the other in the drop zone, each recorded as the robot's placement."""
    inv, b = runner.robot.inventory, runner.belief
    plate = next(m for m in inv.models.values() if m.cls == "plate")
    poses = []
    for _ in range(n):
        T = make_T(np.eye(3), (PILE_XY[0], PILE_XY[1], 0.3))
        u = world.add_object(plate, T)
        T = drop_onto(world, u, T)
        world.set_pose(u, T)
        T_release = T.copy()
        T_release[2, 3] += 0.01
        b.record_placed(runner.task, ObjectPose(plate.obj_id, "plate", T, 1.0),
                        PlaceTarget(T_release, "drop", support="counter"), T)
        poses.append(T)
    return poses


def _slipped_glass(runner, world, T_rest_guess: np.ndarray):
    """A glass that slipped out above the pile: it rests where `T_rest_guess` dropped onto the world comes to lie;
    the belief records it as dropped above there, as the executive does on a slip."""
    glass = next(m for m in runner.robot.inventory.models.values() if m.cls == "glass")
    u = world.add_object(glass, T_rest_guess)
    T = drop_onto(world, u, T_rest_guess)
    world.set_pose(u, T)
    runner.item = Item(ObjectPose(glass.obj_id, "glass", make_T(np.eye(3), (0.6, 0.03, -0.16)), 1.0))  # as picked
    runner.belief.record_dropped(np.array([T[0, 3] + 0.004, T[1, 3] - 0.002, 0.16]), cls="glass")
    return glass, T


def _connected(runner):
    for dev in (runner.arm, runner.gripper, runner.camera):
        dev.connect()


def test_a_glass_fallen_onto_placed_plates_is_found(make_runner):
    runner, world = make_runner(task="sink-pick", oracle=False)  # the pipeline's perception of the drop site
    _connected(runner)
    for u in list(world.objects):  # an emptied sink
        world.remove_object(u)
    _pile_of_placed_plates(runner, world)
    axis = np.array([-0.86, 0.47, 0.0]) / np.linalg.norm([-0.86, 0.47])  # on its side across the pile
    R = np.c_[[0.0, 0.0, 1.0], np.cross(axis, [0.0, 0.0, 1.0]), axis]
    _, T_glass = _slipped_glass(runner, world, make_T(R, (PILE_XY[0], PILE_XY[1] + 0.028, 0.2)))
    assert T_glass[2, 3] > 0.035  # it lies on the plates, not on the counter
    b = runner.belief
    assert len(b.lost_drops()) == 1

    runner._search_drop_site()

    assert b.lost_drops() == [], "the glass lying in view on the placed plates was not found"
    assert runner.report.recovered_drops == 1
    found = [p for p in b.placed if p.cls == "glass"]
    assert len(found) == 1 and np.linalg.norm(found[0].T_base_obj[:3, 3] - T_glass[:3, 3]) < 0.02
    assert runner.report.objects_done == 1  # the drop zone takes it as it lies (sink-pick)
    assert sum(p.cls == "plate" for p in b.placed) == 2  # the plates stay placed, not picked up again


class _Sees:
    def __init__(self, poses):
        self.poses = poses

    def perceive(self, views):
        return SimpleNamespace(poses=self.poses, map_points=None)


def test_a_placed_plate_read_as_the_dropped_class_is_not_the_dropped_item(make_runner):
    """What perception finds where a plate was placed, taken for the dropped class (a misreading of the plate:
    its centre at the plate's), is still that plate, not the glass that fell: nothing is recovered there."""
    runner, world = make_runner(task="sink-pick", oracle=True)
    _connected(runner)
    for u in list(world.objects):
        world.remove_object(u)
    T_top = _pile_of_placed_plates(runner, world)[-1]
    glass = next(m for m in runner.robot.inventory.models.values() if m.cls == "glass")
    runner.item = Item(ObjectPose(glass.obj_id, "glass", make_T(np.eye(3), (0.6, 0.03, -0.16)), 1.0))
    runner.belief.record_dropped(np.array([PILE_XY[0], PILE_XY[1], 0.16]), cls="glass")
    misread = ObjectPose(glass.obj_id, "glass", make_T(np.eye(3), T_top[:3, 3] + (0.01, 0.0, 0.0)), 0.6)
    runner._drop_perceiver = lambda: _Sees([misread])

    runner._search_drop_site()

    assert runner.report.recovered_drops == 0
    assert len(runner.belief.lost_drops()) == 1
    assert runner.report.objects_done == 0
