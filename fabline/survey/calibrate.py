"""Camera calibration from photos of a ChArUco board (OpenCV), with the reprojection error reported."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from fabline.errors import FablineError
from fabline.progress import progress
from fabline.survey.camera import Camera
from fabline.survey.detect import read_gray, write_image

BOARD_DICTIONARY = cv2.aruco.DICT_5X5_100
MIN_CORNERS = 8
MIN_VIEWS = 4


@dataclass
class BoardSpec:
    """A ChArUco board: squares across and down, square and marker edge in mm (5x5 ArUco markers)."""

    squares_x: int = 7
    squares_y: int = 5
    square_mm: float = 40.0
    marker_mm: float = 30.0

    def board(self) -> cv2.aruco.CharucoBoard:
        """The OpenCV board object, in millimetres."""
        if self.squares_x < 3 or self.squares_y < 3 or not 0 < self.marker_mm < self.square_mm:
            raise FablineError(f"bad ChArUco board {self.squares_x}x{self.squares_y}, square {self.square_mm} mm, "
                               f"marker {self.marker_mm} mm (need at least 3x3 squares and marker < square)")
        return cv2.aruco.CharucoBoard((self.squares_x, self.squares_y), self.square_mm, self.marker_mm,
                                      cv2.aruco.getPredefinedDictionary(BOARD_DICTIONARY))


def board_image(spec: BoardSpec, pixels_per_mm: float = 10.0) -> np.ndarray:
    """The board as an 8-bit image at `pixels_per_mm`, no margin (print it at true size)."""
    size = (int(round(spec.squares_x * spec.square_mm * pixels_per_mm)), int(round(spec.squares_y * spec.square_mm * pixels_per_mm)))
    return spec.board().generateImage(size, marginSize=0, borderBits=1)


def write_board(spec: BoardSpec, path: str | os.PathLike, pixels_per_mm: float = 10.0) -> None:
    """Write the board image (PNG) for printing."""
    write_image(path, board_image(spec, pixels_per_mm), suffix=".png")


def calibrate(photos: list[Path], spec: BoardSpec) -> tuple[Camera, list[str]]:
    """Intrinsics from ChArUco photos; returns the camera and the photos left out, each with its reason."""
    board = spec.board()
    detector = cv2.aruco.CharucoDetector(board)
    object_points, image_points, skipped = [], [], []
    size = None
    for path in progress(photos, "detecting board"):
        try:
            gray = read_gray(path)
        except FablineError as exc:
            skipped.append(str(exc))
            continue
        if size is None:
            size = gray.shape[::-1]
        elif gray.shape[::-1] != size:
            skipped.append(f"{path}: image is {gray.shape[1]} x {gray.shape[0]} px, the first photo {size[0]} x {size[1]} px")
            continue
        corners, ids, _, _ = detector.detectBoard(gray)
        if ids is None or len(ids) < MIN_CORNERS:
            skipped.append(f"{path}: found {0 if ids is None else len(ids)} board corners, need {MIN_CORNERS}")
            continue
        objects, images = board.matchImagePoints(corners, ids)
        object_points.append(objects.astype(np.float32))
        image_points.append(images.astype(np.float32))
    if len(object_points) < MIN_VIEWS:
        raise FablineError(f"calibration needs the board in at least {MIN_VIEWS} photos, found it in {len(object_points)}"
                           + (f" ({skipped[0]})" if skipped else ""))
    rms, matrix, distortion, _, _ = cv2.calibrateCamera(object_points, image_points, size, None, None)
    return Camera(matrix, distortion.ravel()[:5], int(size[0]), int(size[1]), float(rms)), skipped
