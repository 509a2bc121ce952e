"""A grasp backed off along its approach (a shallower bite, planning.grasps.BITES) is kept only where its fingers
still reach onto the item (planning/bite.py). A bowl's foot ring stands 10 mm proud; backed off 8 mm its pinch
ends short of the ring and the gripper closes on air (`grasp_missed`, again and again on two nested bowls whose
believed poses overlapped). Hand-made: a bowl upside down, and beside its +x foot pinch an upside-down cup whose
base reaches 3 mm into the pads' closing sweep at the full bite (and at 4 mm back), clear of it 8 mm back: the
belief of a neighbour perceived where it overlaps the bowl."""

import numpy as np

from kitchenbot.planning.bite import fingers_reach
from kitchenbot.transforms import trans

SPEC = "foot_00"  # the foot-ring pinch on the +x side of the bowl (object frame)


def _scene(planner, resting):
    bowl = resting("bowl", (0.55, 0.0), 1, upside_down=True)
    m = planner.inventory[bowl.obj_id]
    spec = next(s for s in m.grasps if s.name == SPEC)
    full = np.asarray(bowl.T_base_obj) @ spec.T_obj_tcp  # the pinch at the full bite, base frame
    ring_end = float(np.max((np.asarray(m.mesh.vertices) @ bowl.T_base_obj[:3, :3].T + bowl.T_base_obj[:3, 3])[:, 2]))
    cup = resting("cup", (full[0, 3] + 0.012, full[1, 3]), 2, upside_down=True)  # under the outer pad
    mc = planner.inventory[cup.obj_id]
    top = float(np.max((np.asarray(mc.mesh.vertices) @ cup.T_base_obj[:3, :3].T + cup.T_base_obj[:3, 3])[:, 2]))
    cup.T_base_obj = trans(0.0, 0.0, (ring_end - 0.003) - top) @ cup.T_base_obj  # its base 3 mm below the ring end
    return bowl, cup, spec, full


def _sim_closes_on(planner, bowl, g) -> bool:
    """Whether the simulated Fin-Ray gripper, at grasp `g` with the bowl where the belief has it, holds the bowl."""
    from kitchenbot.executive.config import CellConfig
    from kitchenbot.fakes.gripper import FakeGripper
    from kitchenbot.fakes.world import SimWorld

    cfg = CellConfig()
    world = SimWorld(planner.cell, planner.inventory, T_flange_tcp=cfg.safety_limits().T_flange_tcp, q=np.asarray(g.q))
    uid = world.add_object(planner.inventory[bowl.obj_id], np.asarray(bowl.T_base_obj, float))
    grip = FakeGripper(world)
    grip.connect()
    grip.open(g.spec.opening)
    r = grip.grasp(0.8)
    return bool(r.holding and world.held_uid == uid)


def test_backed_off_foot_pinch_that_ends_short_of_the_ring_is_not_offered(planner, resting, home):
    bowl, cup, spec, full = _scene(planner, resting)
    out = planner.select_grasps(home, [bowl, cup], target=bowl)
    assert isinstance(out, list) and out, "the bowl's other grasps stay"
    for g in out:  # every grasp offered closes on the bowl in the simulator
        assert _sim_closes_on(planner, bowl, g), f"{g.spec.name} closes on nothing"
    g = next((g for g in out if g.spec.name == spec.name), None)
    if g is not None:  # kept only at a bite its fingers reach the ring from
        back = float((g.T_base_tcp[:3, 3] - full[:3, 3]) @ -full[:3, 2])
        assert back < 0.006


def test_fingers_reach_the_ring_at_the_bites_the_simulator_holds_at(planner):
    m = planner.inventory.by_name("bowl")
    spec = next(s for s in m.grasps if s.name == SPEC)
    assert fingers_reach(m, spec.T_obj_tcp)
    assert fingers_reach(m, spec.T_obj_tcp @ trans(0.0, 0.0, -0.004))
    assert not fingers_reach(m, spec.T_obj_tcp @ trans(0.0, 0.0, -0.008))


def test_the_backed_off_answer_is_kept_per_model_and_grasp(planner, monkeypatch):
    """fingers_reach_backed_off answers as fingers_reach at the backed-off pose, and asks it once per (model, grasp,
    bite): it does not depend on where the item lies."""
    from kitchenbot.planning import bite

    m = planner.inventory.by_name("bowl")
    spec = next(s for s in m.grasps if s.name == SPEC)
    asked = []
    real = bite.fingers_reach
    monkeypatch.setattr(bite, "fingers_reach", lambda model, T: asked.append(1) or real(model, T))
    monkeypatch.setattr(bite, "_backed", {})
    for _ in range(3):
        assert bite.fingers_reach_backed_off(m, spec.T_obj_tcp, 0.004)
        assert not bite.fingers_reach_backed_off(m, spec.T_obj_tcp, 0.008)
    assert len(asked) == 2
