"""A glass lying across a plate's rim (its centre beside the plate, not over it): the plate's lift runs into it, so
the glass must come first. The tasks' pick order (Task.remaining: uncovered items first, then plates) judged
"covered" only by another item's centre lying within the plate's radius, higher up; the plate came first and its
pick failed with its lift blocked by the glass (one failed attempt, then blocker_first). The order now also asks the
meshes which item lies on which (planning.resting, the planner's own "blocked by" test)."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning.resting import lying_on
from kitchenbot.tasks import make_task
from kitchenbot.transforms import make_T, rot_y
from kitchenbot.world.cell import Cell


@pytest.fixture
def plate_and_glass(planner, inventory):
    """A dinner plate flat on the sink floor; a glass on its side, tilted 12 degrees (open end down, away from the
    plate), its body over the plate's rim and 1 mm clear of it, its centre 15 cm from the plate's."""
    plate_m, glass_m = inventory.by_name("dinner_plate"), inventory.by_name("glass")
    floor = planner.cell.sink_interior[0][2]
    plate = ObjectPose(plate_m.obj_id, plate_m.cls, make_T(t=(0.45, 0.0, floor + 0.016)), 1.0, instance_id=1)
    R = rot_y(np.radians(102.0))
    V = np.asarray(glass_m.mesh.vertices) @ R[:3, :3].T
    z = floor + 0.001 - V[:, 2].min()
    for k in range(60):  # raised in 1 mm steps until it clears the plate
        glass = ObjectPose(glass_m.obj_id, glass_m.cls, make_T(t=(0.599, 0.0, z + 0.001 * k)) @ R, 1.0, instance_id=2)
        if planner._vertical_clear_travel(glass, plate) == 0.0:
            break
    assert planner._vertical_clear_travel(glass, plate) == 0.0
    # beside the plate, not over it: the centre test alone does not see it
    r = max(plate_m.extents[:2]) / 2
    assert np.linalg.norm(glass.T_base_obj[:2, 3] - plate.T_base_obj[:2, 3]) > r
    return plate, glass


def test_the_plates_pick_is_blocked_by_the_glass(planner, home, plate_and_glass):
    """The failure the order avoids: every lift of the plate runs into the glass."""
    plate, glass = plate_and_glass
    pick = planner.plan_pick(home, [plate, glass], target=plate)
    assert not pick.ok and pick.kind == "cartesian_path_failed", str(pick)
    assert pick.details.get("blocking") == glass.instance_id
    assert planner.plan_pick(home, [plate, glass], target=glass).ok


@pytest.mark.parametrize("task_name", ["sink-pick", "sink-to-dishwasher"])
def test_the_glass_lying_on_the_plate_is_picked_first(inventory, plate_and_glass, task_name):
    plate, glass = plate_and_glass
    assert [o.instance_id for o in lying_on(plate, [glass], inventory)] == [glass.instance_id]
    assert lying_on(glass, [plate], inventory) == []
    task = make_task(task_name, inventory, Cell())
    assert task.remaining([plate, glass]) == [glass, plate]
    assert task.remaining([glass, plate]) == [glass, plate]


def test_the_planner_and_the_order_agree(planner, inventory, plate_and_glass):
    plate, glass = plate_and_glass
    assert planner._lies_on(glass, plate) and not planner._lies_on(plate, glass)
    assert planner.items_on(plate, [plate, glass]) == [glass]
