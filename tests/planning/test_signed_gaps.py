"""Scene.signed_gaps gives the bisection's answers, bit for bit, with fewer collision checks where the two are apart.

Hand-made: the bowl lying tilted on the rim of a stack of plates (tests/planning/test_lift_foot_under_rim.py), its
pick planned; every signed-gap profile the planner asked for along its lifts (the held bowl against the plates it
touches at the grasp, at each lift's half-step samples) is computed again by the plain bisection on the security
margin (below, as Scene.signed_gaps ran it before: ~12 collision checks per sample within the span) and compared.
Where the two are apart the bisection's last bracket is predicted from one distance query and checked at its ends;
a prediction the checks refuse falls back to the bisection, so the answer is the same either way."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from kitchenbot.planning import collision as collision_mod
from kitchenbot.transforms import from_rotvec
from tests.planning.test_lift_foot_under_rim import (BOWL, BOWL_FIT, MID_PLATE, MID_PLATE_FIT, Q_SCAN, TOP_PLATE,
                                                     TOP_PLATE_FIT)


def _bisected(scene, Q, pair, span, tol):
    """The signed gaps by bisection alone (Scene.signed_gaps before the distance query)."""
    out = np.full(len(Q), float(span))
    k = scene._pair_index(pair)
    other = scene._variant()
    req = other.gd.collisionRequests[k]

    def within(m):
        req.security_margin = m
        return bool(pin.computeCollision(scene.gm, other.gd, k))

    for i, q in enumerate(Q):
        pin.updateGeometryPlacements(scene.model, other.data, scene.gm, other.gd, q)
        if not within(span):
            continue
        if within(-span):
            out[i] = -float(span)
            continue
        lo, hi = scene._switch(lambda m: not within(m), -float(span), float(span), tol)
        out[i] = (lo + hi) / 2
    return out


def test_signed_gaps_are_the_bisections_with_fewer_checks(planner, sim_items, monkeypatch):
    asked = []
    signed_gaps = collision_mod.Scene.signed_gaps

    def recorded(scene, Q, pair, span, tol=2e-5):
        asked.append((scene, np.array(Q, float), pair, span, tol))
        return signed_gaps(scene, Q, pair, span, tol)

    monkeypatch.setattr(collision_mod.Scene, "signed_gaps", recorded)
    world, (bowl, top, mid) = sim_items([(name, from_rotvec(*true), from_rotvec(*fit)) for name, true, fit in (
        ("bowl", BOWL, BOWL_FIT), ("dinner_plate", TOP_PLATE, TOP_PLATE_FIT),
        ("dinner_plate", MID_PLATE, MID_PLATE_FIT))])
    assert planner.plan_pick(Q_SCAN, [bowl, top, mid], target=bowl).ok
    monkeypatch.undo()
    assert asked

    checks = [0]
    collide = pin.computeCollision

    def counted(*a):
        checks[0] += 1
        return collide(*a)

    monkeypatch.setattr(pin, "computeCollision", counted)
    apart = 0
    spent = {}
    for name, f in (("bisection", _bisected), ("signed_gaps", signed_gaps)):
        checks[0] = 0
        out = [f(*a) for a in asked]
        spent[name] = (checks[0], out)
    for (scene, Q, pair, span, tol), a, b in zip(asked, spent["bisection"][1], spent["signed_gaps"][1]):
        assert np.array_equal(a, b), pair  # the same gaps, to the last bit
        apart += int(np.sum((a > 0) & (a < span)))
    assert apart > 20  # the bowl parts from the plates within the span along its lifts
    assert spent["signed_gaps"][0] < 0.7 * spent["bisection"][0], (spent["signed_gaps"][0], spent["bisection"][0])


def test_the_predicted_bracket_is_the_bisections():
    """_switch_at follows the bisection's own midpoints: for a predicate that switches at x it ends where _switch
    does, whatever x (on the midpoints themselves too)."""
    span, tol = 0.006, 2e-5
    mids = []
    collision_mod.Scene._switch(lambda m: mids.append(m) or True, -span, span, tol)
    for x in [-0.0059, -0.0031, -1e-7, 0.0, 1e-7, 0.00123, 0.004999, 0.0059] + mids[:5]:
        assert collision_mod.Scene._switch_at(x, -span, span, tol) == \
            collision_mod.Scene._switch(lambda m: x > m, -span, span, tol)
