"""An item staged on the counter settles when let go: its record (where it was put down) is looked at, and replaced
by what the view shows, before a grasp is planned on it (executive/verification.py, ``_look_at_staged``). Oracle
perception: the executive's mechanism is under test."""

from __future__ import annotations

import numpy as np

from kitchenbot.transforms import make_T, rot_z


def _staged_mug(record_staged, runner, world, T_put, T_true):
    """A mug recorded as staged at T_put (where it was put down) that really lies at T_true."""
    for dev in (runner.arm, runner.gripper, runner.camera):
        dev.connect()
    mug = runner.robot.inventory.by_name("mug")
    world.add_object(mug, T_true)
    return record_staged(runner, mug, T_put)


def _put_down_spot(runner):
    """Where a mug is put down upright in the middle of the drop zone: (T_put, its xy, its centre's height)."""
    mug = runner.robot.inventory.by_name("mug")
    zone = runner.robot.cell.spec.drop_zone
    z = zone.z + mug.extents[2] / 2
    xy = np.array(zone.origin_xy) + np.array(zone.size_xy) / 2
    return make_T(np.eye(3), (xy[0], xy[1], z)), xy, z


def test_a_staged_item_is_looked_at_and_its_record_replaced_before_its_regrasp(make_runner, record_staged):
    """Put down at one spot, the mug settled 3.2 cm away with its handle turned 146 deg: a grasp planned on the
    record hits it. Selected for its regrasp, the record is replaced by the view's pose (before: selected as
    recorded); the record a view gave is not looked at again."""
    runner, world = make_runner(task="sink-to-dishwasher")
    T_put, xy, z = _put_down_spot(runner)
    T_true = make_T(rot_z(np.radians(146.0))[:3, :3], (xy[0] + 0.026, xy[1] - 0.0186, z))
    rec = _staged_mug(record_staged, runner, world, T_put, T_true)
    b = runner.belief
    assert b.provenance(type("P", (), {"instance_id": rec.instance_id})()) == "staged"
    q0 = runner.arm.joint_positions().copy()
    assert runner._do_select_grasp() == "selected"
    sel = runner.item.obj
    assert sel.cls == "mug" and runner.item.staged is not None
    assert np.linalg.norm(sel.T_base_obj[:3, 3] - T_true[:3, 3]) < 0.005
    R = T_true[:3, :3].T @ sel.T_base_obj[:3, :3]
    assert np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))) < 5.0
    assert not np.allclose(runner.arm.joint_positions(), q0)  # the arm moved to look
    # the belief holds the new record (as staged, seen), once
    assert len(b.staged) == 1 and np.allclose(b.staged[0].T_base_obj, sel.T_base_obj)
    assert b.provenance(sel) == "staged, seen" and not b.needs_look(b.staged[0])
    q1 = runner.arm.joint_positions().copy()
    assert runner._do_select_grasp() == "selected"
    assert np.allclose(runner.arm.joint_positions(), q1)  # no second look


def test_a_staged_item_not_seen_keeps_its_record(make_runner, record_staged):
    """Nothing of its class within reach of the record in the view: the record stays (and is not looked at
    again)."""
    runner, world = make_runner(task="sink-to-dishwasher")
    T_put, xy, z = _put_down_spot(runner)
    T_far = make_T(np.eye(3), (xy[0] + 0.2, xy[1], z))  # not this one: too far from where it was put down
    rec = _staged_mug(record_staged, runner, world, T_put, T_far)
    assert runner._do_select_grasp() == "selected"
    assert np.allclose(runner.item.obj.T_base_obj, rec.T_base_obj)
    assert not runner.belief.needs_look(runner.belief.staged[0])


def test_a_staged_item_seen_where_it_was_put_down_keeps_its_record(make_runner, record_staged):
    """The view shows it within a pose fit's error of where it was put down (5 mm, 8 deg): the record, which
    stands it exactly on the counter, stays."""
    runner, world = make_runner(task="sink-to-dishwasher")
    T_put, xy, z = _put_down_spot(runner)
    T_true = make_T(rot_z(np.radians(8.0))[:3, :3], (xy[0] + 0.005, xy[1], z))
    rec = _staged_mug(record_staged, runner, world, T_put, T_true)
    assert runner._do_select_grasp() == "selected"
    assert np.allclose(runner.item.obj.T_base_obj, rec.T_base_obj)
    assert not runner.belief.needs_look(runner.belief.staged[0])


