"""Verification parts on hand-made point sets (perception/verify.py): the map's surface noise, and the share of a
segment on a posed model at the sensor's precision."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from kitchenbot.perception.verify import fine_share, fine_tolerance, surface_noise
from kitchenbot.transforms import make_T, rot_x


def _plane(sigma: float, n: int = 20000, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    P = np.column_stack([rng.uniform(0, 0.3, n), rng.uniform(0, 0.3, n), rng.normal(0, sigma, n)])
    return P


def test_surface_noise_follows_the_depth_noise():
    """On a plane with Gaussian noise along its normal the estimate is near the noise and grows with it."""
    est = [surface_noise(_plane(s)) for s in (0.0005, 0.001, 0.002)]
    assert est[0] < est[1] < est[2]
    for s, e in zip((0.0005, 0.001, 0.002), est):
        assert 0.6 * s < e < 1.2 * s, (s, e)
    assert surface_noise(np.zeros((10, 3))) == 0.0  # too few points: no estimate
    assert fine_tolerance(0.0) == 0.003 and abs(fine_tolerance(0.002) - 0.008) < 1e-12


def _cup_surface(entry, T, sigma: float, seed: int = 0):
    """Points of the posed model's surface seen from above and the side (normals facing +x +z), with noise."""
    rng = np.random.default_rng(seed)
    P, N = entry.dense_points, entry.dense_normals
    keep = N @ np.array([0.6, 0.0, 0.8]) > 0.2
    P = P[keep] @ T[:3, :3].T + T[:3, 3]
    N = N[keep] @ T[:3, :3].T
    return P + rng.normal(0, sigma, P.shape) * N, N


def test_fine_share_tells_the_right_shape_from_one_millimetres_off(perceiver):
    entry = perceiver.database[4]  # the cup
    T = make_T(np.eye(3), np.array([0.4, 0.0, 0.05]))
    P, N = _cup_surface(entry, T, 0.001)
    tol = fine_tolerance(0.001)
    assert fine_share(P, N, entry, T, tol) > 0.9
    # The same points 15 % farther from the axis (4-6 mm: a cylinder of about the cup's size): mostly off.
    Q = P.copy()
    Q[:, :2] = T[:2, 3] + 1.15 * (P[:, :2] - T[:2, 3])
    assert fine_share(Q, N, entry, T, tol) < 0.5
    # A pose tilted 6 degrees about its centre (rim and base up to 5 mm off) is judged as the segment's best
    # fit near it (a short ICP): an occluded item's fit a few millimetres off is not taken for a wrong shape.
    T_tilt = T @ make_T(rot_x(np.radians(6))[:3, :3], np.zeros(3))
    assert fine_share(P, N, entry, T_tilt, tol) > 0.9


def test_points_another_pose_explains_do_not_count(perceiver):
    """A neighbour's points in the segment (touching items segmented together) count neither way."""
    cup, plate = perceiver.database[4], perceiver.database[2]
    T_cup = make_T(np.eye(3), np.array([0.4, 0.0, 0.05]))
    T_plate = make_T(np.eye(3), np.array([0.4, 0.15, 0.01]))
    Pc, Nc = _cup_surface(cup, T_cup, 0.001)
    Pp, Np = _cup_surface(plate, T_plate, 0.001, seed=1)
    P, N = np.vstack([Pc, Pp[: len(Pc)]]), np.vstack([Nc, Np[: len(Pc)]])
    tol = fine_tolerance(0.001)
    alone = fine_share(P, N, cup, T_cup, tol)
    assert alone < 0.6
    assert fine_share(P, N, cup, T_cup, tol, [(plate, T_plate)]) > 0.9


def _cylinder_side(radius: float, z0: float, z1: float, n: int = 6000, seed: int = 1) -> np.ndarray:
    """Points on the half of a cylinder's side facing +x (object frame, axis z), as a camera from +x sees it."""
    rng = np.random.default_rng(seed)
    a = rng.uniform(-np.pi / 2, np.pi / 2, n)
    return np.column_stack([radius * np.cos(a), radius * np.sin(a), rng.uniform(z0, z1, n)])


def test_a_surface_going_on_past_the_models_end_is_continuation(perceiver, inventory):
    """A cup lying on its side: its own points leave nothing past its rim or base; a bottle's body that the cup
    covers goes on past the base (a longer cylinder), and those points count, unless another pose explains
    them (a neighbour touching the base)."""
    from kitchenbot.perception.register import on_surface
    from kitchenbot.perception.verify import continuation

    entry, model = perceiver.database[4], inventory[4]
    T = make_T(rot_x(np.pi / 2)[:3, :3], np.array([0.4, 0.0, 0.05]))  # lying: axis along -y
    own, _ = _cup_surface(entry, T, 0.0005)
    mine = on_surface(own, None, entry, T, 0.004)
    assert continuation(own, model.points, T, mine, len(own)) < 0.02
    # The bottle: a cylinder of the cup's base radius, 8 cm on from the base (object z < 0).
    r_base = np.linalg.norm(model.points[model.points[:, 2] < model.points[:, 2].min() + 0.005, :2]
                            - np.median(model.points[:, :2], axis=0), axis=1).max()
    body = _cylinder_side(r_base, model.points[:, 2].min() - 0.08, model.points[:, 2].min())
    body = body @ T[:3, :3].T + T[:3, 3]
    P = np.vstack([own, body])
    explained = on_surface(P, None, entry, T, 0.004)
    c = continuation(P, model.points, T, explained, len(own))
    assert c > 0.2, c
    # The same points explained by another pose: nothing unexplained continues.
    assert continuation(P, model.points, T, explained | (np.arange(len(P)) >= len(own)), len(own)) < 0.02


