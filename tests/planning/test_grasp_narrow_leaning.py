"""A glass leaning on an upturned bowl, wedged between the bowls' domes and a basin wall, is taken with its pads
opened only 8 mm wider than it (planning.grasps.select_grasps, third pass: the second of NARROW_SLACKS).

Hand-made from a sink where it happened (a task run): two bowls upside down, one nested over the other, and a glass
tilted 60 degrees from upright leaning on the upper one's dome, 24 mm from the basin's -x wall. Every grasp collides:
across its body one pad goes into the bowl under it and the other into the wall; the rim pinches put the palm into
the other wall. Opened 16 mm wider than the glass the bowl-side pad is still in the bowl; 8 mm wider (4 mm a pad)
it comes down between the glass and the dome. The glass's failure named the bowl, the bowl's pinned lift named the
glass: the run waited on the pair until it ended. Taken so on the simulated arm: no collision, held."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.executive.oracle import OraclePerceiver
from kitchenbot.planning import grasps as grasps_mod

pytestmark = pytest.mark.timeout(300)


def _pose(R, t) -> np.ndarray:
    """A rigid transform from a rotation written to 4 decimals (made orthonormal) and a position."""
    U, _, Vt = np.linalg.svd(np.asarray(R, float))
    T = np.eye(4)
    T[:3, :3] = U @ Vt
    T[:3, 3] = t
    return T


LOWER_BOWL = _pose([[-0.4567, -0.8874, 0.0632], [-0.877, 0.4371, -0.1995], [0.1494, -0.1466, -0.9778]],
                   (0.4006, 0.0888, -0.1478))
UPPER_BOWL = _pose([[0.3115, -0.95, -0.0199], [-0.9475, -0.3121, 0.0693], [-0.072, -0.0028, -0.9974]],
                   (0.4065, 0.0763, -0.1208))
GLASS = _pose([[-0.9607, 0.2775, 0.0026], [-0.1385, -0.4875, 0.8621], [0.2405, 0.8278, 0.5068]],
              (0.3102, 0.0741, -0.0973))


@pytest.fixture
def scene(empty_sim_cell):
    cfg, world, planner = empty_sim_cell()
    bowl = next(m for m in world.inventory if m.name == "bowl")
    glass = next(m for m in world.inventory if m.name == "glass")
    lower = world.add_object(bowl, LOWER_BOWL)
    upper = world.add_object(bowl, UPPER_BOWL)
    g = world.add_object(glass, GLASS)
    poses = OraclePerceiver(world).perceive([]).poses
    return cfg, world, planner, poses, next(o for o in poses if o.instance_id == g), (lower, upper)


def test_before_16_mm_is_not_narrow_enough(scene, monkeypatch):
    monkeypatch.setattr(grasps_mod, "NARROW_SLACKS", (grasps_mod.NARROW_SLACK,))
    cfg, world, planner, poses, glass, (lower, upper) = scene
    r = planner.plan_pick(world.q.copy(), poses, target=glass)
    assert not r.ok and r.kind == "no_collision_free_grasp", r
    assert r.details["blocking"] in (lower, upper)  # a bowl it leans on
    bowl = next(o for o in poses if o.instance_id == upper)  # whose own lift it pins
    r = planner.plan_pick(world.q.copy(), poses, target=bowl)
    assert not r.ok and r.details.get("blocking") == glass.instance_id, r


def test_the_leaning_glass_is_taken_with_the_pads_opened_8_mm_wider(scene, run_pick_on_fake_arm):
    cfg, world, planner, poses, glass, _ = scene
    pick = planner.plan_pick(world.q.copy(), poses, target=glass)
    assert pick.ok, pick
    spec = pick.grasp.spec
    assert spec.name.endswith("_narrow8") and abs(spec.opening - (spec.width + 0.008)) < 1e-6
    run_pick_on_fake_arm(cfg, world, pick)
    assert world.held_uid == glass.instance_id
