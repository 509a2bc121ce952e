"""The ChArUco calibration board: its definition, a rendered image (to print, and for the simulator), detection
in a camera image and the board pose by PnP with quality gates.

Board frame (OpenCV's): origin at the outer top-left corner of the printed board, x to the right along the
image columns, y down along the image rows, z = x cross y, pointing *into* the board (away from a camera that
sees its front). Detection and pose use OpenCV 5's ``cv2.aruco.CharucoDetector`` and ``cv2.solvePnP``.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from kitchenbot.transforms import make_T


class BoardDetectionError(RuntimeError):
    """No usable board pose in an image (not found, too few corners, or reprojection error too large)."""


class CharucoSpec(BaseModel):
    """A ChArUco board: `squares_x` x `squares_y` chessboard squares, ArUco markers in the white ones."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    squares_x: int = Field(8, ge=3, le=40)
    squares_y: int = Field(6, ge=3, le=40)
    square_m: float = Field(0.030, gt=0.0, lt=0.5, description="chessboard square side, metres")
    marker_m: float = Field(0.022, gt=0.0, lt=0.5, description="ArUco marker side, metres")
    dictionary: str = Field("DICT_5X5_100", description="a cv2.aruco predefined dictionary name")

    @model_validator(mode="after")
    def _check(self) -> "CharucoSpec":
        if self.marker_m >= self.square_m:
            raise ValueError(f"marker_m ({self.marker_m}) must be smaller than square_m ({self.square_m})")
        d = getattr(cv2.aruco, self.dictionary, None)
        if not self.dictionary.startswith("DICT_") or not isinstance(d, int):
            raise ValueError(f"dictionary {self.dictionary!r}: expected a cv2.aruco name such as DICT_5X5_100")
        n_markers = (self.squares_x * self.squares_y) // 2
        size = cv2.aruco.getPredefinedDictionary(d).bytesList.shape[0]
        if n_markers > size:
            raise ValueError(f"dictionary {self.dictionary} has {size} markers, the board needs {n_markers}")
        return self

    @property
    def size_m(self) -> tuple[float, float]:
        """(width, height) of the board's printed area, metres."""
        return self.squares_x * self.square_m, self.squares_y * self.square_m

    @property
    def n_corners(self) -> int:
        return (self.squares_x - 1) * (self.squares_y - 1)

    def board(self) -> cv2.aruco.CharucoBoard:
        d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard((self.squares_x, self.squares_y), self.square_m, self.marker_m, d)

    def corners(self) -> np.ndarray:
        """(N, 3) chessboard corners in the board frame, metres (index = ChArUco corner id)."""
        return np.asarray(self.board().getChessboardCorners(), dtype=np.float64).reshape(-1, 3)


def render_board(spec: CharucoSpec, px_per_m: float = 4000.0, margin_px: int = 0) -> np.ndarray:
    """Greyscale uint8 image of the board at `px_per_m`, with a white margin of `margin_px` on every side.

    Pixel centre (u, v) shows board point ((u + 0.5 - margin_px) / px_per_m, (v + 0.5 - margin_px) / px_per_m):
    the image size is chosen so the squares land on exact pixel boundaries (see :func:`image_to_board`).
    """
    sq_px = spec.square_m * px_per_m
    if abs(sq_px - round(sq_px)) > 1e-6 or sq_px < 20:
        raise ValueError(f"px_per_m={px_per_m}: a square must be a whole number of pixels >= 20, got {sq_px:.3f}")
    w = int(round(spec.squares_x * sq_px)) + 2 * margin_px
    h = int(round(spec.squares_y * sq_px)) + 2 * margin_px
    return spec.board().generateImage((w, h), marginSize=margin_px, borderBits=1)


def image_to_board(px_per_m: float, margin_px: int = 0) -> np.ndarray:
    """3x3 map from rendered-image pixel coordinates (homogeneous, pixel centres at integers) to board metres."""
    s = 1.0 / px_per_m
    o = (0.5 - margin_px) * s
    return np.array([[s, 0.0, o], [0.0, s, o], [0.0, 0.0, 1.0]])


