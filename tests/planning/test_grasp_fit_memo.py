"""Grasp candidates' checks kept across selections (planning.grasps.select_grasps' `memo`) give the same answer as
checking again.

Hand-made on the pile of test_grasp_swivel.py (a cup lying tilted on a dinner plate, a bowl beside both): as the
cup lies, no grasp fits as given and the second pass swivels one; 0.5 mm higher one fits as given. A place filter
that refuses every grasp runs every later pass (swivels, narrowed pads, the three spins), as a pick whose grasps
reach no target does before a staging regrasp. Each selection is made without a memo, then twice with one (the
second answered from what the first kept), and the answers compared: grasps, poses, joints, scores, the counts and
the failure. A neighbour moved by a centimetre is another scene: nothing kept for the first applies to it."""

from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.planning import grasps as grasps_mod
from kitchenbot.planning.grasps import GraspStats

from tests.planning.test_grasp_swivel import Q, _pile


def _select(planner, objects, cup, memo, grasp_filter=None):
    st = GraspStats()
    scene = planner.scene(objects, None, own=[cup])  # a new scene each time, as every plan_pick builds one
    out = grasps_mod.select_grasps(planner.robot, scene, planner.inventory, objects, Q, settings=planner.settings,
                                   target=cup, grasp_filter=grasp_filter, stats=st,
                                   limit=planner.settings.max_grasp_candidates, q_rest=planner.q_rest, memo=memo)
    return out, st


def _same(a, b):
    (out_a, st_a), (out_b, st_b) = a, b
    assert st_a.__dict__ == st_b.__dict__
    if isinstance(out_a, list):
        assert isinstance(out_b, list) and [g.spec.name for g in out_a] == [g.spec.name for g in out_b]
        for ga, gb in zip(out_a, out_b):
            assert ga.obj is gb.obj or ga.obj.instance_id == gb.obj.instance_id
            for x, y in ((ga.T_base_tcp, gb.T_base_tcp), (ga.q, gb.q), (ga.q_pregrasp, gb.q_pregrasp)):
                assert np.array_equal(x, y)
            assert ga.score == gb.score and ga.pad_contacts == gb.pad_contacts
    else:
        assert not isinstance(out_b, list) and out_a.kind == out_b.kind and out_a.details == out_b.details


class _CountIK:
    """Counts the closed-form IK solves (each candidate checked, not answered from the memo, solves its bites)."""

    def __init__(self, robot, monkeypatch):
        self.n = 0
        orig = robot.ik_all_batch

        def counted(*a, **kw):
            self.n += 1
            return orig(*a, **kw)
        monkeypatch.setattr(robot, "ik_all_batch", counted)


@pytest.mark.parametrize("dz", [0.0, 0.0005])
@pytest.mark.parametrize("refuse", [False, True])
def test_kept_checks_give_the_unshared_answer(planner, inventory, dz, refuse, monkeypatch):
    objects, cup = _pile(inventory, dz)
    flt = (lambda o, spec, T: False) if refuse else None
    plain = _select(planner, objects, cup, None, flt)
    if refuse:
        assert plain[0].kind == "no_feasible_placement" and plain[1].no_placement > 0
    else:
        assert isinstance(plain[0], list) and plain[0] and (plain[1].swivelled > 0) == (dz == 0.0)
    memo: dict = {}
    ik = _CountIK(planner.robot, monkeypatch)
    first = _select(planner, objects, cup, memo, flt)
    solved = ik.n
    assert memo and solved > 0
    # the same item in a new scene of the same content, its objects as new instances (a later perception)
    objects2, cup2 = _pile(inventory, dz)
    second = _select(planner, objects2, cup2, memo, flt)
    assert ik.n == solved  # every candidate answered from the memo
    _same(plain, first)
    _same(plain, second)


def test_a_moved_neighbour_is_another_scene(planner, inventory, monkeypatch):
    objects, cup = _pile(inventory, 0.0)
    memo: dict = {}
    _select(planner, objects, cup, memo)
    moved, cup_m = _pile(inventory, 0.0)
    moved[2].T_base_obj = moved[2].T_base_obj.copy()
    moved[2].T_base_obj[0, 3] += 0.01  # the bowl 1 cm away
    ik = _CountIK(planner.robot, monkeypatch)
    kept = _select(planner, moved, cup_m, memo)
    assert ik.n > 0  # checked again
    _same(_select(planner, moved, cup_m, None), kept)


# ---- the place filter's cheap first cut (`approachable`) in the spin selections ----------------------------------

def _rack_filter(planner, inventory, objects, cup, monkeypatch):
    """The place filter Planner.select_grasps makes for the cup towards the rack (mouth down: most grasps from
    above come up from below there), caught on its way to grasps.select_grasps."""
    from kitchenbot.planning import pick_place
    from kitchenbot.planning.placement import SlotBook

    caught = {}
    orig = pick_place.select_grasps

    def catch(*a, **kw):
        caught["flt"] = kw["grasp_filter"]
        return orig(*a, **kw)
    monkeypatch.setattr(pick_place, "select_grasps", catch)
    targets = SlotBook(planner.cell).targets_for(inventory.by_name("cup"))[:4]
    planner.select_grasps(Q, objects, target=cup, place_target=targets)
    monkeypatch.setattr(pick_place, "select_grasps", orig)
    return caught["flt"]


def test_approachable_is_a_necessary_condition_of_the_place_filter(planner, inventory, monkeypatch):
    objects, cup = _pile(inventory, 0.0)
    flt = _rack_filter(planner, inventory, objects, cup, monkeypatch)
    model = inventory[cup.obj_id]
    specs = grasps_mod.expand_grasps(model)[::3] + grasps_mod.spun_grasps(model, 0.5)[::3]
    ok = flt.approachable(cup, np.array([g.T_obj_tcp for g in specs]))
    assert ok.any() and not ok.all()
    for g, y in zip(specs, ok):
        if not y:
            assert not flt(cup, g, cup.T_base_obj @ g.T_obj_tcp), g.name


@pytest.mark.parametrize("spin", [0.0, 0.5])
def test_the_first_cut_leaves_the_spin_selection_as_it_was(planner, inventory, spin, monkeypatch):
    objects, cup = _pile(inventory, 0.0)
    flt = _rack_filter(planner, inventory, objects, cup, monkeypatch)
    plain_flt = lambda o, spec, T: flt(o, spec, T)  # the same filter without its first cut

    def select(f):
        scene = planner.scene(objects, None, own=[cup])
        return grasps_mod.select_grasps(planner.robot, scene, planner.inventory, objects, Q, settings=planner.settings,
                                        target=cup, grasp_filter=f, limit=planner.settings.max_grasp_candidates,
                                        q_rest=planner.q_rest, spin=spin)
    ik = _CountIK(planner.robot, monkeypatch)
    plain = select(plain_flt)
    n_plain = ik.n
    cut = select(flt)
    if isinstance(plain, list):
        assert [g.spec.name for g in plain] == [g.spec.name for g in cut]
        assert all(np.array_equal(a.q, b.q) and a.score == b.score for a, b in zip(plain, cut))
    else:
        assert not isinstance(cut, list) and cut.kind == plain.kind
    if spin:
        assert ik.n - n_plain < n_plain  # fewer candidates checked