def test_a_standing_vessel_is_continued_along_its_axis_not_across_it(perceiver, inventory):
    """A cup upside down (standing on its rim): an upright bottle's body and neck going on past its base, within
    the base's radius, are continuation; a plate lying across that end, or the board the cup stands on, reach
    out wider than the end: something across the axis, not the same body going on, so that end is not judged.
    (Lying vessels are judged as before: `only_along` off.)"""
    from kitchenbot.perception.register import on_surface
    from kitchenbot.perception.verify import continuation

    entry, model = perceiver.database[4], inventory[4]
    T = make_T(rot_x(np.pi)[:3, :3], np.array([0.4, 0.0, 0.10]))  # upside down: the base (object z0) on top
    own, _ = _cup_surface(entry, T, 0.0005)
    z0 = model.points[:, 2].min()
    # A bottle's body (a little narrower than the base) going on 1.5 cm past the base, then a neck 1.5 cm on.
    body = np.vstack([_cylinder_side(0.027, z0 - 0.015, z0), _cylinder_side(0.012, z0 - 0.03, z0 - 0.015, 2000)])
    P = np.vstack([own, body @ T[:3, :3].T + T[:3, 3]])
    explained = on_surface(P, None, entry, T, 0.004)
    along = continuation(P, model.points, T, explained, len(own), only_along=True)
    assert along > 0.2, along
    # A plate lying across the base: a disk of 10 cm radius 1 cm past it. Within the base's radius it is "past
    # the end" just as the bottle was, but it reaches out across the axis.
    plate = _disk(0.10, z0 - 0.01, 12000) @ T[:3, :3].T + T[:3, 3]
    P = np.vstack([own, plate])
    explained = on_surface(P, None, entry, T, 0.004)
    assert continuation(P, model.points, T, explained, len(own)) > 0.2  # judged when lying (as before)
    assert continuation(P, model.points, T, explained, len(own), only_along=True) < 0.02
    # The board it stands on (under its rim, object z1 end): across, not judged either.
    z1 = model.points[:, 2].max()
    board = _disk(0.15, z1 + 0.002, 20000) @ T[:3, :3].T + T[:3, 3]
    P = np.vstack([own, board])
    explained = on_surface(P, None, entry, T, 0.004)
    assert continuation(P, model.points, T, explained, len(own), only_along=True) < 0.02


def _disk(radius: float, z: float, n: int = 3000, seed: int = 2) -> np.ndarray:
    """Points on a flat disk across the object z axis at height z (object frame): a lid."""
    rng = np.random.default_rng(seed)
    r, a = radius * np.sqrt(rng.uniform(0, 1, n)), rng.uniform(0, 2 * np.pi, n)
    return np.column_stack([r * np.cos(a), r * np.sin(a), np.full(n, z)])


def test_a_lid_across_the_opening_fills_the_cavity(perceiver, inventory):
    """A cup's cavity shows its own inner wall and floor: nothing unexplained fills it. A closed cylinder fitted
    by the cup (a drink can) shows its lid across the opening at the rim: those points fill the cavity, unless
    another pose explains them (an item nested in the cup); upright or lying, it is judged in the cup's frame.
    Points beside the cup (a neighbour) do not count."""
    from kitchenbot.perception.register import on_surface
    from kitchenbot.perception.verify import filled

    entry, model = perceiver.database[4], inventory[4]
    z1 = model.points[:, 2].max()
    r_rim = np.linalg.norm(model.points[model.points[:, 2] > z1 - 0.005, :2]
                           - np.median(model.points[:, :2], axis=0), axis=1).max()
    for T in (make_T(np.eye(3), np.array([0.4, 0.0, 0.05])),
              make_T(rot_x(np.pi / 2)[:3, :3], np.array([0.4, 0.0, 0.05]))):  # upright; lying (axis along -y)
        own, _ = _cup_surface(entry, T, 0.0005)
        mine = on_surface(own, None, entry, T, 0.004)
        assert filled(own, model.points, T, mine, len(own)) < 0.02
        lid = _disk(r_rim - 0.002, z1) @ T[:3, :3].T + T[:3, 3]
        beside = (_disk(r_rim, z1) + np.array([2.5 * r_rim, 0.0, 0.0])) @ T[:3, :3].T + T[:3, 3]
        P = np.vstack([own, lid, beside])
        explained = on_surface(P, None, entry, T, 0.004)
        f = filled(P, model.points, T, explained, len(own))
        assert f > 0.2, f
        P2 = np.vstack([own, beside])
        assert filled(P2, model.points, T, on_surface(P2, None, entry, T, 0.004), len(own)) < 0.02
        # The lid explained by another pose: nothing unexplained fills the cup.
        assert filled(P, model.points, T, explained | (np.arange(len(P)) >= len(own)), len(own)) < 0.02