def warp_board(
    image: np.ndarray, px_per_m: float, margin_px: int, K: np.ndarray, T_cam_board: np.ndarray,
    size: tuple[int, int], background: int = 128, supersample: int = 3,
) -> np.ndarray:
    """What a pinhole camera (K, no distortion) at T_cam_board sees of the rendered board: a plane-induced
    homography H = K [r1 r2 t] S (S = :func:`image_to_board`) applied with cv2.warpPerspective, rendered at
    `supersample` x the resolution and area-averaged down (a camera integrates over its pixels)."""
    k = int(supersample)
    # Pixel centres at integers: the k-times finer grid maps to coarse pixels by u = (u_k + 0.5) / k - 0.5.
    up = np.array([[k, 0.0, (k - 1) / 2.0], [0.0, k, (k - 1) / 2.0], [0.0, 0.0, 1.0]])
    Rt = T_cam_board[:3, [0, 1, 3]]
    H = up @ K @ Rt @ image_to_board(px_per_m, margin_px)
    big = cv2.warpPerspective(image, H, (size[0] * k, size[1] * k), flags=cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_CONSTANT, borderValue=background)
    return big if k == 1 else cv2.resize(big, size, interpolation=cv2.INTER_AREA)


@dataclass
class BoardPose:
    T_cam_board: np.ndarray
    ids: np.ndarray  # (N,) ChArUco corner ids
    image_points: np.ndarray  # (N, 2) px
    object_points: np.ndarray  # (N, 3) m, board frame
    rms_px: float  # reprojection error
    n_markers: int

    @property
    def n_corners(self) -> int:
        return len(self.ids)


class BoardDetector:
    """Finds the board in an image and estimates its pose. Gates: >= `min_corners` ChArUco corners and a PnP
    reprojection RMS <= `max_rms_px`; a view that fails a gate raises :class:`BoardDetectionError`."""

    def __init__(self, spec: CharucoSpec, min_corners: int = 8, max_rms_px: float = 1.0):
        self.spec = spec
        self.board = spec.board()
        params = cv2.aruco.DetectorParameters()
        params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
        self.detector = cv2.aruco.CharucoDetector(self.board, cv2.aruco.CharucoParameters(), params)
        self.min_corners = int(min_corners)
        self.max_rms_px = float(max_rms_px)

    def detect(self, image: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
        """(ids (N,), corners (N, 2) px, number of markers found) in a grey or RGB uint8 image."""
        if image.ndim == 3:
            image = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
        if image.dtype != np.uint8:
            raise ValueError(f"image: expected uint8, got {image.dtype}")
        corners, ids, _, marker_ids = self.detector.detectBoard(image)
        n_markers = 0 if marker_ids is None else len(marker_ids)
        if ids is None or corners is None or len(ids) == 0:
            return np.zeros(0, int), np.zeros((0, 2)), n_markers
        return np.asarray(ids).reshape(-1).astype(int), np.asarray(corners, np.float64).reshape(-1, 2), n_markers

    def pose(self, image: np.ndarray, K: np.ndarray, dist: np.ndarray | None = None) -> BoardPose:
        """T_cam_board of the board in `image` for intrinsics K (and optional distortion coefficients)."""
        ids, pts, n_markers = self.detect(image)
        if len(ids) < self.min_corners:
            raise BoardDetectionError(
                f"board not found well enough: {len(ids)} ChArUco corners ({n_markers} markers), "
                f"need >= {self.min_corners}"
            )
        obj = self.spec.corners()[ids]
        if self.board.checkCharucoCornersCollinear(ids.reshape(-1, 1).astype(np.int32)):
            raise BoardDetectionError(f"the {len(ids)} detected corners are collinear: the pose is not determined")
        K = np.asarray(K, np.float64)
        dist = np.zeros(5) if dist is None else np.asarray(dist, np.float64)
        ok, rvec, tvec = cv2.solvePnP(obj, pts, K, dist, flags=cv2.SOLVEPNP_IPPE)
        if not ok:
            raise BoardDetectionError("solvePnP failed on the detected corners")
        rvec, tvec = cv2.solvePnPRefineLM(obj, pts, K, dist, rvec, tvec)
        proj, _ = cv2.projectPoints(obj, rvec, tvec, K, dist)
        rms = float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - pts) ** 2, axis=1))))
        if rms > self.max_rms_px:
            raise BoardDetectionError(f"board pose rejected: reprojection RMS {rms:.3f} px > {self.max_rms_px} px")
        T = make_T(cv2.Rodrigues(rvec)[0], tvec.reshape(3))
        return BoardPose(T_cam_board=T, ids=ids, image_points=pts, object_points=obj, rms_px=rms,
                         n_markers=n_markers)
