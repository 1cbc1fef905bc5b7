"""Camera intrinsics (pinhole + OpenCV lens distortion) and their `fabline.camera/1` JSON format."""

from __future__ import annotations

import os
from dataclasses import dataclass

import cv2
import numpy as np

from fabline.errors import FablineError
from fabline.fileio import finite_number, read_json, write_json

CAMERA_SCHEMA = "fabline.camera/1"
MAX_PIXELS = 1e6       # image sides, focal lengths and principal points (px) a camera file may give
MAX_DISTORTION = 1e4   # size of a distortion coefficient (real lenses: well under 100)


def parse_resolution(text: str) -> tuple[int, int]:
    """'4000x2667' -> (4000, 2667) pixels; malformed or smaller than 64 x 64 is a FablineError naming the text."""
    try:
        width, height = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise FablineError(f"{text!r}: expected WIDTHxHEIGHT in pixels, e.g. 4000x2667") from None
    if width < 64 or height < 64:
        raise FablineError(f"{text!r}: must be at least 64x64 pixels")
    return width, height


@dataclass
class Camera:
    """Intrinsics of one camera at one resolution: 3x3 matrix, distortion (k1 k2 p1 p2 k3), image size."""

    matrix: np.ndarray
    distortion: np.ndarray
    width: int
    height: int
    reprojection_error_px: float | None = None

    @property
    def focal_px(self) -> float:
        """Mean focal length in pixels, the scale that turns normalised residuals into pixels."""
        return float(0.5 * (self.matrix[0, 0] + self.matrix[1, 1]))

    def project(self, points_cam: np.ndarray) -> np.ndarray:
        """Pixel positions (N, 2) of points (N, 3) given in this camera's frame, with lens distortion."""
        points = np.ascontiguousarray(points_cam, dtype=np.float64).reshape(-1, 1, 3)
        pixels, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), self.matrix, self.distortion)
        return pixels.reshape(-1, 2)

    def normalise(self, pixels: np.ndarray) -> np.ndarray:
        """Undistorted normalised image coordinates (N, 2) of distorted pixel positions (N, 2)."""
        pts = np.ascontiguousarray(pixels, dtype=np.float64).reshape(-1, 1, 2)
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12)
        return cv2.undistortPoints(pts, self.matrix, self.distortion, None, None, None, criteria).reshape(-1, 2)

    def check_image(self, shape: tuple[int, ...], source: str) -> None:
        """Raise naming `source` when an image of `shape` was not taken at this camera's resolution."""
        height, width = shape[:2]
        if (width, height) != (self.width, self.height):
            raise FablineError(f"{source}: image is {width} x {height} px but the camera file is for "
                               f"{self.width} x {self.height} px")


def camera_to_dict(camera: Camera) -> dict:
    """The JSON-ready form of a camera."""
    data = {
        "schema": CAMERA_SCHEMA,
        "width": camera.width,
        "height": camera.height,
        "fx": float(camera.matrix[0, 0]), "fy": float(camera.matrix[1, 1]),
        "cx": float(camera.matrix[0, 2]), "cy": float(camera.matrix[1, 2]),
        "distortion": [float(v) for v in camera.distortion.ravel()],
    }
    if camera.reprojection_error_px is not None:
        data["reprojection_error_px"] = float(camera.reprojection_error_px)
    return data


def camera_from_dict(data: object, source: str = "camera") -> Camera:
    """Build a camera from its JSON form; a missing or bad field raises naming `source` and the field."""
    if not isinstance(data, dict) or data.get("schema") != CAMERA_SCHEMA:
        raise FablineError(f"{source}: not a {CAMERA_SCHEMA} file (missing or wrong 'schema')")
    values = {}
    for key in ("width", "height", "fx", "fy", "cx", "cy"):
        value = data.get(key)
        if not finite_number(value, MAX_PIXELS) or value <= 0:
            raise FablineError(f"{source}: field '{key}' must be a positive number of pixels, at most {MAX_PIXELS:g}")
        values[key] = value
    for key in ("width", "height"):
        if int(values[key]) != values[key]:
            raise FablineError(f"{source}: field '{key}' must be a whole number of pixels")
    distortion = data.get("distortion", [0.0] * 5)
    if (not isinstance(distortion, list) or len(distortion) not in (4, 5, 8, 12, 14)
            or not all(finite_number(v, MAX_DISTORTION) for v in distortion)):
        raise FablineError(f"{source}: field 'distortion' must be a list of 4, 5, 8, 12 or 14 numbers, each at most "
                           f"{MAX_DISTORTION:g} in size")
    matrix = np.array([[values["fx"], 0, values["cx"]], [0, values["fy"], values["cy"]], [0, 0, 1]], dtype=float)
    error = data.get("reprojection_error_px")
    return Camera(matrix, np.array(distortion, dtype=float), int(values["width"]), int(values["height"]),
                  float(error) if isinstance(error, (int, float)) else None)


def load_camera(path: str | os.PathLike) -> Camera:
    """Read a `fabline.camera/1` file."""
    return camera_from_dict(read_json(path), str(path))


def save_camera(camera: Camera, path: str | os.PathLike) -> None:
    """Write a camera atomically as `fabline.camera/1` JSON."""
    write_json(path, camera_to_dict(camera))