def test_a_pose_that_fails_explains_nothing_for_its_neighbour(perceiver, inventory):
    """A lying cup over the first part of a bottle's body (the body goes on 3 cm past its base) and a second cup
    fitted 3 cm further along, which puts its surface where the body goes on. While the second cup counts,
    the first one's `continued` sees nothing; the second one fails the verification (its model is seen through),
    so it explains nothing: the first one is judged again without it and fails too. When the second one passes,
    the first one keeps its verification."""
    from kitchenbot.perception.map import InstanceMap
    from kitchenbot.perception.register import Hypothesis
    from kitchenbot.perception.verify import Verification

    entry, model = perceiver.database[4], inventory[4]
    T = make_T(rot_x(np.pi / 2)[:3, :3], np.array([0.4, 0.0, 0.05]))  # lying: axis along -y
    own, _ = _cup_surface(entry, T, 0.0005)
    z0 = model.points[:, 2].min()
    r_base = np.linalg.norm(model.points[model.points[:, 2] < z0 + 0.005, :2]
                            - np.median(model.points[:, :2], axis=0), axis=1).max()
    body = _cylinder_side(r_base, z0 - 0.03, z0)
    body = body[body[:, 0] > -0.3 * r_base]  # the side the cameras see
    body = body @ T[:3, :3].T + T[:3, 3]
    T2 = T @ make_T(np.eye(3), np.array([0.0, 0.0, -0.03]))  # 3 cm along the axis towards the body
    second, _ = _cup_surface(entry, T2, 0.0005, seed=1)
    points = np.vstack([own, second, body])
    ids = np.r_[np.zeros(len(own), int), np.ones(len(second), int), np.full(len(body), 2)]
    m = InstanceMap(points, ids, np.zeros(len(points), int), np.zeros((len(points), 2), int),
                    np.array([[0.8, 0.0, 0.6]]))
    for second_free, first_passes in ((0.0, True), (0.8, False)):
        a = Hypothesis(4, T, verification=Verification(seen=0.9, explained=1.0, free_space=0.0, normals=1.0))
        b = Hypothesis(4, T2, verification=Verification(seen=1.0 - second_free, explained=1.0,
                                                        free_space=second_free, normals=1.0))
        perceiver._fine_check(m, [(a, 0, np.nonzero(ids == 0)[0]), (b, 1, np.nonzero(ids == 1)[0])])
        assert (a.verification.score >= perceiver.settings.verify_threshold) == first_passes, \
            (second_free, a.verification, b.verification)


def test_a_lid_wider_than_the_base_overhangs_it(perceiver, inventory):
    """A glass upside down: its own points end at its base's edge, and nothing unexplained lies in the base's
    plane beyond it. A drink can wider than the glass's base, fitted by it, shows its lid there (a ring 4-20 mm
    past the edge): those points overhang, unless another pose explains them. A surface in the base's plane
    farther out (a neighbour's top) or well off the plane does not count."""
    from kitchenbot.perception.register import on_surface
    from kitchenbot.perception.verify import overhang

    entry, model = perceiver.database[6], inventory[6]  # the glass
    T = make_T(rot_x(np.pi)[:3, :3], np.array([0.4, 0.0, 0.08]))  # upside down: its base at the top
    own, _ = _cup_surface(entry, T, 0.0005)
    z0 = model.points[:, 2].min()
    r_base = np.linalg.norm(model.points[model.points[:, 2] < z0 + 0.005, :2]
                            - np.median(model.points[:, :2], axis=0), axis=1).max()
    mine = on_surface(own, None, entry, T, 0.004)
    assert overhang(own, model.points, T, mine, len(own)) < 0.01
    lid = _disk(r_base + 0.012, z0, n=6000)
    ring = lid[np.linalg.norm(lid[:, :2], axis=1) > r_base + 0.005]
    far = _disk(r_base + 0.06, z0, n=6000)
    far = far[np.linalg.norm(far[:, :2], axis=1) > r_base + 0.03]  # a neighbour's top, a hand's width away
    below = ring + np.array([0.0, 0.0, 0.02])  # off the base's plane
    for extra, expect_over in ((ring, True), (far, False), (below, False)):
        P = np.vstack([own, extra @ T[:3, :3].T + T[:3, 3]])
        explained = on_surface(P, None, entry, T, 0.004)
        o = overhang(P, model.points, T, explained, len(own))
        assert (o > 0.15) == expect_over, o
    # the ring explained by another pose: nothing overhangs
    P = np.vstack([own, ring @ T[:3, :3].T + T[:3, 3]])
    assert overhang(P, model.points, T, np.arange(len(P)) >= 0, len(own)) == 0.0


