"""Quasi-static settling: objects end supported under their centre of mass, not balanced on a point."""

import numpy as np
import pytest

from kitchenbot.fakes.geometry import build_scene
from kitchenbot.fakes.placement import _Body, _drop, _support_pivot, drop_onto, settle
from kitchenbot.fakes.world import SimWorld
from kitchenbot.transforms import make_T, rot_x
from kitchenbot.world.cell import Cell
from kitchenbot.world.inventory import Inventory


@pytest.fixture(scope="module")
def inventory():
    return Inventory.builtin()


def _tilt_deg(T):
    return float(np.degrees(np.arccos(np.clip(T[2, 2], -1, 1))))


def test_plate_dropped_flat_stays_flat(inventory):
    w = SimWorld(Cell(), inventory)
    u = w.add_object(inventory.by_name("side_plate"), make_T(t=(0.5, 0.0, 0.1)))
    T = settle(w, u, w.objects[u].T_base_obj)
    assert _tilt_deg(T) < 0.5
    floor = w.cell.sink_interior[0][2]
    assert T[2, 3] - inventory.by_name("side_plate").extents[2] / 2 == pytest.approx(floor, abs=0.002)


def test_cup_on_its_side_lies_down(inventory):
    cup = inventory.by_name("cup")
    w = SimWorld(Cell(), inventory)
    u = w.add_object(cup, make_T(rot_x(np.radians(60))[:3, :3], (0.5, 0.0, 0.1)))
    T0 = drop_onto(w, u, w.objects[u].T_base_obj)  # a vertical drop alone leaves it balanced on its rim edge
    T = settle(w, u, w.objects[u].T_base_obj, keep_inside=w.cell.sink_interior)
    assert _tilt_deg(T0) == pytest.approx(60, abs=0.5)
    assert 70 < _tilt_deg(T) < 100  # on its side (the taper tilts the axis a few degrees)
    # Statically stable: the centre of mass is over the support polygon.
    body = _Body.of(cup.mesh)
    scene, _ = build_scene(w, exclude=(u,))
    T2, contacts = _drop(body, T, scene, -1.0)
    com = T2[:3, :3] @ body.com + T2[:3, 3]
    assert _support_pivot(contacts, com[:2], margin=0.0) is None


def test_offset_plate_on_a_plate_tips_onto_it(inventory):
    p = inventory.by_name("side_plate")
    w = SimWorld(Cell(), inventory)
    u1 = w.add_object(p, make_T(t=(0.5, 0.0, 0.1)))
    w.set_pose(u1, settle(w, u1, w.objects[u1].T_base_obj))
    u2 = w.add_object(p, make_T(t=(0.56, 0.0, 0.2)))
    T = settle(w, u2, w.objects[u2].T_base_obj, keep_inside=w.cell.sink_interior)
    assert 2 < _tilt_deg(T) < 30  # rests on the lower plate and the floor, tilted
    assert T[2, 3] > w.objects[u1].T_base_obj[2, 3]


def _hold(w, uid):
    """Make `uid` the held object where it is (release only needs held_uid)."""
    w.held_uid, w.T_tcp_held = uid, np.eye(4)


def test_released_cup_under_a_plate_stays_put(inventory):
    """A cup let go in place stays under the plate lying on its rim; it does not jump up through the plate."""
    w = SimWorld(Cell(), inventory)
    cup = w.add_object(inventory.by_name("cup"), make_T(t=(0.5, 0.0, 0.1)))
    w.set_pose(cup, settle(w, cup, w.objects[cup].T_base_obj))
    plate = w.add_object(inventory.by_name("side_plate"), make_T(t=(0.5, 0.0, 0.3)))
    w.set_pose(plate, drop_onto(w, plate, w.objects[plate].T_base_obj))
    assert w.objects[plate].T_base_obj[2, 3] > w.objects[cup].T_base_obj[2, 3] + 0.03  # lies on the rim
    T0 = w.objects[cup].T_base_obj.copy()
    _hold(w, cup)
    assert w.release() == cup
    assert w.objects[cup].T_base_obj[2, 3] == pytest.approx(T0[2, 3], abs=0.001)


def test_released_cup_falls_onto_the_plate_below(inventory):
    w = SimWorld(Cell(), inventory)
    plate = w.add_object(inventory.by_name("side_plate"), make_T(t=(0.5, 0.0, 0.1)))
    w.set_pose(plate, settle(w, plate, w.objects[plate].T_base_obj))
    cup = w.add_object(inventory.by_name("cup"), make_T(t=(0.5, 0.0, 0.3)))
    T_rest = drop_onto(w, cup, w.objects[cup].T_base_obj)
    _hold(w, cup)
    w.release()
    assert w.objects[cup].T_base_obj[2, 3] == pytest.approx(T_rest[2, 3], abs=0.001)


@pytest.mark.parametrize("sunk", [0.0003, 0.003])
def test_released_cup_sunk_into_a_plate_rises_onto_it(inventory, sunk):
    """Overlapping true poses (a settled stack, a grasp-time overlap) resolve upward, not through the plate."""
    w = SimWorld(Cell(), inventory)
    plate = w.add_object(inventory.by_name("side_plate"), make_T(t=(0.5, 0.0, 0.1)))
    w.set_pose(plate, settle(w, plate, w.objects[plate].T_base_obj))
    cup = w.add_object(inventory.by_name("cup"), make_T(t=(0.5, 0.0, 0.3)))
    T_rest = drop_onto(w, cup, w.objects[cup].T_base_obj)
    T = T_rest.copy()
    T[2, 3] -= sunk
    w.set_pose(cup, T)
    _hold(w, cup)
    w.release()
    assert w.objects[cup].T_base_obj[2, 3] == pytest.approx(T_rest[2, 3], abs=0.001)
