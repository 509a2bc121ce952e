"""Scene.only_pads_touch: what a grasp's third pass asks (planning.grasps.select_grasps, `pads_in_the_way`): whether
all that collides at a configuration has an open pad in it. It must say what `_pads_only(colliding_pairs(q))`
(every pair checked) says, with the pads' contact zone of a grasp scene and with the pads moved between asks
(set_opening: its variants share the geometry), and the two kinds of ask kept apart on one scene. The same for
Scene.only_tool_touches (a grasp's near miss, `narrow`): what `_tool_only(colliding_pairs(q))` says."""

from __future__ import annotations

import numpy as np

from kitchenbot.planning.grasps import _pads_only, _tool_only, expand_grasps, object_name

from .test_grasp_swivel import Q, _pile


def test_only_pads_touch_is_what_every_pair_says(planner, inventory):
    objects, cup = _pile(inventory)
    scene = planner.scene(objects, own=[cup])
    grasp_scene = scene.for_grasp(object_name(cup, 0))
    model = inventory[cup.obj_id]
    asked = {True: 0, False: 0}
    tool_asked = {True: 0, False: 0}
    for spec in expand_grasps(model)[::2]:
        T = np.asarray(cup.T_base_obj, float) @ spec.T_obj_tcp
        branches = planner.robot.ik_all_batch(T[None], Q)[0]
        for s in (grasp_scene, scene):
            for opening in (spec.opening, spec.width + 0.016):
                s.set_opening(opening)
                for q in branches:
                    pairs = s.colliding_pairs(q)
                    want = _pads_only(pairs)
                    assert s.only_pads_touch(q) == want, (spec.name, opening, q, pairs)
                    # the tool's split kept beside the pads' on the same scene
                    tool = _tool_only(pairs)
                    assert s.only_tool_touches(q) == tool, (spec.name, opening, q, pairs)
                    asked[want] += 1
                    tool_asked[tool] += 1
    assert asked[True] > 0 and asked[False] > 0, asked
    assert tool_asked[True] > 0 and tool_asked[False] > 0, tool_asked


def test_the_contact_zone_kept_per_configuration_answers_as_computed(planner, inventory):
    """Scene._tcp_in_zone (which of a grasp scene's two variants answers the pair queries at q, kept per q) says what
    the contact zone says of the TCP at q, on first and later asks, and a variant does not inherit the kept answers."""
    from kitchenbot.planning.collision import tcp_positions

    objects, cup = _pile(inventory)
    grasp_scene = planner.scene(objects, own=[cup]).for_grasp(object_name(cup, 0))
    model = inventory[cup.obj_id]
    seen = {True: 0, False: 0}
    for spec in expand_grasps(model)[::2]:
        T = np.asarray(cup.T_base_obj, float) @ spec.T_obj_tcp
        for q in planner.robot.ik_all_batch(T[None], Q)[0]:
            for lift in (0.0, 0.05):  # at the grasp and 5 cm up the approach: inside and outside the zone
                q = np.asarray(q, float) + np.array([0.0, -lift, 0.0, 0.0, 0.0, 0.0])
                want = bool(grasp_scene._in_contact_zone(tcp_positions(planner.robot, q[None]))[0])
                assert grasp_scene._tcp_in_zone(q) == want and grasp_scene._tcp_in_zone(q.copy()) == want
                seen[want] += 1
    assert seen[True] > 0 and seen[False] > 0, seen
    assert grasp_scene._zone_at and not grasp_scene.allowing([])._zone_at
