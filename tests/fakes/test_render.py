"""The renderer and the fake camera: known geometry gives known images."""

import numpy as np
import pytest

from kitchenbot.drivers.errors import DeviceNotConnectedError, DriverTimeoutError
from kitchenbot.fakes.camera import FakeCamera
from kitchenbot.fakes.render import oakd_intrinsics, render, stereo_noise
from kitchenbot.fakes.world import SimWorld
from kitchenbot.transforms import make_T, rot_x, transform_points, inv
from kitchenbot.world.cell import Cell
from kitchenbot.world.inventory import Inventory


@pytest.fixture(scope="module")
def inventory():
    return Inventory.builtin()


def _looking_down(x, y, z):
    """Camera at (x, y, z) with its optical axis along -z of the base."""
    return make_T(rot_x(np.pi)[:3, :3], (x, y, z))


def test_depth_of_a_known_plane(inventory):
    world = SimWorld(Cell(), inventory)
    K = oakd_intrinsics()
    # 0.40 m above the counter top (z = 0), looking straight down at a region of plain counter.
    T = _looking_down(-0.15, 0.30, 0.40)
    r = render(world, K, T, 640, 480)
    centre = r.depth[200:280, 280:360]
    assert np.allclose(centre, 0.40, atol=1e-4)
    assert np.all(r.labels == 0)
    noisy = stereo_noise(r.depth, r.cos_incidence, K, np.random.default_rng(0))
    sel = noisy[200:280, 280:360]
    sel = sel[sel > 0]
    sigma_expected = 0.40**2 * 0.12 / (K[0, 0] * 0.075)
    assert abs(np.median(sel) - 0.40) < 0.001
    assert np.std(sel) == pytest.approx(np.sqrt(sigma_expected**2 + 0.001**2 / 12), rel=0.35)


def test_rendered_labels_match_object_projection(inventory):
    world = SimWorld(Cell(), inventory)
    cup = inventory.by_name("cup")
    uid = world.add_object(cup, make_T(t=(0.5, 0.0, -0.2 + cup.extents[2] / 2)))
    K = oakd_intrinsics()
    T = _looking_down(0.5, 0.0, 0.25)
    r = render(world, K, T, 640, 480)
    mask = r.labels == uid
    assert mask.sum() > 2000
    # Model points projected through K land inside the mask (allow a 1-pixel border).
    pts = transform_points(inv(T) @ world.objects[uid].T_base_obj, cup.points)
    uv = (pts @ K.T)[:, :2] / pts[:, 2:3]
    u, v = np.round(uv[:, 0]).astype(int), np.round(uv[:, 1]).astype(int)
    from scipy.ndimage import binary_dilation

    assert binary_dilation(mask, iterations=1)[v, u].mean() > 0.99
    # And the depth there is the object's: between the cup's top and the sink floor.
    assert np.all((r.depth[mask] > 0.25) & (r.depth[mask] < 0.25 + 0.2 + 1e-3))


def test_fake_camera_faults(inventory):
    world = SimWorld(Cell(), inventory, T_flange_cam=np.eye(4))
    world.set_joints(np.array([np.pi, -1.9, 1.9, -1.57, -1.57, 0.0]))
    cam = FakeCamera(world, 160, 120)
    with pytest.raises(DeviceNotConnectedError):
        cam.capture()
    cam.connect()
    f = cam.capture()
    assert f.rgb.shape == (120, 160, 3) and f.depth.dtype == np.float32 and f.stamp > 0
    world.faults.camera_drop = 1
    t0 = world.clock.now()
    with pytest.raises(DriverTimeoutError):
        cam.capture(timeout=0.5)
    assert world.clock.now() - t0 == pytest.approx(0.5)
    world.faults.camera_nan_depth = 1
    f = cam.capture()
    assert np.isnan(f.depth).any() and not np.isfinite(f.depth[:, :80]).any()
    f = cam.capture()
    assert np.isfinite(f.depth).all()