def test_what_lies_on_one_side_of_a_standing_vessels_rim_is_not_continuation(perceiver, inventory):
    """A mug standing upright, half hidden, with a cup lying across its rim on one side: the cup's pose explains
    its body but not the part that rests on the rim (there the fit is a few millimetres off). That patch lies past
    the mug's rim within the rim's radius + 1 cm and not in the ring 2-5 cm wider, as a bottle going on would;
    but it covers one side of the axis only (~90-120 deg), where a bottle's body, a closed surface round the
    axis, is seen over a wide arc. The rim is not judged; a bottle's body seen over half its circumference past the
    rim still is. (Development table scene: an upright mug lost to `continued` 0.18 under a leaning cup.)"""
    from kitchenbot.perception.register import on_surface
    from kitchenbot.perception.verify import around_span, continuation

    entry, model = perceiver.database[5], inventory[5]
    T = make_T(np.eye(3), np.array([0.4, 0.0, 0.05]))
    own, _ = _cup_surface(entry, T, 0.0005)
    own = own[own[:, 1] > T[1, 3]]  # the half the neighbour does not hide
    spacing = np.median(cKDTree(own).query(own, k=2)[0][:, 1])
    z1 = model.points[:, 2].max()
    r_rim = np.linalg.norm(model.points[model.points[:, 2] > z1 - 0.005, :2]
                           - np.median(model.points[:, :2], axis=0), axis=1).max()
    # The lying cup's body: a cylinder of 4 cm radius across the +x side of the rim (its axis along y), resting on
    # it.
    R, a = 0.04, np.arange(0, 2 * np.pi, spacing / 0.04)
    a, y = (g.ravel() for g in np.meshgrid(a, np.arange(-0.05, 0.05, spacing)))
    body = np.column_stack([r_rim + R * np.sin(a), y, z1 + R - R * np.cos(a)])
    # Left unexplained: what of it lies within 4 cm of where it touches the rim, up to 3 cm over the rim and
    # within the rim's radius + 1 cm (the rest its pose explains).
    h, r = body[:, 2] - z1, np.linalg.norm(body[:, :2], axis=1)
    patch = body[(np.linalg.norm(body - np.array([r_rim, 0.0, z1]), axis=1) < 0.04) & (h > 0) & (h < 0.03) &
                 (r < r_rim + 0.01)]
    P = np.vstack([own, patch + T[:3, 3]])
    explained = on_surface(P, None, entry, T, 0.004)
    assert around_span(patch[:, :2]) <= 120
    assert continuation(P, model.points, T, explained, len(own)) > 0.15  # judged when lying (as before)
    assert continuation(P, model.points, T, explained, len(own), only_along=True) < 0.02
    # A bottle's body (as wide as the rim) going on 3 cm past it, seen from one side (half its circumference).
    bottle = _cylinder_side(r_rim, z1, z1 + 0.03, int(np.pi * r_rim * 0.03 / spacing**2))  # as dense as the mug
    P = np.vstack([own, bottle + T[:3, 3]])
    explained = on_surface(P, None, entry, T, 0.004)
    assert around_span(bottle[:, :2]) >= 150
    assert continuation(P, model.points, T, explained, len(own), only_along=True) > 0.15


def _tilted_plane(centre: np.ndarray, normal: np.ndarray, radius: float, n: int = 8000, seed: int = 3) -> np.ndarray:
    """Points on a flat disk (object frame) through `centre` with the given normal: a neighbour's surface."""
    rng = np.random.default_rng(seed)
    normal = normal / np.linalg.norm(normal)
    u = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    r, a = radius * np.sqrt(rng.uniform(0, 1, n)), rng.uniform(0, 2 * np.pi, n)
    return centre + np.outer(r * np.cos(a), u) + np.outer(r * np.sin(a), v)


def test_a_surface_through_the_wall_of_a_vessel_facing_down_intrudes(perceiver, inventory):
    """A glass fitted upside down (tilted) over a drink can: its own points (the can's side and lid, on the
    glass's surface) end where the can ends, two thirds along it; past that the glass's wall would pass through
    the surface the can rests on (a plate or a bowl seen there, crossing its axis at 50 deg). Those points lie
    inside the glass's cavity: `intruded` well over the 0.02 at which the verification rejects it. The same
    surface past the glass's rim (outside it), or a right glass whose own points go on to its rim with a
    neighbour's surface beside it, leave nothing inside. (Development sink scenes: glasses kept on cans with
    verification 0.91-0.99.)"""
    from kitchenbot.perception.register import on_surface
    from kitchenbot.perception.verify import INTRUDED_FULL, Verification, intruded

    entry, model = perceiver.database[6], inventory[6]  # the glass
    z0, z1 = model.points[:, 2].min(), model.points[:, 2].max()
    T = make_T(rot_x(np.radians(130))[:3, :3], np.array([0.4, 0.0, 0.08]))  # opening down and to the side
    own, _ = _cup_surface(entry, T, 0.0005)
    Ti = np.linalg.inv(T)
    q_own = own @ Ti[:3, :3].T + Ti[:3, 3]
    can = own[q_own[:, 2] < z0 + 0.08]  # an 8 cm can covered by the 12 cm glass
    tilt = np.array([0.0, np.sin(np.radians(50)), np.cos(np.radians(50))])
    crossing = _tilted_plane(np.array([0.0, 0.0, z0 + 0.1]), tilt, 0.07)
    beyond = crossing + np.array([0.0, 0.0, z1 - z0])  # the same surface past the rim, outside the glass
    beside = _tilted_plane(np.array([0.07, 0.0, 0.0]), np.array([1.0, 0.0, 0.0]), 0.03)  # a neighbour's side
    for mine, extra, expect in ((can, crossing, True), (can, beyond, False), (own, beside, False), (can, None, False)):
        P = mine if extra is None else np.vstack([mine, extra @ T[:3, :3].T + T[:3, 3]])
        x = intruded(P, model.points, T, on_surface(P, None, entry, T, 0.003))
        assert (x > 0.15 * INTRUDED_FULL) == expect, (expect, x)
        v = Verification(seen=1.0, explained=1.0, free_space=0.0, normals=1.0, intruded=x)
        assert (v.score < perceiver.settings.verify_threshold) == expect


