"""A lying cup slid with the closed fingers pressing on it rides on what it touches at the start; the simulated
arm stops on any new contact of the dragged item. A cup resting on one side plate's rim a fraction of a millimetre
from a second side plate's rim: which of the two carries it is below what a fitted pose resolves. Before, every
item within the planner's margin at the press was allowed to the held item for the whole slide (and its resting
height followed it onto them): the slide went along the gap, towards the second plate, and the simulated arm
stopped on it (`held hits obj`). Now (`planning.slide.NearItems`) a slide is safe whichever of the near items
carries the cup: it comes nearer to none of them, and does not go up or down following one while it leaves
another; the planner takes the direction that moves the cup away from the second plate, and refuses only where no
direction is safe."""

from __future__ import annotations

import coal
import numpy as np
import pytest

from kitchenbot.executive.oracle import OraclePerceiver
from kitchenbot.fakes.placement import drop_onto
from kitchenbot.planning.collision import coal_transform
from kitchenbot.transforms import rot_y, rot_z

pytestmark = pytest.mark.timeout(600)


def _scene(empty_sim_cell, gap_to_second: float | None, yaw_deg: float = 45.0):
    """Two side plates flat on the sink floor 1 cm apart along x; a cup lying across the gap (its axis turned
    `yaw_deg` from y) dropped onto them; with `gap_to_second`, the plate it does not touch is moved along x until
    its rim is that far from the cup."""
    cfg, world, planner = empty_sim_cell()
    lo, hi = planner.cell.sink_interior
    c = (lo + hi) / 2
    plate = next(m for m in world.inventory if m.name == "side_plate")
    cup = next(m for m in world.inventory if m.name == "cup")
    plates = []
    for sx in (-1, 1):
        T = np.eye(4)
        T[:3, 3] = (c[0] + sx * (plate.extents[0] / 2 + 0.005), c[1], 0.0)
        u = world.add_object(plate, T)
        world.set_pose(u, drop_onto(world, u, T))
        plates.append(u)
    T = rot_z(np.radians(yaw_deg)) @ rot_y(np.pi / 2)
    T[:3, 3] = (c[0], c[1], 0.08)
    cu = world.add_object(cup, T)
    world.set_pose(cu, drop_onto(world, cu, T))

    def gap(p):
        A, B = world.objects[cu], world.objects[p]
        return coal.distance(planner.world.bvh(A.model), coal_transform(A.T_base_obj), planner.world.bvh(B.model),
                             coal_transform(B.T_base_obj), coal.DistanceRequest(), coal.DistanceResult())

    if gap_to_second is not None:
        far = max(plates, key=gap)
        T0 = world.objects[far].T_base_obj.copy()
        sx = np.sign(world.objects[cu].T_base_obj[0, 3] - T0[0, 3])
        a, b = 0.0, 0.1  # bisect the shift towards the cup
        for _ in range(40):
            m = (a + b) / 2
            T = T0.copy()
            T[0, 3] += sx * m
            world.set_pose(far, T)
            a, b = (m, b) if gap(far) > gap_to_second else (a, m)
        T = T0.copy()
        T[0, 3] += sx * a
        world.set_pose(far, T)
    poses = OraclePerceiver(world).perceive([]).poses
    return cfg, world, planner, next(o for o in poses if o.instance_id == cu), poses, [gap(p) for p in plates]


def _run(cfg, world, slide) -> tuple[int, int]:
    from kitchenbot.fakes.arm import FakeArm
    from kitchenbot.fakes.gripper import FakeGripper

    arm, grip = FakeArm(world, cfg.safety_limits()), FakeGripper(world)
    arm.connect()
    grip.connect()
    grip.open(0.0)
    for traj in slide.trajectories:
        try:
            arm.execute_trajectory(traj.times, traj.q)
        except Exception:  # noqa: BLE001 (a protective stop: counted below)
            break
    return arm.log.collisions, arm.log.protective_stops


def test_a_slide_goes_away_from_a_neighbour_that_may_not_carry_the_item(empty_sim_cell):
    cfg, world, planner, cup, poses, gaps = _scene(empty_sim_cell, 0.0003)
    assert sorted(np.round(gaps, 5)) == [0.0, 0.0003]  # on one plate, 0.3 mm from the other
    slide = planner.plan_slide(world.q.copy(), poses, cup, then_pickable=False)
    assert slide.ok, slide  # not refused: there is a safe way (away from the second plate) ...
    assert _run(cfg, world, slide) == (0, 0)  # ... and it runs without a contact (before: 1 collision, 1 stop)


def test_a_slide_that_is_safe_in_no_direction_is_refused(empty_sim_cell):
    """45 micrometres from the second plate (the gap of the slide that collided): every direction either comes
    nearer to it or climbs the first plate's rim while leaving it. Before: planned along the gap, 1 collision."""
    cfg, world, planner, cup, poses, gaps = _scene(empty_sim_cell, 0.00005)
    assert sorted(np.round(gaps, 6)) == [0.0, 0.00005]
    slide = planner.plan_slide(world.q.copy(), poses, cup, then_pickable=False)
    if slide.ok:
        assert _run(cfg, world, slide) == (0, 0)
    else:
        assert "may carry it" in slide.message or "may not carry it" in slide.message, slide


@pytest.mark.parametrize("gap_to_second, yaw", [(None, 90.0), (None, 45.0)])
def test_a_cup_on_both_plates_or_clear_of_the_second_still_slides(empty_sim_cell, gap_to_second, yaw):
    """On both rims (0 and 0), or on one 3 mm from the other: the slide plans and runs without a contact."""
    cfg, world, planner, cup, poses, gaps = _scene(empty_sim_cell, gap_to_second, yaw)
    slide = planner.plan_slide(world.q.copy(), poses, cup, then_pickable=False)
    assert slide.ok, slide
    assert _run(cfg, world, slide) == (0, 0)
