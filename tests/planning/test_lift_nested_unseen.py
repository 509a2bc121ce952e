"""Three bowls nested on a plate, as the simulator settles them, of which perception found the top two (the bowl
under them only as map points: its points lie more than 1.5 cm from both fitted surfaces, so they stay obstacles,
voxels). The top bowl lies tilted in the middle one; lifted straight up it slides along the middle one's wall and the
contact is made again (tests/planning/test_lift_nested_fit.py), so the planner first moves it along the direction
that parts it from the middle bowl (planning.lift.separating_legs). The direction that parts the two fastest leads
the top bowl towards the bottom one (10.5 mm away at the grasp, touching after 2 cm): its points were right to refuse
that leg. Before, only that best direction was tried; refused, the last resort was the straight-up lift, which the
simulator stops. Now every parting direction is tried, best first, each checked against everything else."""

from __future__ import annotations

import coal
import numpy as np
import pytest

from kitchenbot.planning import lift as lift_mod
from kitchenbot.planning.collision import coal_transform, model_bvh
from kitchenbot.transforms import from_rotvec

# (rotation vector, position; base frame): the true poses, and the fitted ones perception gave (the bottom bowl: none)
BOTTOM = ((0.075715, 0.349462, 1.735468), (0.532222, -0.040181, -0.13722))
MIDDLE = ((-0.808945, 0.212234, 2.235314), (0.564417, -0.044593, -0.096473))
TOP = ((-1.682054, 0.748794, 2.187913), (0.564166, -0.035112, -0.04648))
MIDDLE_FIT = ((0.07944, -0.735381, -1.448544), (0.564763, -0.044117, -0.096236))
TOP_FIT = ((-0.55945, -1.280681, -0.31709), (0.564185, -0.034892, -0.04627))
Q_SCAN = np.array([2.198, -1.734, 2.006, -1.53, -1.13, 0.142])  # the last scan waypoint (config/sim.yaml)


def _surface_points(model, T: np.ndarray, n: int = 4000) -> np.ndarray:
    """`n` points spread over the model's mesh surface (area-weighted), in the base frame."""
    V = np.asarray(model.mesh.vertices, float)
    F = np.asarray(model.mesh.triangles)
    a = np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    rng = np.random.default_rng(0)
    k = rng.choice(len(F), n, p=a / a.sum())
    u, v = rng.random(n), rng.random(n)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    P = V[F[k, 0]] + u[:, None] * (V[F[k, 1]] - V[F[k, 0]]) + v[:, None] * (V[F[k, 2]] - V[F[k, 0]])
    return P @ T[:3, :3].T + T[:3, 3]


@pytest.fixture
def nested_on_unseen(sim_items, inventory):
    """The SimWorld with the three bowls (true poses); the middle and top ones as perceived (fitted poses); the map:
    points on the bottom bowl's surface."""
    world, (bottom, middle, top) = sim_items([
        ("bowl", from_rotvec(*BOTTOM), from_rotvec(*BOTTOM)),
        ("bowl", from_rotvec(*MIDDLE), from_rotvec(*MIDDLE_FIT)),
        ("bowl", from_rotvec(*TOP), from_rotvec(*TOP_FIT))])
    points = _surface_points(inventory[bottom.obj_id], from_rotvec(*BOTTOM))
    return world, bottom, middle, top, points


def _gap(model, Ta: np.ndarray, Tb: np.ndarray) -> float:
    b = model_bvh(model)
    if coal.collide(b, coal_transform(Ta), b, coal_transform(Tb), coal.CollisionRequest(), coal.CollisionResult()):
        return 0.0
    return float(coal.distance(b, coal_transform(Ta), b, coal_transform(Tb), coal.DistanceRequest(),
                               coal.DistanceResult()))


def test_the_bowl_nested_over_an_unseen_one_is_parted_from_it_clear_of_the_one_below(planner, nested_on_unseen,
                                                                                      lift_contact):
    world, _, middle, top, points = nested_on_unseen
    pick = planner.plan_pick(Q_SCAN, [middle, top], target=top, map_points=points)
    assert pick.ok, str(pick)
    contact = lift_contact(world, pick, top)
    assert contact is None, f"{pick.grasp.spec.name}: {contact}"
    assert pick.timings_ms.get("lift_separate_m", 0.0) > 0.0, pick.timings_ms  # parted first, not the last resort


def test_the_fastest_parting_direction_leads_towards_the_unseen_bowl(planner, inventory, nested_on_unseen):
    """The cause: the map points are a real bowl, and the best parting direction (on the fitted poses) brings the
    top bowl to it in the world: no rule may drop those points."""
    _, bottom, middle, top, _ = nested_on_unseen
    model = inventory[top.obj_id]
    held = model_bvh(model)
    other = (model_bvh(inventory[middle.obj_id]), coal_transform(middle.T_base_obj))

    def gap(offset, o):
        T = np.array(top.T_base_obj, float)
        T[:3, 3] += offset
        if coal.collide(held, coal_transform(T), o[0], o[1], coal.CollisionRequest(), coal.CollisionResult()):
            return 0.0
        return float(coal.distance(held, coal_transform(T), o[0], o[1], coal.DistanceRequest(), coal.DistanceResult()))

    legs = lift_mod.separating_legs(gap, [other], planner.settings.grasp_margin)
    assert len(legs) > 1
    best = legs[0] / np.linalg.norm(legs[0])
    T_top, T_bottom = from_rotvec(*TOP), from_rotvec(*BOTTOM)
    at_grasp = _gap(model, T_top, T_bottom)
    moved = T_top.copy()
    moved[:3, 3] += 0.02 * best
    assert at_grasp > 0.008 and _gap(model, moved, T_bottom) == 0.0


def test_every_parting_direction_is_offered_best_first():
    """separating_legs on a hand-made gap: an item that parts from what it touches when moved towards +x (more
    the more level the move), and not at all towards -x."""

    def gap(offset, _):
        return float(offset[0])

    legs = lift_mod.separating_legs(gap, [None], 0.002)
    dirs = [leg / np.linalg.norm(leg) for leg in legs]
    scores = [d[0] for d in dirs]
    assert len(legs) > 5 and all(s > 0 for s in scores)
    assert scores == sorted(scores, reverse=True)
    assert lift_mod.separating_legs(lambda o, _: -1.0, [None], 0.002) == []
