"""ChArUco boards: finding their corners in raw frames, and the camera's intrinsics from many views.

A board is described as the rig file's ``[calibration.board]`` describes it (:class:`BoardSpec`): squares
across and down, the square and marker sides in metres, the ArUco dictionary by OpenCV's name. Corner
``i`` of a board is OpenCV's chessboard corner ``i``; its position on the board (metres, board frame:
z = 0) comes from OpenCV's own board model, so detection and model cannot disagree.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import cv2
import numpy as np

from hlr_lab.errors import HlrLabError

MIN_CORNERS = 6  # per view: OpenCV needs at least 4 for a pose; 6 keeps noise from dominating a view
MIN_VIEWS = 8
MIN_COVERAGE = 1 / 3  # of the image area, by the hull of every detected corner: distortion needs the edges


class CalibrationError(HlrLabError):
    """A calibration that cannot be trusted: too few views or corners, a board not in view, no
    convergence. The message says what to do."""


@dataclass(frozen=True)
class BoardSpec:
    """A ChArUco board: squares across and down, square and marker sides (m), the ArUco dictionary."""

    squares: tuple[int, int]  # across (x), down (y)
    square_m: float
    marker_m: float
    dictionary: str = "DICT_4X4_50"

    @cached_property
    def board(self) -> cv2.aruco.CharucoBoard:
        if not hasattr(cv2.aruco, self.dictionary):
            raise CalibrationError(
                f"unknown ArUco dictionary {self.dictionary!r} (OpenCV names: DICT_4X4_50 …)"
            )
        d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard(self.squares, self.square_m, self.marker_m, d)

    @cached_property
    def corners_m(self) -> np.ndarray:
        """(N, 3) every chessboard corner on the board, metres, board frame."""
        return np.asarray(self.board.getChessboardCorners(), np.float64).reshape(-1, 3)


@dataclass(frozen=True)
class Detection:
    """The corners found in one image: ids (N,) into :attr:`BoardSpec.corners_m`, pixels (N, 2)."""

    ids: np.ndarray
    pixels: np.ndarray


def detect(image: np.ndarray, spec: BoardSpec) -> Detection:
    """The board's corners in a raw frame (H, W) or (H, W, C), any unsigned integer depth; sub-pixel
    (OpenCV refines ChArUco corners on the grey image). No board: an empty detection."""
    grey = image.astype(np.float64)
    if grey.ndim == 3:
        grey = grey.mean(axis=2)
    top = np.percentile(grey, 99.9)
    grey8 = np.clip(grey * (255.0 / max(top, 1e-9)), 0, 255).astype(np.uint8)
    corners, ids, _, _ = cv2.aruco.CharucoDetector(spec.board).detectBoard(grey8)
    if ids is None or len(ids) == 0:
        return Detection(np.zeros(0, np.int64), np.zeros((0, 2)))
    return Detection(ids.ravel().astype(np.int64), corners.reshape(-1, 2).astype(np.float64))


@dataclass(frozen=True)
class Intrinsics:
    """A camera matrix (3, 3) and distortion (5,), with the reprojection RMS (px) they reach."""

    matrix: np.ndarray  # (3, 3)
    distortion: np.ndarray  # (5,) k1 k2 p1 p2 k3
    rms_px: float  # over every corner of every view used


def usable_views(detections: list[Detection], size: tuple[int, int]) -> list[int]:
    """Indices of the views with enough corners; refuses (:class:`CalibrationError`) when fewer than
    :data:`MIN_VIEWS` remain or when their corners cover less than a third of the image."""
    used = [i for i, d in enumerate(detections) if len(d.ids) >= MIN_CORNERS]
    if len(used) < MIN_VIEWS:
        raise CalibrationError(
            f"only {len(used)} of {len(detections)} views show the board with {MIN_CORNERS}+ corners (need "
            f"{MIN_VIEWS}); check that the board is in view, lit and in focus, and take more views"
        )
    points = np.concatenate([detections[i].pixels for i in used]).astype(np.float32)
    hull = cv2.convexHull(points)
    coverage = cv2.contourArea(hull) / (size[0] * size[1])
    if coverage < MIN_COVERAGE:
        raise CalibrationError(
            f"the detected corners cover {coverage:.0%} of the image (need {MIN_COVERAGE:.0%}): the lens "
            "distortion would be guessed at the edges; use a larger board or bring it closer"
        )
    return used


def calibrate_intrinsics(
    detections: list[Detection], spec: BoardSpec, size: tuple[int, int], *, fit_k3: bool = False
) -> Intrinsics:
    """OpenCV's camera calibration over the usable views. size: (width, height) px.

    k3 stays 0 unless ``fit_k3``: over the part of the field a board covers, k1, k2 and k3 trade off
    against each other, and a free k3 was measured to wander to ~16 while moving the principal point by
    0.9 px (simulated bench, 22 views); fixed, the principal point lands within 0.5 px. Only a strongly
    distorting (wide-angle) lens needs it."""
    used = usable_views(detections, size)
    objects = [spec.corners_m[detections[i].ids].astype(np.float32) for i in used]
    images = [detections[i].pixels.astype(np.float32).reshape(-1, 1, 2) for i in used]
    flags = 0 if fit_k3 else cv2.CALIB_FIX_K3
    rms, matrix, dist, _, _ = cv2.calibrateCamera(objects, images, size, None, None, flags=flags)
    return Intrinsics(matrix, dist.ravel()[:5], float(rms))
