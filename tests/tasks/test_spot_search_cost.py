"""The tasks' spot search (tasks/base.area_spots) builds each candidate's pose and footprint once: the spots it has
already chosen are not re-measured for every later candidate (it scanned a rack's whole grid per target, a few
thousand footprints per item), and its answer stays that of the plain search (first `limit` free spots in order)."""

from __future__ import annotations

import numpy as np

from kitchenbot.tasks import base
from kitchenbot.tasks.base import Placed, area_spots, footprint, inverted
from kitchenbot.transforms import make_T, rot_x, rot_y, rot_z


def _plain(model, lo_xy, hi_xy, z, placed, limit, step):
    """The search written the obvious way (no reuse): every candidate in order, free of the placed and chosen."""
    c = (np.asarray(lo_xy) + np.asarray(hi_xy)) / 2
    nx, ny = (np.ceil((np.asarray(hi_xy) - np.asarray(lo_xy)) / 2 / step) + 1).astype(int)
    grid = sorted([(c[0] + i * step, c[1] + j * step) for i in range(-nx, nx + 1) for j in range(-ny, ny + 1)],
                  key=base.nearest_the_robot)
    out = []
    for xy in grid:
        T = inverted(model, xy, z)
        lo, hi, top = footprint(model, T)
        inside = np.all(lo >= np.asarray(lo_xy) + base.CLEARANCE / 2 - 1e-6) and \
            np.all(hi <= np.asarray(hi_xy) - base.CLEARANCE / 2 + 1e-6)
        others = placed + [Placed(model.obj_id, model.cls, t, *footprint(model, t), None) for t in out]
        if inside and not any(np.all(lo < p.hi + base.CLEARANCE) and np.all(hi > p.lo - base.CLEARANCE)
                              for p in others):
            out.append(T)
            if len(out) >= limit:
                break
    return out


def test_each_candidate_footprint_is_computed_once_and_the_spots_are_the_plain_search_s(inv, monkeypatch):
    cup = inv.by_name("cup")
    lo_xy, hi_xy, z = np.array([0.3, -0.2]), np.array([0.6, 0.2]), 0.1
    # a placed cup near the robot, so that the search skips some candidates before it finds its spots
    T0 = inverted(cup, (0.32, 0.0), z)
    placed = [Placed(cup.obj_id, cup.cls, T0, *footprint(cup, T0), None)]
    want = _plain(cup, lo_xy, hi_xy, z, placed, 6, 0.02)
    calls = []
    real = base.footprint

    def counted(model, T):
        calls.append(T[:2, 3].round(6).tobytes())
        return real(model, T)

    monkeypatch.setattr(base, "footprint", counted)
    got = area_spots(cup, lo_xy, hi_xy, z, placed, inverted, 6)
    assert len(got) == 6 and all(np.array_equal(a, b) for a, b in zip(got, want))
    assert len(calls) == len(set(calls)), "a footprint measured again"


def test_rotations_about_one_axis_are_scipy_s():
    from scipy.spatial.transform import Rotation

    for a in (0.0, 0.3, -1.2, np.pi / 2, np.pi, 5.0):
        for f, ax in ((rot_x, "x"), (rot_y, "y"), (rot_z, "z")):
            T = f(a)
            assert np.allclose(T[:3, :3], Rotation.from_euler(ax, a).as_matrix(), atol=1e-15)
            assert np.array_equal(T[3], [0, 0, 0, 1]) and np.array_equal(T[:3, 3], [0, 0, 0])
    assert np.array_equal(rot_x(np.pi), make_T(Rotation.from_euler("x", np.pi).as_matrix()))
