"""Scene.only_tool_touches: what a grasp's near miss asks (planning.grasps.select_grasps, `narrow`): whether all
that collides at a configuration is the tool meeting perceived objects or the map. It must say what
`_tool_only(colliding_pairs(q))` (every pair checked) says, with the pads' contact zone of a grasp scene and with
the pads moved between asks (set_opening: its variants share the geometry)."""

from __future__ import annotations

import numpy as np

from kitchenbot.planning.grasps import _tool_only, expand_grasps, object_name

from .test_grasp_swivel import Q, _pile


def test_only_tool_touches_is_what_every_pair_says(planner, inventory):
    objects, cup = _pile(inventory)
    scene = planner.scene(objects, own=[cup])
    grasp_scene = scene.for_grasp(object_name(cup, 0))
    model = inventory[cup.obj_id]
    asked = {True: 0, False: 0}
    for spec in expand_grasps(model)[::3]:
        T = np.asarray(cup.T_base_obj, float) @ spec.T_obj_tcp
        branches = planner.robot.ik_all_batch(T[None], Q)[0]
        for s in (grasp_scene, scene):
            s.set_opening(spec.opening)
            for q in branches:
                want = _tool_only(s.colliding_pairs(q))
                assert s.only_tool_touches(q) == want, (spec.name, q)
                asked[want] += 1
    assert asked[True] > 0 and asked[False] > 0, asked
