"""The same views give the same poses, bit for bit, in any process and on every call (perception/ransac.py: Open3D's
RANSACs drew from one generator on several threads, in a timing-dependent order)."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np

from kitchenbot.perception.ransac import segment_plane

# Perceive one synthetic scene twice in this process; print a hash of each answer (poses, scores, map ids: exact
# bytes). argv: the CAD cache directory.
PERCEIVE_TWICE = r"""
import hashlib, sys
import numpy as np
from kitchenbot.perception.pipeline import Perceiver
from kitchenbot.perception.settings import PerceptionSettings
from kitchenbot.perception.synthetic import render, resting_pose, scan_poses
from kitchenbot.world.cell import Cell
from kitchenbot.world.inventory import Inventory

inv, cell = Inventory.builtin(), Cell()
placed = [(4, resting_pose(inv, 4, 0.45, 0.09, 0.3, cell)), (2, resting_pose(inv, 2, 0.56, -0.06, 0.0, cell))]
views, _ = render(inv, placed, scan_poses(cell)[:2], cell, noise=0.002)
p = Perceiver(PerceptionSettings(cache_dir=sys.argv[1]), inv, cell)
for _ in range(2):
    res = p.perceive(views)
    h = hashlib.sha1(res.map.ids.tobytes())
    for q in res.poses:
        h.update(np.int64(q.obj_id).tobytes() + q.T_base_obj.tobytes() + np.float64(q.score).tobytes())
    print(len(res.poses), h.hexdigest())
"""


def _cloud() -> np.ndarray:
    """A basin floor (80 % of the points, 1.5 mm noise) with a wall beside it and clutter on it: RANSAC stops
    early, after its best fit so far says a better one is unlikely, and which fit that is depends on the order of
    its draws."""
    rng = np.random.default_rng(3)
    floor = np.column_stack([rng.uniform(0, 0.4, 4000), rng.uniform(0, 0.3, 4000), rng.normal(0, 0.0015, 4000)])
    wall = np.column_stack([rng.normal(0, 0.0015, 500), rng.uniform(0, 0.3, 500), rng.uniform(0, 0.2, 500)])
    clutter = rng.uniform([0.05, 0.05, 0.0], [0.35, 0.25, 0.1], (500, 3))
    return np.vstack([floor, wall, clutter])


def test_plane_fit_is_the_same_on_every_call():
    P = _cloud()
    planes, inliers = zip(*(segment_plane(P, 0.004, 100) for _ in range(30)))
    assert all(np.array_equal(planes[0], q) for q in planes[1:])
    assert all(np.array_equal(inliers[0], q) for q in inliers[1:])
    assert abs(planes[0][2]) > 0.99 and len(inliers[0]) > 3500  # the floor


def test_two_processes_perceive_the_same_scene_bit_for_bit(perceiver):
    out = []
    for _ in range(2):
        p = subprocess.run([sys.executable, "-c", PERCEIVE_TWICE, perceiver.settings.cache_dir],
                           capture_output=True, text=True, env=os.environ.copy())
        assert p.returncode == 0, p.stderr[-2000:]
        out += p.stdout.split("\n")[:2]
    assert out[0].split()[0] == "2"  # both items found
    assert len(set(out)) == 1, out
