from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from kitchenbot.calibration.board import (
    BoardDetectionError,
    BoardDetector,
    CharucoSpec,
    image_to_board,
    render_board,
    warp_board,
)
from kitchenbot.transforms import make_T, pose_error

K = np.array([[600.0, 0.0, 320.0], [0.0, 600.0, 240.0], [0.0, 0.0, 1.0]])
PPM, MARGIN = 4000.0, 12


def _view(spec: CharucoSpec, rpy, dist: float) -> np.ndarray:
    """T_cam_board with the board centre on the optical axis at `dist`, tilted by rpy."""
    R = Rotation.from_euler("xyz", rpy).as_matrix()
    w, h = spec.size_m
    T = make_T(R, [0.0, 0.0, dist])
    T[:3, 3] -= R @ np.array([w / 2, h / 2, 0.0])
    return T


def test_render_geometry_matches_board_frame():
    spec = CharucoSpec()
    img = render_board(spec, PPM, MARGIN)
    assert img.shape == (round(spec.size_m[1] * PPM) + 2 * MARGIN, round(spec.size_m[0] * PPM) + 2 * MARGIN)
    det = BoardDetector(spec)
    ids, pts, _ = det.detect(img)
    assert len(ids) == spec.n_corners
    # Detected corners, mapped back through image_to_board, land on the board's corner coordinates.
    S = image_to_board(PPM, MARGIN)
    xy = (S @ np.c_[pts, np.ones(len(pts))].T).T[:, :2]
    assert np.abs(xy - spec.corners()[ids, :2]).max() < 0.05 / PPM * 10


@pytest.mark.parametrize("rpy,dist", [((0.3, -0.25, 0.4), 0.40), ((-0.5, 0.2, -1.2), 0.50), ((0.1, 0.55, 2.8), 0.35)])
def test_pose_from_warped_image(rpy, dist):
    spec = CharucoSpec()
    T_true = _view(spec, rpy, dist)
    img = warp_board(render_board(spec, PPM, MARGIN), PPM, MARGIN, K, T_true, (640, 480))
    pose = BoardDetector(spec).pose(img, K)
    r, t = pose_error(pose.T_cam_board, T_true)
    assert pose.n_corners >= 30
    assert pose.rms_px < 0.3
    assert np.rad2deg(r) < 0.1 and t < 0.5e-3


def test_gates_reject_bad_views():
    spec = CharucoSpec()
    board_img = render_board(spec, PPM, MARGIN)
    blank = np.full((480, 640), 128, np.uint8)
    with pytest.raises(BoardDetectionError, match="ChArUco corners"):
        BoardDetector(spec).pose(blank, K)
    # Board mostly outside the image: too few corners for the gate.
    T = _view(spec, (0.0, 0.0, 0.0), 0.4) @ make_T(t=[0.19, 0.0, 0.0])
    img = warp_board(board_img, PPM, MARGIN, K, T, (640, 480))
    with pytest.raises(BoardDetectionError, match="need >= 30"):
        BoardDetector(spec, min_corners=30).pose(img, K)
    # Wrong intrinsics given to PnP: the corners cannot be explained, the reprojection gate refuses the pose.
    img = warp_board(board_img, PPM, MARGIN, K, _view(spec, (0.4, 0.3, 0.2), 0.4), (640, 480))
    K_bad = K.copy()
    K_bad[0, 0] *= 1.25
    with pytest.raises(BoardDetectionError, match="reprojection RMS"):
        BoardDetector(spec, max_rms_px=1.0).pose(img, K_bad)


def test_spec_validation():
    with pytest.raises(ValueError, match="marker_m"):
        CharucoSpec(square_m=0.02, marker_m=0.03)
    with pytest.raises(ValueError, match="dictionary"):
        CharucoSpec(dictionary="DICT_NOPE")
    with pytest.raises(ValueError, match="needs"):
        CharucoSpec(squares_x=20, squares_y=20, dictionary="DICT_4X4_50")
