"""A mug among neighbours is fitted by its body; its handle, mostly hidden, is what settles the turn about its axis,
so the fit may be turned (23.5 degrees in a traced protective stop: the lift of the item resting against it met
the real handle). The map then holds nothing where the real handle is (only the body was seen, and the model
explains the body), and the model's handle is elsewhere: the held item's scene must keep clear of where the handle
may be (planning/unseen_parts.py), and the grasp's scene (nothing held) is not changed by it."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from kitchenbot.planning.types import Grasp
from kitchenbot.planning.unseen_parts import TURN_UNCERTAINTY, off_axis_part
from kitchenbot.transforms import rot_z, trans


def _in_voxels(P, vox, half):
    if len(vox) == 0:
        return np.zeros(len(P), bool)
    return np.all(np.abs(P[:, None] - vox[None]) <= half + 1e-9, axis=2).any(axis=1)


def _turned_mug(planner, resting, deg):
    mug = resting("mug", (0.50, 0.0), 1)
    m = planner.inventory[mug.obj_id]
    c, handle = off_axis_part(m)
    T_true = mug.T_base_obj
    # about the body's axis (the vertical through c in the object frame)
    T_fit = T_true @ trans(*c) @ rot_z(np.radians(deg)) @ trans(*(-c))
    # what the views saw: the body only (the handle hidden by neighbours), 2 mm noise
    rng = np.random.default_rng(5)
    S = np.asarray(m.mesh.sample_points_uniformly(4000).points)
    body = S[np.linalg.norm(S[:, :2] - c[:2], axis=1) < np.min(np.linalg.norm(handle[:, :2] - c[:2], axis=1))]
    seen = body @ T_true[:3, :3].T + T_true[:3, 3] + rng.normal(0, 0.002, (len(body), 3))
    true_handle = handle @ T_true[:3, :3].T + T_true[:3, 3]
    return replace(mug, T_base_obj=T_fit, points=seen), m, seen, true_handle


def _held_cup(planner, resting):
    cup = resting("cup", (0.50, 0.12), 2)
    mc = planner.inventory[cup.obj_id]
    spec = mc.grasps[0]
    T_tcp = cup.T_base_obj @ spec.T_obj_tcp
    return cup, Grasp(spec, cup, T_tcp, np.zeros(6), np.zeros(6), T_tcp)


def test_a_neighbours_handle_turned_out_of_the_fit_is_kept_clear_of_by_the_held_item(planner, resting):
    assert np.radians(23.5) < TURN_UNCERTAINTY
    mug, m, seen, true_handle = _turned_mug(planner, resting, 23.5)
    # the real handle lies where neither the fitted model nor the map's points are
    from kitchenbot.planning.collision import _surface_distance

    T = mug.T_base_obj
    d = _surface_distance(m, (true_handle - T[:3, 3]) @ T[:3, :3])
    assert np.mean(d > 0.01) > 0.5
    cup, g = _held_cup(planner, resting)
    held_scene = planner.scene([mug, cup], seen, exclude=cup, held=g, own=[cup])
    half = planner.world.voxel_size / 2
    # before: no voxel at all (the body's points are the model's); the real handle was free space to the lift
    assert _in_voxels(true_handle, held_scene.voxels, half).mean() > 0.9
    # the grasp's scene is unchanged: the body's points explained, no voxel
    assert len(planner.scene([mug, cup], seen, own=[cup]).voxels) == 0


def test_the_held_mug_and_an_item_put_down_get_no_sweep(planner, resting):
    """Only perceived neighbours: not the held item (what the pads close on), not a record of an item the robot put
    down (no observed points: its pose is the one it was put down at)."""
    mug, m, seen, _ = _turned_mug(planner, resting, 0.0)
    spec = m.grasps[0]
    T_tcp = mug.T_base_obj @ spec.T_obj_tcp
    g = Grasp(spec, mug, T_tcp, np.zeros(6), np.zeros(6), T_tcp)
    assert len(planner.scene([mug], seen, exclude=mug, held=g, own=[mug]).voxels) == 0
    placed = replace(mug, points=np.zeros((0, 3)))
    cup, gc = _held_cup(planner, resting)
    assert len(planner.scene([placed, cup], None, exclude=cup, held=gc, own=[cup]).voxels) == 0
