"""Hardware-in-the-loop checks on the real cell named by KITCHENBOT_HIL_CONFIG (skipped unless KITCHENBOT_HIL=1).

They read state and make only small, safe motions: the gripper opens and closes on nothing, the arm moves
a few degrees on the last joint and back. Run them with the cell clear:

    KITCHENBOT_HIL=1 KITCHENBOT_HIL_CONFIG=my_cell.yaml .venv/bin/pytest -m hil tests/test_hil.py
"""

from __future__ import annotations

import os

import numpy as np
import pytest

pytestmark = pytest.mark.hil


@pytest.fixture(scope="module")
def cell():
    from kitchenbot.executive.assembly import assemble
    from kitchenbot.executive.config import load_config

    path = os.environ.get("KITCHENBOT_HIL_CONFIG")
    if not path:
        pytest.fail("KITCHENBOT_HIL_CONFIG must name the real cell's config file")
    cfg = load_config(path)
    c = assemble(cfg)
    c.connect()
    yield c
    c.disconnect()


def test_arm_state_is_live_and_inside_limits(cell):
    from kitchenbot.drivers.arm import SafetyState

    s1 = cell.arm.state()
    s2 = cell.arm.state()
    assert s1.safety is SafetyState.NORMAL
    assert np.all(np.isfinite(s1.q)) and s2.stamp >= s1.stamp
    cell.arm.limits.check_joints(s1.q, "current configuration")


def test_small_wrist_motion_and_back(cell):
    q0 = cell.arm.joint_positions()
    q1 = q0.copy()
    q1[5] += np.radians(5)
    cell.arm.move_joints(q1, speed=0.2, accel=0.5)
    assert np.allclose(cell.arm.joint_positions(), q1, atol=np.radians(0.2))
    cell.arm.move_joints(q0, speed=0.2, accel=0.5)
    assert np.allclose(cell.arm.joint_positions(), q0, atol=np.radians(0.2))


def test_gripper_closes_on_nothing_and_opens(cell):
    cell.gripper.open()
    assert cell.gripper.status().error is None
    result = cell.gripper.grasp(current_limit=0.3 * cell.gripper.max_current)
    assert not result.holding and result.opening < 0.01
    cell.gripper.open()
    assert cell.gripper.opening() > 0.5 * cell.gripper.max_opening


def test_camera_gives_aligned_rgbd_with_depth(cell):
    frame = cell.camera.capture(timeout=3.0)
    h, w = frame.depth.shape
    assert frame.rgb.shape == (h, w, 3)
    valid = np.isfinite(frame.depth) & (frame.depth > 0)
    assert valid.mean() > 0.3, "less than 30 % valid depth: check the camera's view and lighting"
    assert 0.15 < float(np.median(frame.depth[valid])) < 3.0