def test_only_an_item_nested_in_a_vessel_explains_its_cavity(perceiver, inventory):
    """A cup upside down with a copy nested in it (the copy's surface inside its cavity, within its wall): the
    nested pose explains its points and the cup is not intruded on. A cup lying across the first one's axis
    through its wall explains nothing there: its surface inside the cavity counts. An upright or a lying cup is
    not judged (things are put into an open vessel facing up, or poke into a lying one's mouth)."""
    from kitchenbot.perception.map import InstanceMap
    from kitchenbot.perception.register import Hypothesis
    from kitchenbot.perception.verify import INTRUDED_FULL, Verification

    entry, model = perceiver.database[4], inventory[4]  # the cup

    def hyp(T):
        return Hypothesis(4, T, verification=Verification(seen=1.0, explained=1.0, free_space=0.0, normals=1.0))

    def dense(T):  # the posed model's surface all round
        return entry.dense_points @ T[:3, :3].T + T[:3, 3]

    for flip, judged in ((np.pi, True), (0.0, False), (np.pi / 2, False)):
        T = make_T(rot_x(flip)[:3, :3], np.array([0.4, 0.0, 0.08]))
        own, _ = _cup_surface(entry, T, 0.0005)
        T_in = T @ make_T(np.eye(3), np.array([0.0, 0.0, model.nest_pitch]))
        T_across = T @ make_T(rot_x(np.pi / 2)[:3, :3], np.array([0.0, 0.0, 0.04]))
        for T2, counts in ((T_in, False), (T_across, True)):
            pts = np.vstack([own, dense(T2)])
            m = InstanceMap(pts, np.zeros(len(pts), int), np.zeros(len(pts), int), np.zeros((len(pts), 2), int),
                            np.array([[0.8, 0.0, 0.6]]))
            a, b = hyp(T), hyp(T2)
            x = perceiver._intruded(m, cKDTree(pts), 0.003, a, [(a, 0, None), (b, 1, None)])
            assert (x > 0.15 * INTRUDED_FULL) == (counts and judged), (flip, counts, x)


def test_a_vessel_facing_down_fitted_a_little_off_is_judged_where_its_own_points_put_it(perceiver, inventory):
    """A glass standing upside down on a floor, seen from above (its base and outer wall, the floor up to its rim):
    fitted 6 deg tilted (a right pose, within 0.1 diameter), the floor beside the rim lies inside the model's wall
    near the rim, and `intruded` read 0.10 there on the pose as given (rejected above 0.02). The cavity is read at the pose the fine
    check nudged onto the glass's own points: nothing inside. A glass fitted over a drink can (its own points end
    two thirds along it) with a surface crossing its cavity past the can's end, fitted as given or tilted alike,
    is still intruded on: that surface stays inside wherever the fit is slid."""
    from kitchenbot.perception.map import InstanceMap
    from kitchenbot.perception.register import Hypothesis
    from kitchenbot.perception.verify import INTRUDED_FULL, Verification

    entry, model = perceiver.database[6], inventory[6]  # the glass
    z0, z1 = model.points[:, 2].min(), model.points[:, 2].max()
    T = make_T(rot_x(np.pi)[:3, :3], np.array([0.4, 0.0, z1]))  # upside down, its rim on the floor z = 0
    keep = entry.dense_normals @ np.array([0.3, 0.0, -0.95]) > 0.2  # the outside seen from above
    glass = entry.dense_points[keep] @ T[:3, :3].T + T[:3, 3]
    rng = np.random.default_rng(1)
    floor = np.column_stack([rng.uniform(0.25, 0.55, 30000), rng.uniform(-0.15, 0.15, 30000), np.zeros(30000)])
    r_rim = np.linalg.norm(model.points[:, :2] - np.median(model.points[:, :2], axis=0), axis=1).max()
    floor = floor[np.linalg.norm(floor[:, :2] - [0.4, 0.0], axis=1) > r_rim + 0.002]
    q = glass @ T[:3, :3] - T[:3, 3] @ T[:3, :3]  # object frame
    can = glass[q[:, 2] < z0 + 0.08]  # an 8 cm can under the 12 cm glass
    tilt = np.array([0.0, np.sin(np.radians(50)), np.cos(np.radians(50))])
    crossing = _tilted_plane(np.array([0.0, 0.0, z0 + 0.1]), tilt, 0.07) @ T[:3, :3].T + T[:3, 3]
    centre = np.array([0.4, 0.0, z1 / 2])
    tilted = make_T(np.eye(3), centre) @ make_T(rot_x(np.radians(6))[:3, :3], np.zeros(3)) @ \
        make_T(np.eye(3), -centre) @ T
    for own_pts, extra, expect in ((glass, floor, False), (can, crossing, True)):
        pts = np.vstack([own_pts, extra])
        m = InstanceMap(pts, np.zeros(len(pts), int), np.zeros(len(pts), int), np.zeros((len(pts), 2), int),
                        np.array([[0.6, 0.0, 0.8]]))
        for T_fit in (T, tilted):
            h = Hypothesis(6, T_fit, verification=Verification(seen=1.0, explained=1.0, free_space=0.0, normals=1.0))
            perceiver._fine_parts(m, cKDTree(pts), 0.003, h, np.arange(len(own_pts)), [(h, 0, None)])
            assert (h.verification.intruded > 0.15 * INTRUDED_FULL) == expect, (expect, h.verification.intruded)


