from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from kitchenbot.calibration import synthetic as synth
from kitchenbot.calibration.park_martin import (
    DegenerateSetError,
    motion_pairs,
    solve_park_martin,
)
from kitchenbot.calibration.residuals import board_spread, pair_residuals, solve_robust
from kitchenbot.transforms import inv, make_T, pose_error


@pytest.mark.parametrize("mount", ["eye_in_hand", "eye_to_hand"])
def test_exact_recovery_without_noise(mount, rng):
    F, C = synth.samples(mount, 6, rng)
    sol = solve_park_martin(F, C, mount)
    assert np.allclose(sol.X, synth.X_TRUE, atol=1e-9)
    res = solve_robust(F, C, mount)
    assert np.allclose(res.X, synth.X_TRUE, atol=1e-9)
    assert res.pairs_rejected == [] and len(res.pairs_used) == 15
    assert res.rotation_deg_mean < 1e-6 and res.translation_mm_mean < 1e-6
    assert res.spread.translation_max_mm < 1e-6 and res.spread.rotation_max_deg < 1e-6


@pytest.mark.parametrize("mount", ["eye_in_hand", "eye_to_hand"])
def test_three_poses_are_enough(mount, rng):
    F, C = synth.samples(mount, 3, rng)
    assert np.allclose(solve_park_martin(F, C, mount).X, synth.X_TRUE, atol=1e-9)


def test_chains_are_the_documented_ones(rng):
    """A X = X B holds with the true X for the documented chains, and only for them: swapping A and B,
    inverting one side, or using the other mount's chain breaks it (and the solve)."""
    X = synth.X_TRUE
    for mount in ("eye_in_hand", "eye_to_hand"):
        F, C = synth.samples(mount, 5, rng)
        A, B, pairs = motion_pairs(F, C, mount)
        rot, tr = pair_residuals(X, A, B)
        assert rot.max() < 1e-9 and tr.max() < 1e-9
        i, j = pairs[0]
        if mount == "eye_in_hand":
            assert np.allclose(A[0], inv(F[j]) @ F[i]) and np.allclose(B[0], C[j] @ inv(C[i]))
        else:
            assert np.allclose(A[0], F[j] @ inv(F[i])) and np.allclose(B[0], C[j] @ inv(C[i]))
        for wrong_A, wrong_B in ((B, A), ([inv(a) for a in A], B), (A, [inv(b) for b in B])):
            rot, tr = pair_residuals(X, wrong_A, wrong_B)
            assert rot.mean() > 1.0 or tr.mean() > 1.0
    # Samples recorded eye-to-hand solved as eye-in-hand do not give the right X.
    for seed in range(5):
        F, C = synth.samples("eye_to_hand", 6, np.random.default_rng(seed))
        r, t = pose_error(solve_park_martin(F, C, "eye_in_hand").X, X)
        assert np.rad2deg(r) > 5 or t > 0.05


def test_two_poses_rejected(rng):
    F, C = synth.samples("eye_in_hand", 2, rng)
    with pytest.raises(DegenerateSetError, match="too few samples"):
        solve_park_martin(F, C, "eye_in_hand")
    with pytest.raises(DegenerateSetError, match="too few samples"):
        solve_robust(F, C, "eye_in_hand")


def test_parallel_rotation_axes_rejected(rng):
    """All flange rotations about one axis (e.g. only the last joint turns): the rotation of X about that
    axis cannot be told apart, which must be reported, not silently solved."""
    F0 = synth.flange_poses(1, rng)[0]
    F = [F0 @ make_T(Rotation.from_rotvec([0, 0, a]).as_matrix(), [0.01 * k, -0.02 * k, 0.0])
         for k, a in enumerate([0.0, 0.4, -0.7, 1.1, 0.9])]
    C = [inv(f @ synth.X_TRUE) @ synth.T_BASE_BOARD for f in F]
    with pytest.raises(DegenerateSetError, match="rotation axes parallel"):
        solve_park_martin(F, C, "eye_in_hand")


def test_tiny_rotations_rejected(rng):
    F0 = synth.flange_poses(1, rng)[0]
    F = [F0 @ make_T(Rotation.from_rotvec(rng.normal(0, 0.002, 3)).as_matrix(), rng.uniform(-0.1, 0.1, 3))
         for _ in range(6)]
    C = [inv(f @ synth.X_TRUE) @ synth.T_BASE_BOARD for f in F]
    with pytest.raises(DegenerateSetError, match="rotations too small"):
        solve_park_martin(F, C, "eye_in_hand")


def test_bad_input_named():
    with pytest.raises(ValueError, match=r"T_cam_board\[1\]"):
        solve_park_martin([np.eye(4)] * 3, [np.eye(4), np.ones((4, 4)), np.eye(4)], "eye_in_hand")
    with pytest.raises(ValueError, match="mount"):
        solve_park_martin([np.eye(4)] * 3, [np.eye(4)] * 3, "eye_on_table")
    with pytest.raises(ValueError, match="one of each"):
        solve_park_martin([np.eye(4)] * 3, [np.eye(4)] * 4, "eye_in_hand")


def test_noise_gives_small_error_and_outliers_are_rejected(rng):
    F, C = synth.samples("eye_in_hand", 15, rng, cam_rot_deg=0.05, cam_trans_mm=0.2)
    clean = solve_robust(F, C, "eye_in_hand")
    r, t = pose_error(clean.X, synth.X_TRUE)
    assert np.rad2deg(r) < 0.1 and t < 1e-3
    assert 0 < clean.translation_mm_mean < 5 and 0 < clean.rotation_deg_mean < 0.5
    # One grossly wrong board pose (a flipped detection): rejected pairs all involve it, the result is as good.
    C_bad = [c.copy() for c in C]
    C_bad[4] = C_bad[4] @ make_T(Rotation.from_rotvec([0.15, 0.0, 0.05]).as_matrix(), [0.03, 0.0, 0.01])
    plain = solve_park_martin(F, C_bad, "eye_in_hand").X
    robust = solve_robust(F, C_bad, "eye_in_hand")
    assert robust.pairs_rejected and all(4 in p for p in robust.pairs_rejected)
    assert 4 not in robust.samples_used
    assert pose_error(robust.X, synth.X_TRUE)[1] < 1e-3
    assert pose_error(plain, synth.X_TRUE)[1] > 2 * pose_error(robust.X, synth.X_TRUE)[1]


def test_board_spread_measures_the_fixed_frame(rng):
    F, C = synth.samples("eye_in_hand", 8, rng)
    s = board_spread(synth.X_TRUE, F, C, "eye_in_hand")
    assert np.allclose(s.mean, synth.T_BASE_BOARD, atol=1e-9)
    X_off = synth.X_TRUE @ make_T(t=[0.005, 0.0, 0.0])  # a 5 mm wrong mount spreads the board
    assert board_spread(X_off, F, C, "eye_in_hand").translation_max_mm > 1.0
