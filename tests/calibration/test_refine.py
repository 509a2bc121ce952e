from __future__ import annotations

import numpy as np
import pytest

from kitchenbot.calibration import synthetic as synth
from kitchenbot.calibration.board import CharucoSpec
from kitchenbot.calibration.refine import refine_reprojection
from kitchenbot.calibration.residuals import solve_robust
from kitchenbot.transforms import inv, make_T, pose_error, transform_points

K = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])


@pytest.mark.parametrize("mount", ["eye_in_hand", "eye_to_hand"])
def test_refinement_on_pixels_beats_pose_averaging(mount, rng):
    """Pixel noise -> noisy PnP-like poses for Park–Martin; the joint pixel fit gets closer to the truth."""
    # Put the board 0.4 m in front of the camera for the first pose, whatever X is.
    X = synth.X_TRUE
    obj = CharucoSpec().corners()
    F = synth.flange_poses(10, rng, max_tilt=0.25)
    if mount == "eye_in_hand":
        T_fixed = F[0] @ X @ make_T(t=[-0.1, -0.07, 0.4])  # T_base_board
        C = [inv(f @ X) @ T_fixed for f in F]
    else:
        T_fixed = inv(F[0]) @ X @ make_T(t=[-0.1, -0.07, 0.4])  # T_flange_board
        C = [inv(X) @ f @ T_fixed for f in F]
    img = []
    for c in C:
        p = transform_points(c, obj)
        assert p[:, 2].min() > 0.1
        uv = (K @ p.T).T
        img.append(uv[:, :2] / uv[:, 2:] + rng.normal(0, 0.3, (len(obj), 2)))
    C_noisy = [synth.perturb(c, rng, 0.1, 0.5) for c in C]
    pm = solve_robust(F, C_noisy, mount)
    ref = refine_reprojection(pm.X, pm.spread.mean, F, [obj] * len(F), img, K, mount=mount)
    e_pm, e_ref = pose_error(pm.X, X), pose_error(ref.X, X)
    assert e_ref[0] < e_pm[0] and e_ref[1] < e_pm[1]
    assert np.rad2deg(e_ref[0]) < 0.05 and e_ref[1] < 0.5e-3
    assert pose_error(ref.T_fixed, T_fixed)[1] < 1e-3
    assert ref.rms_px_after < ref.rms_px_before and abs(ref.rms_px_after - 0.3 * np.sqrt(2)) < 0.1


def test_refinement_input_checked():
    with pytest.raises(ValueError, match="one flange pose"):
        refine_reprojection(np.eye(4), np.eye(4), [np.eye(4)] * 2, [np.zeros((4, 3))], [np.zeros((4, 2))], K)