def test_a_vessel_standing_on_something_narrow_is_not_continued_by_it(perceiver, inventory):
    """A glass standing upright on a drink can (its base on the can's lid, the can's side seen 3 cm down under it,
    a little narrower than the base) or nested in another glass (whose wall goes on under its base): what lies
    under a standing vessel's base within its footprint is what it stands on, not the same body going on, so the
    pose passes. On the base code the can's side read as continuation (a bottle going on past the base) and the
    glass was rejected. An upright glass fitted over the lower part of an upright bottle, whose shoulder and neck
    go on past its rim, is still rejected; so is the same glass lying (its base end judged as before)."""

    entry, model = perceiver.database[6], inventory[6]  # the glass
    z0, z1 = model.points[:, 2].min(), model.points[:, 2].max()
    axis = np.median(model.points[:, :2], axis=0)
    r_base = np.linalg.norm(model.points[model.points[:, 2] < z0 + 0.005, :2] - axis, axis=1).max()
    r_rim = np.linalg.norm(model.points[model.points[:, 2] > z1 - 0.005, :2] - axis, axis=1).max()
    upright = make_T(np.eye(3), np.array([0.4, 0.0, 0.16]))
    lying = make_T(rot_x(np.pi / 2)[:3, :3], np.array([0.4, 0.0, 0.05]))

    def verdict(T, extra):
        own, _ = _cup_surface(entry, T, 0.0005)
        extra = extra[extra[:, 0] > -0.3 * np.abs(extra[:, :2]).max()]  # the side the cameras see
        return _fine_verdict(perceiver, 6, T, own, extra)

    can = _cylinder_side(r_base - 0.002, z0 - 0.03, z0)  # a can's side under the base
    ver = verdict(upright, can)
    assert ver.continued < 0.02 and ver.score >= perceiver.settings.verify_threshold, ver
    # the wall of the glass it is nested in, going on under its base, wider than the base (tapered like it)
    nest = _cylinder_side(r_base + 0.004, z0 - 0.03, z0)
    ver = verdict(upright, nest)
    assert ver.continued < 0.02 and ver.score >= perceiver.settings.verify_threshold, ver
    # a bottle going on past the rim (its shoulder, as wide as the rim, then a neck): still continuation
    bottle = np.vstack([_cylinder_side(r_rim - 0.002, z1, z1 + 0.015), _cylinder_side(0.012, z1 + 0.015, z1 + 0.03)])
    ver = verdict(upright, bottle)
    assert ver.score < perceiver.settings.verify_threshold, ver
    # lying, the base end is judged as before
    ver = verdict(lying, can)
    assert ver.score < perceiver.settings.verify_threshold, ver


def test_two_vessels_turned_opposite_ways_through_each_other_vouch_for_nothing(perceiver, inventory):
    """Two glasses fitted rim into rim along a lying bottle's body (one turned the other way round, 5 cm further
    along the axis: their lengths overlap by 7 cm, so their walls would pass through each other): the bottle
    goes on past each one's end, where the other one's surface is. Rigid copies nest or stack facing the same
    way only, so at most one of the two is right, and neither explains points for the other's checks: both
    are judged on what goes on past their ends, and both fail. (On main 7b88b7a each explained the other's
    continuation and both passed: fresh table scene, three glasses kept on one lying bottle.) The same two
    fits facing the same way (a glass nested in a glass) still explain each other's ends."""
    from kitchenbot.perception.map import InstanceMap
    from kitchenbot.perception.register import Hypothesis, on_surface
    from kitchenbot.perception.verify import Verification

    entry = perceiver.database[6]  # the glass
    T = make_T(rot_x(np.pi / 2)[:3, :3], np.array([0.4, 0.0, 0.06]))  # lying: axis along -y
    c = 0.5 * (inventory[6].points.min(axis=0) + inventory[6].points.max(axis=0))
    turn = make_T(np.diag([1.0, -1.0, -1.0]), c - np.diag([1.0, -1.0, -1.0]) @ c)  # half round about its middle
    shift = make_T(np.eye(3), np.array([0.0, 0.0, 0.05]))  # 5 cm along the axis, towards the rim
    thr = perceiver.settings.verify_threshold
    for T2, both_pass in ((T @ shift @ turn, False), (T @ shift, True)):
        a_pts, _ = _cup_surface(entry, T, 0.0005)
        b_pts, _ = _cup_surface(entry, T2, 0.0005, seed=1)
        # the second one's points: where the first one's surface is not (the map holds one surface there)
        b_pts = b_pts[~on_surface(b_pts, None, entry, T, 0.002)]
        points = np.vstack([a_pts, b_pts])
        ids = np.r_[np.zeros(len(a_pts), int), np.ones(len(b_pts), int)]
        m = InstanceMap(points, ids, np.zeros(len(points), int), np.zeros((len(points), 2), int),
                        np.array([[0.8, 0.0, 0.6]]))
        a = Hypothesis(6, T, verification=Verification(seen=1.0, explained=1.0, free_space=0.0, normals=1.0))
        b = Hypothesis(6, T2, verification=Verification(seen=1.0, explained=1.0, free_space=0.0, normals=1.0))
        own_a = np.nonzero(ids == 0)[0]
        own_b = np.nonzero((ids == 1) | on_surface(points, None, entry, T2, 0.002))[0]
        perceiver._fine_check(m, [(a, 0, own_a), (b, 1, own_b)])
        assert (a.verification.score >= thr) == both_pass, (both_pass, a.verification)
        assert (b.verification.score >= thr) == both_pass, (both_pass, b.verification)


