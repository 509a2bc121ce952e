"""Things in the sink no pose explains are grouped and named (executive/unrecognised.py)."""

import numpy as np

from kitchenbot.executive.unrecognised import unrecognised_things

V = 0.02  # voxel size, m
LO, HI = np.array([0.0, 0.0, -0.3]), np.array([0.5, 0.4, 0.0])


def _block(corner, n):
    """Voxel centres filling an n[0] x n[1] x n[2] block from `corner`."""
    g = np.stack(np.meshgrid(*[np.arange(k) for k in n], indexing="ij"), -1).reshape(-1, 3)
    return np.asarray(corner) + (g + 0.5) * V


def test_two_buried_items_are_two_things_and_what_is_outside_the_sink_is_not_named():
    bowl = _block((0.05, 0.05, -0.28), (5, 5, 2))  # 10 x 10 x 4 cm
    plate = _block((0.30, 0.20, -0.28), (8, 8, 1))  # 16 x 16 x 2 cm, far from the bowl
    on_counter = _block((0.6, 0.1, 0.0), (4, 4, 2))
    things = unrecognised_things(np.vstack([bowl, plate, on_counter]), V, LO, HI)
    assert [t.voxels for t in things] == [64, 50]
    assert np.allclose(things[0].extent, [0.16, 0.16, 0.02])
    assert np.allclose(things[1].centre, [0.10, 0.10, -0.26])
    assert "16 x 16 x 2 cm" in things[0].describe()


def test_voxels_touching_at_a_corner_are_one_thing():
    a = _block((0.1, 0.1, -0.2), (2, 2, 2))
    b = a + 2 * V  # diagonal neighbour block, touching a's far corner
    assert len(unrecognised_things(np.vstack([a, b]), V, LO, HI)) == 1


def test_stray_voxels_and_slivers_are_noise():
    stray = _block((0.1, 0.1, -0.2), (1, 1, 3))  # 3 voxels
    sliver = _block((0.3, 0.1, -0.2), (1, 1, 1)) + np.array([[0, 0, 0]])  # one voxel
    thin = _block((0.3, 0.3, -0.2), (1, 1, 1))
    thin = np.vstack([thin, thin + [V, 0, 0]])  # 2 voxels, 4 cm
    assert unrecognised_things(np.vstack([stray, sliver, thin]), V, LO, HI) == []
    assert unrecognised_things(np.zeros((0, 3)), V, LO, HI) == []


def test_an_item_no_pose_explains_is_named_when_the_run_gives_up(make_runner, safe_end):
    """Two cups in the sink; perception poses one (its every pick blocked) and only maps the other (as a buried
    item is: points, no pose). The run gives up naming the perceived cup with its reason and the unposed one as an
    unrecognised thing where it is."""
    from kitchenbot.executive.oracle import OracleResult
    from kitchenbot.planning.types import CartesianPathFailed

    runner, world = make_runner(task="sink-pick", cups=2)
    real_perceiver, real = runner.perceiver, runner.planner
    hidden_uid = sorted(world.objects)[-1]
    hidden = world.objects[hidden_uid]
    T = np.asarray(hidden.T_base_obj, float)

    class PosesOnlyOne:
        def __getattr__(self, name):
            return getattr(real_perceiver, name)

        def perceive(self, views, *a, **kw):
            res = real_perceiver.perceive(views)
            return OracleResult([p for p in res.poses if p.instance_id != hidden_uid],
                                hidden.model.points @ T[:3, :3].T + T[:3, 3])

    class Blocked:
        def __getattr__(self, name):
            return getattr(real, name)

        def plan_pick(self, q, objects, *, target=None, **kw):
            return CartesianPathFailed("test: lift: straight line collides")

    runner.perceiver, runner.planner = PosesOnlyOne(), Blocked()
    report = runner.run()
    safe_end(runner, world)
    assert report.status == "failed"
    assert "1 object(s) left in the sink: cup (cartesian_path_failed in direct_pick)" in report.message
    assert "1 unrecognised thing(s)" in report.message, report.message
    x, y = T[:2, 3]
    where = report.message.split("at (")[1].split(")")[0]
    assert np.allclose([float(v) for v in where.split(",")[:2]], [x, y], atol=0.03), (where, x, y)
