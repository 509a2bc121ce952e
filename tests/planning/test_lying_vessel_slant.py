"""A vessel lying on its side offers the top of its rim as a wall lying flat: its straight pinches there close
vertically and so come in level, and its grips across the body send a pad down beside it. A tumbler lying in a deep
bowl (both from dishware this project has never seen, grasps synthesised from the meshes) has no such grasp free:
each sweeps a pad into the bowl or meets it. The slanted pinches of its rim (planning/grasp_synthesis.py, fallbacks
for vessels) come in from above it; one plans and the simulated arm lifts the glass out with it."""

from __future__ import annotations

import coal
import numpy as np
import pytest

from kitchenbot.perception.types import ObjectPose
from kitchenbot.planning import grasp_synthesis
from kitchenbot.planning.collision import coal_transform
from kitchenbot.planning.grasp_synthesis import RIM_LEVEL, RIM_SLANT, ensure_grasps, synthesise_grasps
from kitchenbot.planning.grasps import FALLBACK_GRASPS, GraspStats, select_grasps
from kitchenbot.transforms import make_T, rot_y, rot_z
from kitchenbot.world.inventory import Inventory


@pytest.fixture(scope="module")
def own(own_dishware, tmp_path_factory):
    folder, expected = own_dishware
    inv = ensure_grasps(Inventory.load(folder), tmp_path_factory.mktemp("grasps"))
    by = {expected[m.obj_id][0]: m for m in inv}
    return inv, by


def _glass_in_bowl(planner, inv, glass, bowl, yaw: float, tilt: float) -> list[ObjectPose]:
    """The bowl upright on the sink floor's middle, the glass lying in it (axis `tilt` above level, turned `yaw`),
    lowered until it rests on the bowl."""
    lo, hi = planner.cell.sink_interior
    c = (lo + hi) / 2
    T_bowl = make_T(t=(c[0], c[1], lo[2] - np.asarray(bowl.mesh.vertices)[:, 2].min() + 0.001))
    R = (rot_z(yaw) @ rot_y(np.pi / 2 - tilt))[:3, :3]
    z = 0.1
    while not coal.collide(planner.world.bvh(glass), coal_transform(make_T(R, (c[0], c[1], z))),
                           planner.world.bvh(bowl), coal_transform(T_bowl), coal.CollisionRequest(),
                           coal.CollisionResult()):
        z -= 0.001
    T_glass = make_T(R, (c[0], c[1], z + 0.002))
    return [ObjectPose(bowl.obj_id, bowl.cls, T_bowl, 1.0, instance_id=1),
            ObjectPose(glass.obj_id, glass.cls, T_glass, 1.0, instance_id=2)]


def test_a_tumbler_lying_in_a_bowl_is_pinched_at_its_rim_from_above(own, cfg, home, run_pick_on_fake_arm):
    from kitchenbot.fakes.world import SimWorld
    from kitchenbot.planning.pick_place import Planner
    from kitchenbot.world.cell import Cell

    inv, by = own
    glass, bowl = by["tumbler"], by["deep_bowl"]
    assert RIM_SLANT in FALLBACK_GRASPS
    assert any(g.name.startswith(RIM_SLANT) for g in glass.grasps)
    planner = Planner.from_config(cfg, inv)
    for yaw, tilt in ((0.0, 0.0), (0.8, 0.25)):
        objects = _glass_in_bowl(planner, inv, glass, bowl, yaw, tilt)
        st = GraspStats()
        grasps = select_grasps(planner.robot, planner.scene(objects), inv, objects, home, settings=planner.settings,
                               target=objects[1], stats=st)
        assert isinstance(grasps, list), (yaw, tilt, st.__dict__)
        # no straight grasp is free at its full bite (each sweeps a pad into the bowl, or meets it); slanted rim
        # pinches from above are, and a straight one only backed off along its approach (a shallower bite whose pads
        # clear the bowl: planning.grasps.select_grasps), which the simulated arm below then lifts out
        assert any(g.spec.name.startswith(RIM_SLANT) for g in grasps), [g.spec.name for g in grasps]
        for g in grasps:
            if not g.spec.name.startswith(RIM_SLANT):
                full = np.asarray(objects[1].T_base_obj, float) @ g.spec.T_obj_tcp
                assert np.linalg.norm(g.T_base_tcp[:3, 3] - full[:3, 3]) > 0.003, g.spec.name
        assert st.multi_object > 0
        assert min(g.T_base_tcp[2, 2] for g in grasps) < -0.5
        pick = planner.plan_pick(home, objects, target=objects[1])
        assert pick.ok, pick
        world = SimWorld(Cell(), inv, T_flange_tcp=cfg.safety_limits().T_flange_tcp, q=home.copy())
        for o, m in zip(objects, (bowl, glass)):
            world.add_object(m, np.asarray(o.T_base_obj, float))
        run_pick_on_fake_arm(cfg, world, pick)
        assert world.objects[world.held_uid].model is glass


def test_a_vessels_straight_grasps_are_the_same_with_its_slanted_pinches(own, monkeypatch):
    """The slanted and the level pinches are spread on their own, after: a vessel's other grasps are exactly those
    synthesised without them (mixed in, they took places from the straight pinches a conical bowl was taken by)."""
    _, by = own
    bowl = by["deep_bowl"]
    with_slant = synthesise_grasps(bowl)
    assert any(g.name.startswith(RIM_LEVEL) for g in with_slant)
    monkeypatch.setattr(grasp_synthesis, "PINCH_TILTS", ())
    monkeypatch.setattr(grasp_synthesis, "MAX_RIM_LEVEL", 0)
    without = synthesise_grasps(bowl)
    straight = [g for g in with_slant if not g.name.startswith((RIM_SLANT, RIM_LEVEL))]
    assert len(with_slant) > len(straight) > 0
    assert [g.name for g in straight] == [g.name for g in without]
    assert all(np.allclose(a.T_obj_tcp, b.T_obj_tcp) and a.width == b.width for a, b in zip(straight, without))