def test_a_lid_seen_at_a_slant_past_a_lying_glass_base_rejects_it(perceiver, inventory):
    """A glass fitted lying along a drink can wider than its base: the can's side gives the glass thousands of
    points of its own, and the can's lid, a flat disc 12 mm wider than the glass's base in the base's plane, seen
    at a slant from a camera facing the base end, a few hundred spread over the ring past the base's edge. Per
    point of its own the overhang is small (under 0.15: the pose passed); the area it covers is most of the
    base's area, and the pose is rejected. The same glass with only a neighbour's edge on one side of its base
    (a patch of the ring, 2 cm wide) passes."""
    from kitchenbot.perception.map import InstanceMap
    from kitchenbot.perception.register import Hypothesis
    from kitchenbot.perception.verify import Verification

    model = inventory[6]  # the glass
    T = make_T(rot_x(np.pi / 2)[:3, :3], np.array([0.4, 0.0, 0.05]))  # lying: axis along -y
    own, _ = _cup_surface(perceiver.database[6], T, 0.0005)
    z0 = model.points[:, 2].min()
    r_base = np.linalg.norm(model.points[model.points[:, 2] < z0 + 0.005, :2]
                            - np.median(model.points[:, :2], axis=0), axis=1).max()
    lid = _disk(r_base + 0.012, z0, n=400)
    lid = lid[np.linalg.norm(lid[:, :2], axis=1) > r_base]  # the lid's part past the glass's base
    edge = _disk(r_base + 0.012, z0, n=3000)
    edge = edge[(edge[:, 0] > r_base) & (np.abs(edge[:, 1]) < 0.01)]  # a neighbour's edge on one side only
    for extra, passes in ((lid, False), (edge, True), (np.zeros((0, 3)), True)):
        points = np.vstack([own, extra @ T[:3, :3].T + T[:3, 3]])
        ids = np.r_[np.zeros(len(own), int), np.ones(len(extra), int)]
        m = InstanceMap(points, ids, np.zeros(len(points), int), np.zeros((len(points), 2), int),
                        np.array([[0.4, -0.6, 0.3]]))
        h = Hypothesis(6, T, verification=Verification(seen=0.9, explained=1.0, free_space=0.0, normals=1.0))
        perceiver._fine_check(m, [(h, 0, np.nonzero(ids == 0)[0])])
        assert h.verification.overhang < 0.15, h.verification  # per point of its own: too little to reject
        assert (h.verification.score >= perceiver.settings.verify_threshold) == passes, (len(extra), h.verification)


def test_a_glass_rejected_for_a_lid_alone_still_ends_where_its_model_ends(perceiver, inventory):
    """A glass lying with its base 1 cm from the side of a drink can lying across it, and a second glass fitted
    along the can, whose lid (12 mm wider than the glass's base) shows all round the base's edge: the second one is
    rejected by `overhang_area` alone. Its surface is still where the can's is, and the can ends where the model
    ends: the first glass is not continued by the can's side past its base. A second glass rejected for claiming
    free space (it is not there at all) explains nothing, and the first one is continued."""
    from kitchenbot.perception.map import InstanceMap
    from kitchenbot.perception.register import Hypothesis
    from kitchenbot.perception.verify import Verification
    from kitchenbot.transforms import rot_y

    entry, model = perceiver.database[6], inventory[6]  # the glass
    z0 = model.points[:, 2].min()
    ax = np.median(model.points[:, :2], axis=0)
    r_model = np.linalg.norm(model.points[:, :2] - ax, axis=1)
    r_base = r_model[model.points[:, 2] < z0 + 0.005].max()
    r_mid = np.median(r_model[np.abs(model.points[:, 2]) < 0.005])
    T_a = make_T(rot_y(np.pi / 2)[:3, :3], np.array([0.5, 0.0, 0.05]))  # lying, its base towards -x
    x_end = 0.5 + z0
    # across it, its side 1 cm past the first one's base (out of the base's plane, within `continued`'s reach)
    T_b = make_T(rot_x(np.pi / 2)[:3, :3], np.array([x_end - r_mid - 0.01, 0.0, 0.05]))
    a_pts, _ = _cup_surface(entry, T_a, 0.0005)
    b_pts, _ = _cup_surface(entry, T_b, 0.0005, seed=1)  # the side facing +x: towards the first glass
    lid = _disk(r_base + 0.012, z0, n=400)
    lid = lid[np.linalg.norm(lid[:, :2], axis=1) > r_base] @ T_b[:3, :3].T + T_b[:3, 3]
    points = np.vstack([a_pts, b_pts, lid])
    ids = np.r_[np.zeros(len(a_pts), int), np.ones(len(b_pts), int), np.full(len(lid), 2)]
    m = InstanceMap(points, ids, np.zeros(len(points), int), np.zeros((len(points), 2), int),
                    np.array([[0.8, 0.0, 0.6]]))
    for b_free, a_passes in ((0.0, True), (0.8, False)):
        a = Hypothesis(6, T_a, verification=Verification(seen=0.9, explained=1.0, free_space=0.0, normals=1.0))
        b = Hypothesis(6, T_b, verification=Verification(seen=1.0 - b_free, explained=1.0, free_space=b_free,
                                                         normals=1.0))
        perceiver._fine_check(m, [(a, 0, np.nonzero(ids == 0)[0]), (b, 1, np.nonzero(ids == 1)[0])])
        assert b.verification.score < perceiver.settings.verify_threshold, b.verification
        assert (a.verification.score >= perceiver.settings.verify_threshold) == a_passes, \
            (b_free, a.verification, b.verification)


