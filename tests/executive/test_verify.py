"""Target presence from one depth view: the object where it should be agrees; an empty spot sees through."""

from __future__ import annotations

import numpy as np

from kitchenbot.executive.verify import target_presence
from kitchenbot.fakes.camera import FakeCamera
from kitchenbot.perception.types import View


def _view(world):
    cam = FakeCamera(world, 640, 480)
    cam.connect()
    f = cam.capture()
    return View(f.rgb, f.depth, f.K, cam.last_true_T_base_cam if cam.last_true_T_base_cam is not None
                else world.T_base_cam(), f.stamp)


def test_present_absent_and_settled_offset(small_config, cup_world):
    cfg = small_config()
    world = cup_world(cfg, 1)
    world.set_joints(np.asarray(cfg.scan_waypoints[0]))
    (uid, obj), = world.objects.items()
    view = _view(world)
    T = obj.T_base_obj.copy()
    here = target_presence(view, obj.model, T)
    assert here.decided and here.present and here.agree > 0.7
    above = T.copy()
    above[2, 3] += 0.03  # released 3 cm higher: it settled; the search finds the offset
    settled = target_presence(view, obj.model, above)
    assert settled.present and abs(settled.dz + 0.03) <= 0.006
    high = T.copy()
    high[2, 3] += 0.05  # expected 5 cm higher (on a stack): what is 5 cm below is not it settling
    assert not target_presence(view, obj.model, high).present
    empty = T.copy()
    empty[:2, 3] += (-0.12, 0.10)  # an empty spot on the sink floor
    empty[2, 3] = T[2, 3]
    gone = target_presence(view, obj.model, empty)
    assert gone.decided and not gone.present
    away = T.copy()
    away[:3, 3] = (-1.0, 2.0, 0.5)  # out of view: no decision
    assert not target_presence(view, obj.model, away).decided