def test_a_view_whose_fit_turns_the_handle_the_other_way_does_not_replace_a_right_record(make_runner, record_staged):
    """The mug lies where it was put down, but the view's fit puts its handle on the other side (turned 147 deg
    about its body's axis: its origin, the box centre, 3 cm off): the record explains the view's depth better and
    stays (before, any view's pose beyond 1 cm / 15 deg replaced it, and a side grasp's finger met the handle)."""
    from dataclasses import replace

    from kitchenbot.transforms import trans

    runner, world = make_runner(task="sink-to-dishwasher")
    T_put, _, _ = _put_down_spot(runner)
    rec = _staged_mug(record_staged, runner, world, T_put, T_put)
    mug = runner.robot.inventory.by_name("mug")
    top = mug.points[mug.points[:, 2] > mug.points[:, 2].max() - 0.004]
    c = np.append(top[:, :2].mean(axis=0), 0.0)  # the body's axis (the rim's centre) in the model's frame
    T_flip = T_put @ trans(*c) @ rot_z(np.radians(147.0)) @ trans(*(-c))
    assert 0.025 < np.linalg.norm(T_flip[:3, 3] - T_put[:3, 3]) < 0.04
    oracle = runner._drop_perceiver()

    class HandleFlipped:
        def perceive(self, views):
            res = oracle.perceive(views)
            res.poses = [replace(p, T_base_obj=T_flip.copy()) if p.cls == "mug" else p for p in res.poses]
            return res

    runner._drop_perceiver = lambda: HandleFlipped()
    logged = []
    log = runner._log
    runner._log = lambda kind, name, /, **kw: (logged.append((name, kw)), log(kind, name, **kw))[1]
    assert runner._do_select_grasp() == "selected"
    assert np.allclose(runner.item.obj.T_base_obj, rec.T_base_obj)
    assert np.allclose(runner.belief.staged[0].T_base_obj, T_put)
    look = next(kw for name, kw in logged if name == "staged item")
    assert look["seen"] and look["view_fit"] < look["record_fit"]


def test_a_staged_item_whose_grasp_missed_is_looked_at_again(make_runner, record_staged):
    """Looked at once already (its record taken as it lies), the mug really lies 3.2 cm off with its handle turned:
    a grasp planned on the record closes on nothing. After that miss the next selection looks at it again and
    takes the view's pose (before: the same record planned the next grasp, which missed too, until its attempts
    ran out and it was left on the counter)."""
    from kitchenbot.executive.belief import as_pose
    from kitchenbot.executive.execution import Item
    from kitchenbot.executive.failures import Failure

    runner, world = make_runner(task="sink-to-dishwasher")
    T_put, xy, z = _put_down_spot(runner)
    T_true = make_T(rot_z(np.radians(146.0))[:3, :3], (xy[0] + 0.026, xy[1] - 0.0186, z))
    rec = _staged_mug(record_staged, runner, world, T_put, T_true)
    b = runner.belief
    b.looked_at(runner.task, rec, None)  # looked at: no view had (the record stays)
    assert runner._do_select_grasp() == "selected"
    assert np.allclose(runner.item.obj.T_base_obj, T_put)  # not looked at again: the record as it was
    runner.item = Item(as_pose(rec), runner.item.targets, rec)
    runner._act_record_failure(Failure("grasp_missed", "the gripper closed on nothing", "execute", {}), {})
    assert runner._do_select_grasp() == "selected"
    sel = runner.item.obj
    assert np.linalg.norm(sel.T_base_obj[:3, 3] - T_true[:3, 3]) < 0.005
    assert len(b.staged) == 1 and np.allclose(b.staged[0].T_base_obj, sel.T_base_obj)


