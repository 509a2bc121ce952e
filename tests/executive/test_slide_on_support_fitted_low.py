"""The top plate of a nest of two dinner plates, where the plate under it was seen in a small part and its fitted
pose lies a little low: 2.5 mm between the two poses, where the real plates touch. Every pinch of the top plate
meets the rim of the plate under it (`no_collision_free_grasp`, naming that plate), so `slide_off_stack` applies.
The press took the plate under it as what it rests on (within 3 mm), but the slide allowed the held plate only what
it was within the grasp margin (2 mm) of at the press: as the top plate climbed out of the well, its foot came
nearer the lower plate's sloping wall than 2 mm and every slide direction "collided" with the plate it rides on.
Both plates stayed in the sink (with a plate under them that waited for them). Now what the slid item lies on within
the press's 3 mm is its support for the whole slide, as what it touches is: the slide plans, the simulated arm
(the true poses, its own contact checks) drags the top plate off without touching anything else, and a pinch of it
is then free."""

from __future__ import annotations

import coal
import numpy as np
import pytest

from kitchenbot.executive.oracle import OraclePerceiver
from kitchenbot.fakes.placement import drop_onto
from kitchenbot.planning.collision import coal_transform
from kitchenbot.transforms import from_rotvec, make_T

from .conftest import plan_with_strategies

pytestmark = pytest.mark.timeout(300)

def _pose(rotvec_deg, xyz) -> np.ndarray:
    return make_T(from_rotvec(np.radians(rotvec_deg))[:3, :3], xyz)


# A stack of three dinner plates, as they lay (m, degrees of rotation vector): the bottom one nearly flat, the two
# above tipped 9 degrees and nested 7 mm apart along their axes; a fourth leaning 70 degrees on the -y wall beside
# them (under the bottom one's rim)
LEANING = _pose([-70.366, 0.0, 0.0], [0.49558, -0.15876, -0.07562])
BOTTOM = _pose([-0.561, 2.465, -40.431], [0.49105, 0.02751, -0.18132])
MIDDLE = _pose([8.258, -10.112, 163.991], [0.48366, 0.05800, -0.16574])
TOP = _pose([8.476, 3.203, 21.819], [0.48590, 0.05588, -0.15897])
# as fitted: the top plate within 0.5 mm of where it is, the middle one (4 % of it seen) 9.3 mm under the top one
# along its axis, 2-2.5 mm aside and tipped 0.64 degrees from it: the two poses 2.0 mm apart (more than the grasp
# margin) where the real plates touch
TOP_FITTED = _pose([2.444, 9.817, -90.017], [0.48626, 0.05628, -0.15901])
MIDDLE_FITTED = _pose([2.373, 10.524, -89.971], [0.48299, 0.05956, -0.16764])


@pytest.fixture(scope="module")
def stack(empty_sim_cell):
    """The four plates in the emptied sink. Returns (cfg, world, planner, [bottom, middle, top] uids)."""
    cfg, world, planner = empty_sim_cell()
    plate = world.inventory.by_name("dinner_plate")
    world.add_object(plate, LEANING)
    return cfg, world, planner, [world.add_object(plate, T) for T in (BOTTOM, MIDDLE, TOP)]


def _gap(planner, a, b) -> float:
    m = planner.inventory[a.obj_id]
    return coal.distance(planner.world.bvh(m), coal_transform(a.T_base_obj), planner.world.bvh(m),
                         coal_transform(b.T_base_obj), coal.DistanceRequest(), coal.DistanceResult())


def test_top_plate_slides_on_a_plate_fitted_low_under_it(stack, run_slide, run_pick_on_fake_arm):
    cfg, world, planner, (bottom, lower, upper) = stack
    poses = OraclePerceiver(world).perceive([]).poses
    top = next(p for p in poses if p.instance_id == upper)
    below = next(p for p in poses if p.instance_id == lower)
    # perceived as fitted: the planner's margins say the two do not touch
    for p, T_true, T_fit in ((top, TOP, TOP_FITTED), (below, MIDDLE, MIDDLE_FITTED)):
        p.T_base_obj = T_fit
        p.points = (p.points - T_true[:3, 3]) @ T_true[:3, :3] @ T_fit[:3, :3].T + T_fit[:3, 3]
    assert planner.settings.grasp_margin < _gap(planner, top, below) < 0.003
    assert [p.instance_id for p in planner.items_on(below, poses)] == [upper]
    plan, counts = plan_with_strategies("sink-to-dishwasher", top, world, planner, poses)
    # no pinch of the top plate is free (the lower plate's rim); the slide on the lower plate plans
    assert counts["direct_pick"] == {"tried": 1, "planned": 0}
    assert plan.strategy == "slide_off_stack" and plan.slide is not None, counts
    run_slide(world, cfg, plan.slide, upper)  # no collision, no stop; the top plate dragged where planned
    poses = OraclePerceiver(world).perceive([]).poses
    assert np.linalg.norm(next(p for p in poses if p.instance_id == lower).T_base_obj[:3, 3]
                          - MIDDLE[:3, 3]) < 1e-4  # the middle plate stayed where it was
    top = next(p for p in poses if p.instance_id == upper)
    pick = planner.plan_pick(world.q.copy(), poses, target=top)
    assert pick.ok, pick
    run_pick_on_fake_arm(cfg, world, pick)
    assert world.held_uid == upper