def test_an_item_lying_on_an_upside_down_mugs_seen_base_is_not_continuation(perceiver, inventory):
    """A mug upside down (standing on its rim) with a sponge propped on its base: the sponge's top, within the
    base's radius and 0.5-3 cm past it, read as the mug's body going on past its base (`continued`), and the
    right pose was rejected (sink block 4872, scene 2, on c5751d4: the turned-over retry of a mug fitted upright,
    overlap 0.95, fine 0.90, rejected by continued 0.26 alone). Half of the base is seen as a closed surface
    facing out: the mug ends there, and what lies past it rests on it. A bottle going on past the same base (its
    body where the base would be seen, then its neck) is still continuation: that base is not seen."""

    entry, model = perceiver.database[5], inventory[5]  # the mug
    z0 = model.points[:, 2].min()
    axis = np.median(model.points[:, :2], axis=0)
    T = make_T(rot_x(np.pi)[:3, :3], np.array([0.4, 0.0, 0.10]))  # upside down: the base (object z0) on top
    rng = np.random.default_rng(3)

    def verdict(own, extra):
        return _fine_verdict(perceiver, 5, T, own, extra)

    # The mug's surface as the camera above sees it (normals facing it in the base frame), as dense as a scan's
    # map (each model point four times, spread 1.5 mm along the surface).
    facing = (entry.dense_normals @ T[:3, :3].T) @ np.array([0.6, 0.0, 0.8]) > 0.2
    q = np.repeat(entry.dense_points[facing], 4, axis=0)
    nq = np.repeat(entry.dense_normals[facing], 4, axis=0)
    jitter = rng.normal(0, 0.0015, q.shape)
    q = q + jitter - (jitter * nq).sum(axis=1, keepdims=True) * nq  # object frame
    own = q @ T[:3, :3].T + T[:3, 3]
    on_base = q[:, 2] < z0 + 0.003
    # The sponge (9 x 6 cm): its lower edge across the base's middle, rising 25 deg away from it over the other half.
    n = 6000
    x, y = rng.uniform(-0.045, 0.045, n), rng.uniform(0.0, 0.06, n)
    sponge = np.column_stack([axis[0] + x, axis[1] + y, z0 - 0.005 - np.tan(np.radians(25)) * y])
    hidden = on_base & (q[:, 1] - axis[1] > 0.0)  # the half of the base under it
    ver = verdict(own[~hidden], sponge)
    assert ver.continued < 0.02 and ver.score >= perceiver.settings.verify_threshold, ver
    # A bottle going on past the base (a body a little narrower than it, then a neck): the base is not seen.
    bottle = np.vstack([_cylinder_side(0.030, z0 - 0.015, z0), _cylinder_side(0.012, z0 - 0.03, z0 - 0.015, 2000)])
    bottle[:, :2] += axis
    bottle = bottle[bottle[:, 0] - axis[0] > -0.3 * 0.03]
    ver = verdict(own[~on_base], bottle)
    assert ver.score < perceiver.settings.verify_threshold, ver


def _fine_verdict(perceiver, obj_id, T, own, extra):
    """The fine check's verification of a pose of `obj_id` at `T` whose own points are `own` (base frame), with
    `extra` (object frame, placed by `T`) as a second instance beside it; camera above, gravity the base's z."""
    from kitchenbot.perception.map import InstanceMap
    from kitchenbot.perception.register import Hypothesis
    from kitchenbot.perception.verify import Verification

    points = np.vstack([own, extra @ T[:3, :3].T + T[:3, 3]])
    ids = np.r_[np.zeros(len(own), int), np.ones(len(extra), int)]
    m = InstanceMap(points, ids, np.zeros(len(points), int), np.zeros((len(points), 2), int),
                    np.array([[0.8, 0.0, 0.6]]))
    h = Hypothesis(obj_id, T, verification=Verification(seen=1.0, explained=1.0, free_space=0.0, normals=1.0))
    perceiver._active_cell = perceiver.cell
    perceiver._fine_check(m, [(h, 0, np.nonzero(ids == 0)[0])])
    return h.verification


def test_content_sticking_out_of_a_cup_does_not_fill_it(perceiver, inventory):
    """A cup holding something no pose explains (a food scrap, a spoon) that rises out of its opening: the
    content's points in the cavity do not count as `filled` (the cup shows its surface, the content sticks out
    over the rim). A can's lid at the rim (a cup fitted over a can) still fills it, and so does the same lump
    sunk in the cavity up to the rim (nothing rises over it)."""
    from kitchenbot.perception.register import on_surface
    from kitchenbot.perception.verify import filled

    entry, model = perceiver.database[4], inventory[4]
    z0, z1 = model.points[:, 2].min(), model.points[:, 2].max()
    T = make_T(np.eye(3), np.array([0.4, 0.0, 0.05]))
    own, _ = _cup_surface(entry, T, 0.0005)
    rng = np.random.default_rng(3)

    def lump(top: float) -> np.ndarray:  # a rounded lump 3 cm across, its top at `top` (object frame)
        d = rng.normal(size=(2500, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        return d * np.array([0.015, 0.015, 0.012]) + np.array([0.005, 0.0, top - 0.012])

    def judged(content: np.ndarray) -> float:
        P = np.vstack([own, content @ T[:3, :3].T + T[:3, 3]])
        return filled(P, model.points, T, on_surface(P, None, entry, T, 0.004), len(own))

    assert judged(lump(z1 + 0.012)) < 0.02  # sticks out 12 mm over the rim: content
    assert judged(lump(z1 - 0.004)) > 0.2  # all in the cavity, up to the rim: fills it
    assert judged(_disk(0.02, z1)) > 0.05  # a lid at the rim
    assert z1 - z0 > 0.05


def test_medians_per_bin_are_np_median_of_each_bin():
    """The wall profile's medians from one sort: bit for bit np.median of each bin's values (odd and even counts,
    repeated values, empty bins 0)."""
    from kitchenbot.perception.verify import medians_per_bin
    rng = np.random.default_rng(3)
    for n, bins in ((1, 1), (2, 3), (7, 2), (500, 17), (4001, 40)):
        values = np.round(rng.normal(0.04, 0.01, n), 4)  # repeated values among them
        b = rng.integers(0, bins, n)
        want = np.array([np.median(values[b == k]) if (b == k).any() else 0.0 for k in range(bins)])
        assert np.array_equal(medians_per_bin(values, b, bins), want)
