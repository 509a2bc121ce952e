"""Closed-form UR IK: every branch reaches the pose, and the configuration the pose came from is among them."""

import numpy as np
import pytest

from kitchenbot.drivers.ur_kinematics import fk_flange, ur_model
from kitchenbot.executive.config import load_config
from kitchenbot.planning.robot import RobotModel
from kitchenbot.planning.ur_ik import ik_flange


@pytest.mark.parametrize("name", ["ur3e", "ur5e", "ur10e"])
def test_all_branches_reach_the_pose_and_include_the_source(name):
    m = ur_model(name)
    rng = np.random.default_rng(4)
    counts = []
    for _ in range(100):
        q = rng.uniform(-np.pi, np.pi, 6)
        T = fk_flange(m, q)
        sols = ik_flange(m, T)
        counts.append(len(sols))
        for s in sols:
            np.testing.assert_allclose(fk_flange(m, s), T, atol=1e-6)
        wrapped = (q + np.pi) % (2 * np.pi) - np.pi
        assert any(np.max(np.abs((s - wrapped + np.pi) % (2 * np.pi) - np.pi)) < 1e-6 for s in sols)
        # distinct branches
        assert len({tuple(np.round(s, 6)) for s in sols}) == len(sols)
    assert max(counts) == 8 and np.mean(counts) > 6


def test_out_of_reach_gives_no_solution():
    m = ur_model("ur5e")
    T = np.eye(4)
    T[:3, 3] = (2.0, 0.0, 0.3)
    assert ik_flange(m, T) == []


def test_robot_model_branches_are_sorted_and_inside_limits():
    cfg = load_config("config/sim.yaml")
    r = RobotModel.from_config(cfg)
    q0 = np.asarray(cfg.robot.home, float)
    q = q0 + np.array([0.3, -0.2, 0.25, 0.1, -0.3, 0.4])
    T = r.fk_tcp(q)
    sols = r.ik_all(T, q0)
    assert len(sols) >= 4
    d = [float(np.max(np.abs(s - q0))) for s in sols]
    assert d == sorted(d)
    assert np.max(np.abs(sols[0] - q)) < 1e-6  # the nearest branch is the one the pose came from
    for s in sols:
        assert r.within_limits(s)
        np.testing.assert_allclose(r.fk_tcp(s), T, atol=1e-6)


def test_batch_ik_gives_the_branches_of_the_single_pose_solver():
    """ik_flange_batch (many poses at once: the release-pose cache) returns exactly ik_flange's branches."""
    from kitchenbot.drivers.ur_kinematics import fk_flange, ur_model
    from kitchenbot.planning.ur_ik import ik_flange, ik_flange_batch

    m = ur_model("ur5e")
    rng = np.random.default_rng(3)
    T = np.array([fk_flange(m, q) for q in rng.uniform(-np.pi, np.pi, (120, 6))])
    T[5, :3, 3] = (3.0, 0.0, 0.5)  # out of reach: no branch
    Q, ok = ik_flange_batch(m, T)
    assert Q.shape == (120, 8, 6) and ok.shape == (120, 8)
    assert not ok[5].any()
    total = 0
    for i in range(len(T)):
        single = sorted(tuple(np.round(q, 7)) for q in ik_flange(m, T[i]))
        batch = sorted(tuple(np.round(q, 7)) for q in Q[i][ok[i]])
        assert single == batch
        total += len(single)
    assert total > 4 * 119  # most random poses have several branches


def test_surely_unreachable_only_where_numerical_ik_fails():
    """Poses around the edge of the reach: where surely_unreachable says so, numerical IK from every seed finds
    nothing; poses the closed form reaches are never flagged; and most poses clearly beyond reach are."""
    from kitchenbot.planning.ur_ik import ik_flange_batch, surely_unreachable

    cfg = load_config("config/sim.yaml")
    r = RobotModel.from_config(cfg)
    m = r.ur
    rng = np.random.default_rng(11)
    Ts = []
    for _ in range(60):
        q = rng.uniform(-np.pi, np.pi, 6)
        T = fk_flange(m, q)
        # push the pose outwards from the shoulder by 0 to 6 cm: reachable, at the edge, or clearly beyond
        out = T[:3, 3] - np.array([0.0, 0.0, m.d[0]])
        T[:3, 3] += out / np.linalg.norm(out) * rng.uniform(0.0, 0.06) * (1.0 if rng.uniform() < 0.8 else 0.0)
        Ts.append(T)
    # and poses stretched to the reach limit (straight arm), then beyond it
    for q2 in np.linspace(-2.5, -0.5, 10):
        for extra in (0.0, 0.002, 0.03):
            q = np.array([0.3, q2, 0.0, -1.2, 1.4, 0.2])
            T = fk_flange(m, q)
            out = T[:3, 3] - np.array([0.0, 0.0, m.d[0]])
            T[:3, 3] += out / np.linalg.norm(out) * extra
            Ts.append(T)
    Ts = np.array(Ts)
    sure = surely_unreachable(m, Ts)
    _, ok = ik_flange_batch(m, Ts)
    assert not (sure & ok.any(axis=1)).any()
    assert sure.sum() >= 10
    T_tcp = Ts @ r.T_flange_tcp
    for T, s in zip(T_tcp, sure):
        if s:  # numerical IK from the whole seed spread (limits ignored: wrapping cannot make a pose reachable)
            for seed in r.seeds:
                _, err, _ = r._dls(pin_se3(T), seed, 200, 1e-5, 1e-6)
                assert err >= 1e-5


def pin_se3(T):
    import pinocchio as pin

    return pin.SE3(np.asarray(T, float))