def test_a_staged_bowl_seen_tilted_below_its_record_takes_the_views_pose(make_runner, record_staged):
    """Recorded lying upside down, flat, where it was seen after it fell, the bowl really lies tilted 27 deg with its
    rim 3.5 cm lower on one side (across the counter's edge): the record's height, where it lies flat, says nothing
    of how high it lies tilted. The view's pose is compared as it was fitted, not only moved to where its lowest
    point is the record's (3.7 cm too high there, it explained almost none of the view, the record won, and each
    grasp planned on the record missed)."""
    from kitchenbot.transforms import rot_x

    runner, world = make_runner(task="sink-to-dishwasher")
    for dev in (runner.arm, runner.gripper, runner.camera):
        dev.connect()
    bowl = runner.robot.inventory.by_name("bowl")
    zone = runner.robot.cell.spec.drop_zone
    xy = np.array(zone.origin_xy) + np.array(zone.size_xy) / 2
    flip = rot_x(np.pi)[:3, :3]
    T_put = make_T(flip, (xy[0], xy[1], 0.0))
    T_put[2, 3] += zone.z - float((bowl.points @ flip.T)[:, 2].min())  # upside down on the counter
    R_true = rot_x(np.radians(27.0))[:3, :3] @ flip
    T_true = make_T(R_true, (xy[0], xy[1] - 0.02, 0.0))
    T_true[2, 3] += zone.z - 0.035 - float((bowl.points @ R_true.T)[:, 2].min())  # its lowest point 3.5 cm lower
    world.add_object(bowl, T_true)
    rec = record_staged(runner, bowl, T_put)
    assert runner.belief.needs_look(rec)
    assert runner._do_select_grasp() == "selected"
    sel = runner.item.obj
    assert np.linalg.norm(sel.T_base_obj[:3, 3] - T_true[:3, 3]) < 0.005
    assert np.degrees(np.arccos(np.clip(sel.T_base_obj[:3, 2] @ T_true[:3, 2], -1, 1))) < 5.0


def test_a_staged_item_whose_grasp_missed_takes_the_views_pose_though_it_agrees_within_a_fits_error(
        make_runner, record_staged):
    """A cup set down lying on its side settled 8.8 mm back along its axis, its axis tilted 2.5 deg: within what a
    pose fit is off by (1 cm, 15 deg), so the look before its regrasp kept the record (where it was put down). Its
    body tapers, so every pinch across it planned on the record closed 4 mm wider than planned and missed. After a
    miss the look again does not keep the record for agreeing so: the view's depth decides, and the view's pose
    (the item as it lies) replaces it (before: the record was kept after each miss, and three grasps planned on it
    missed until its attempts ran out and it was left on the counter)."""
    from kitchenbot.executive.belief import as_pose
    from kitchenbot.executive.execution import Item
    from kitchenbot.executive.failures import Failure
    from kitchenbot.transforms import rot_x

    runner, world = make_runner(task="sink-to-dishwasher")
    for dev in (runner.arm, runner.gripper, runner.camera):
        dev.connect()
    cup = runner.robot.inventory.by_name("cup")
    zone = runner.robot.cell.spec.drop_zone
    xy = np.array(zone.origin_xy) + np.array(zone.size_xy) / 2

    def resting(R, x, y):  # its lowest point on the counter
        T = make_T(R, (x, y, 0.0))
        T[2, 3] = zone.z - float((cup.points @ R.T)[:, 2].min())
        return T

    on_side = rot_x(-np.pi / 2)[:3, :3]  # its axis along +y
    T_put = resting(on_side, xy[0], xy[1])
    T_true = resting(rot_x(np.radians(2.5))[:3, :3] @ on_side, xy[0], xy[1] - 0.0088)
    world.add_object(cup, T_true)
    rec = record_staged(runner, cup, T_put)
    b = runner.belief
    logged = []
    log = runner._log
    runner._log = lambda kind, name, /, **kw: (logged.append((name, kw)), log(kind, name, **kw))[1]
    assert runner._do_select_grasp() == "selected"
    first = next(kw for name, kw in logged if name == "staged item")
    assert first["seen"] and first["agrees"] and first["moved_cm"] < 1.0  # the first look keeps the record
    assert np.allclose(runner.item.obj.T_base_obj, T_put)
    runner.item = Item(as_pose(rec), runner.item.targets, rec)
    miss = Failure("grasp_missed", "the gripper closed at 82.9 mm grasping the cup, not at the grasp's 79.1 mm",
                   "execute", {"opening": 0.0829, "expected": 0.0791})
    runner._act_record_failure(miss, {})
    assert b.missed_on(rec)
    logged.clear()
    assert runner._do_select_grasp() == "selected"
    sel = runner.item.obj
    assert np.linalg.norm(sel.T_base_obj[:3, 3] - T_true[:3, 3]) < 0.002
    assert np.degrees(np.arccos(np.clip(sel.T_base_obj[:3, 2] @ T_true[:3, 2], -1, 1))) < 1.0
    again = next(kw for name, kw in logged if name == "staged item")
    assert again["after_miss"] and not again["agrees"] and again["view_fit"] > again["record_fit"]
    assert len(b.staged) == 1 and np.allclose(b.staged[0].T_base_obj, sel.T_base_obj)
    assert not b.missed_on(b.staged[0]) and not b.needs_look(b.staged[0])  # looked at: not again until a miss
