"""Self-calibration: the survey's own photos fix each camera's intrinsics (focal length, principal point, distortion).

Photos are grouped by camera: EXIF make, model, body serial and focal length (a zoom lens at another focal length is
another camera) with the image size, or as the user maps them. Each camera starts from its EXIF focal length in 35 mm
equivalent where the photos carry one, else from the tags' squares (Zhang's method: OpenCV's calibrateCamera on each
tag view as a planar target of four points, principal point at the centre, no distortion). After a first adjustment
with those, a joint adjustment (scipy's least_squares, sparse Jacobian, soft-L1 loss) frees per camera the focal
length (square pixels), principal point and k1, k2, p1, p2, k3 (or k1, k2 alone: a lens with k3 then biases the focal
length, by 0.2 % on the simulator's) together with every photo's and tag's pose,
in pixels; the tags' known size (and any scale bars afterwards) fixes the scale. The intrinsics' standard uncertainties
come from the Jacobian at the solution; a camera whose focal length the photos cannot pin down (all square-on at one
distance) is reported.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import lil_matrix

from fabline.errors import FablineError
from fabline.survey.camera import Camera
from fabline.survey.detect import TagDetection, tag_object_points
from fabline.survey.reconstruct import Reconstruction, rotation_matrices

# 35 mm film's diagonal, mm: a 35 mm-equivalent focal length over it is the focal length over the image diagonal
FILM_DIAGONAL_MM = float(np.hypot(36.0, 24.0))
# a camera's fitted focal length known to worse than this (relative standard uncertainty) is reported as weak, and
# beyond UNDETERMINED_FOCAL the photos cannot fix it at all
WEAK_FOCAL, UNDETERMINED_FOCAL = 0.005, 0.05
# Photos that see every tag's face within FRONTAL_DEG of square to the optical axis and all tags at depths within DEPTH_SPREAD of each other
# cannot separate the focal length from the distance (the image of a plane facing the camera depends on their ratio
# alone, distortion included): the linearised uncertainty misses this, the geometry shows it
FRONTAL_DEG, DEPTH_SPREAD = 10.0, 1.15
INTRINSIC_NAMES = ("f", "cx", "cy", "k1", "k2", "p1", "p2", "k3")
MAX_TAG_VIEWS_FOR_ZHANG = 300


@dataclass
class CameraGroup:
    """The photos (indices) taken with one camera, its intrinsics, where they came from and their uncertainties."""

    name: str
    photos: list[int]
    camera: Camera
    source: str
    sigma: dict[str, float] = field(default_factory=dict)


def exif_camera(path: str | os.PathLike) -> dict:
    """Make, model, body serial, focal length (mm) and 35 mm-equivalent focal length from a photo's EXIF (Pillow),
    the keys that are present; {} for a photo without EXIF or that Pillow cannot open."""
    try:
        from PIL import Image
    except ImportError:  # Pillow is a dependency; without it no EXIF is read
        return {}
    try:
        with Image.open(path) as image:
            exif = image.getexif()
            details = exif.get_ifd(0x8769)  # the Exif sub-IFD: focal lengths and serial
    except (OSError, ValueError):
        return {}
    found = {"make": exif.get(0x010F), "model": exif.get(0x0110), "serial": details.get(0xA431),
             "focal_mm": details.get(0x920A), "focal_35mm": details.get(0xA405)}
    out = {}
    for key, value in found.items():
        if value is None:
            continue
        if key.startswith("focal"):
            try:
                value = float(value)
            except (TypeError, ValueError, ZeroDivisionError):
                continue
            if not np.isfinite(value) or value <= 0:
                continue
        else:
            value = str(value).strip("\x00 ")
        out[key] = value
    return out


def group_photos(photos: list[Path], sizes: dict[int, tuple[int, int]], mapping: dict[str, str] | None = None):
    """Photo indices per camera: by the user's `mapping` (file name -> camera name) where it names a photo, else by
    EXIF make, model, serial and focal length with the image size; returns (name -> (indices, EXIF of the first),
    the names of photos without EXIF)."""
    groups: dict[str, tuple[list[int], dict]] = {}
    without = []
    for k in sorted(sizes):
        width, height = sizes[k]
        exif = exif_camera(photos[k])
        if mapping and photos[k].name in mapping:
            name = f"{mapping[photos[k].name]} {width}x{height}"
        elif exif:
            label = " ".join(str(exif[key]) for key in ("make", "model") if key in exif) or "camera"
            serial = f" #{exif['serial']}" if "serial" in exif else ""
            focal = f" f {exif['focal_mm']:g} mm" if "focal_mm" in exif else ""
            name = f"{label}{serial}{focal} {width}x{height}"
        else:
            name = f"no EXIF {width}x{height}"
            without.append(photos[k].name)
        groups.setdefault(name, ([], exif))[0].append(k)
    return groups, without


def initial_camera(size: tuple[int, int], exif: dict, views: list[np.ndarray], tag_size: float) -> tuple[Camera, str]:
    """A camera to start from: principal point at the centre, no distortion, the focal length from EXIF's 35 mm
    equivalent or else from the tags' squares `views` (corners (4, 2) px each, AprilTag order; Zhang's method)."""
    width, height = size
    matrix = np.array([[1.0, 0, (width - 1) / 2], [0, 1.0, (height - 1) / 2], [0, 0, 1]])
    if "focal_35mm" in exif:
        focal = exif["focal_35mm"] * np.hypot(width, height) / FILM_DIAGONAL_MM
        source = f"EXIF focal length {exif['focal_35mm']:g} mm (35 mm equivalent)"
    else:
        if len(views) < 3:
            raise FablineError(f"a camera of {width} x {height} px without EXIF focal length shows fewer than 3 tags: "
                               f"its focal length cannot be estimated; give --camera camera.json")
        views = sorted(views, key=lambda quad: -cv2.contourArea(quad.astype(np.float32)))[:MAX_TAG_VIEWS_FOR_ZHANG]
        objects = [tag_object_points(tag_size).astype(np.float32)] * len(views)
        images = [quad.astype(np.float32).reshape(4, 1, 2) for quad in views]
        flags = (cv2.CALIB_FIX_PRINCIPAL_POINT | cv2.CALIB_FIX_ASPECT_RATIO | cv2.CALIB_ZERO_TANGENT_DIST
                 | cv2.CALIB_FIX_K1 | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3 | cv2.CALIB_USE_INTRINSIC_GUESS)
        guess = matrix.copy()
        guess[0, 0] = guess[1, 1] = max(width, height)
        _, fitted, _, _, _ = cv2.calibrateCamera(objects, images, size, guess, np.zeros(5), flags=flags)
        focal = float(fitted[0, 0])
        source = f"tag squares ({len(views)} views, Zhang's method)"
    matrix[0, 0] = matrix[1, 1] = focal
    return Camera(matrix, np.zeros(5), width, height), source


def _distort_project(intrinsics: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Pixels (..., 2) of camera-frame points (..., 3) for intrinsics (f, cx, cy, k1, k2, p1, p2, k3), OpenCV's model."""
    f, cx, cy, k1, k2, p1, p2, k3 = intrinsics
    x, y = points[..., 0] / points[..., 2], points[..., 1] / points[..., 2]
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.stack([f * xd + cx, f * yd + cy], axis=-1)


def _camera_vector(camera: Camera) -> np.ndarray:
    d = np.zeros(5)
    d[:min(5, camera.distortion.size)] = camera.distortion.ravel()[:5]
    return np.array([camera.focal_px, camera.matrix[0, 2], camera.matrix[1, 2], d[0], d[1], d[2], d[3], d[4]])


def refine_cameras(groups: list[CameraGroup], reconstruction: Reconstruction,
                   found: list[tuple[int, TagDetection]], tag_size: float, tangential: bool = True) -> float:
    """Fit each group's intrinsics jointly with every photo's and tag's pose to the detected corners (px), in place;
    returns the RMS reprojection error px. `found`: (photo, detection) pairs of photos and tags the reconstruction
    holds. Free per camera: f, cx, cy, k1, k2 (and p1, p2, k3 with `tangential`)."""
    free = [0, 1, 2, 3, 4] + ([5, 6, 7] if tangential else [])
    group_of = {k: g for g, group in enumerate(groups) for k in group.photos}
    first = min(reconstruction.camera_rotations, key=lambda k: np.linalg.norm(reconstruction.camera_translations[k]))
    photo_ids = [k for k in sorted(reconstruction.camera_rotations) if k != first]
    tag_ids = sorted(reconstruction.tag_poses)
    used = [(k, d) for k, d in found if k in reconstruction.camera_rotations and d.tag_id in reconstruction.tag_poses
            and not d.partial]
    photo_pos = {k: i for i, k in enumerate(photo_ids)}
    tag_pos = {t: i for i, t in enumerate(tag_ids)}
    n_int, n_cam = len(free) * len(groups), 6 * len(photo_ids)
    x0 = np.concatenate([_camera_vector(g.camera)[free] for g in groups]
                        + [np.concatenate([cv2.Rodrigues(reconstruction.camera_rotations[k])[0].ravel(),
                                           reconstruction.camera_translations[k]]) for k in photo_ids]
                        + [reconstruction.tag_poses[t] for t in tag_ids])
    observed = np.array([d.corners for _, d in used])
    group_index = np.array([group_of[k] for k, _ in used])
    photo_index = np.array([photo_pos.get(k, -1) for k, _ in used])
    tag_index = np.array([tag_pos[d.tag_id] for _, d in used])
    model = tag_object_points(tag_size)
    fixed_rotation = reconstruction.camera_rotations[first]
    fixed_translation = reconstruction.camera_translations[first]
    base = np.array([_camera_vector(g.camera) for g in groups])

    def residuals(x: np.ndarray) -> np.ndarray:
        intrinsics = base.copy()
        intrinsics[:, free] = x[:n_int].reshape(len(groups), len(free))
        points = _camera_points(x[n_int:], n_cam, photo_index, tag_index, model, fixed_rotation, fixed_translation)
        pixels = np.empty_like(observed)
        for g in range(len(groups)):
            rows = group_index == g
            pixels[rows] = _distort_project(intrinsics[g], points[rows])
        return (pixels - observed).ravel()

    sparsity = lil_matrix((8 * len(used), len(x0)), dtype=np.uint8)
    for row, (g, p, t) in enumerate(zip(group_index, photo_index, tag_index)):
        rows = slice(8 * row, 8 * row + 8)
        sparsity[rows, len(free) * g:len(free) * (g + 1)] = 1
        if p >= 0:
            sparsity[rows, n_int + 6 * p:n_int + 6 * p + 6] = 1
        sparsity[rows, n_int + n_cam + 6 * t:n_int + n_cam + 6 * t + 6] = 1
    solution = least_squares(residuals, x0, jac_sparsity=sparsity, loss="soft_l1", f_scale=1.0, x_scale="jac",
                             method="trf", max_nfev=200)
    jacobian = solution.jac.toarray() if hasattr(solution.jac, "toarray") else solution.jac
    r = solution.fun
    variance = float(r @ r / max(len(r) - len(x0), 1))
    normal = jacobian.T @ jacobian
    covariance = _leading_block_inverse(normal, n_int) * variance
    fitted = base.copy()
    fitted[:, free] = solution.x[:n_int].reshape(len(groups), len(free))
    sigmas = np.sqrt(np.maximum(np.diag(covariance), 0)).reshape(len(groups), len(free))
    # judged on the adjustment the fit started from: where the photos cannot fix the focal length, the fit is free to
    # tilt the tags along with it
    points = _camera_points(x0[n_int:], n_cam, photo_index, tag_index, model, fixed_rotation, fixed_translation)
    for g in range(len(groups)):
        rows = group_index == g
        sides = points[rows][:, [1, 3]] - points[rows][:, [0, 0]]
        normals = np.cross(sides[:, 0], sides[:, 1])
        centres = points[rows].mean(axis=1)
        tilt = np.degrees(np.arccos(np.abs(normals[:, 2]) / np.linalg.norm(normals, axis=1)))  # from the optical axis
        if tilt.max() < FRONTAL_DEG and centres[:, 2].max() < DEPTH_SPREAD * centres[:, 2].min():
            sigmas[g] = np.inf
    for g, group in enumerate(groups):
        f, cx, cy, *distortion = fitted[g]
        matrix = np.array([[f, 0, cx], [0, f, cy], [0, 0, 1]])
        distortion = np.array([distortion[0], distortion[1], distortion[2], distortion[3], distortion[4]])
        group.camera = Camera(matrix, distortion, group.camera.width, group.camera.height)
        group.sigma = {INTRINSIC_NAMES[i]: float(s) for i, s in zip(free, sigmas[g])}
    return float(np.sqrt(np.mean(r ** 2)))


def _camera_points(poses: np.ndarray, n_cam: int, photo_index, tag_index, model, fixed_rotation, fixed_translation):
    """Each observation's tag corners (M, 4, 3) in its photo's camera frame, from the free photo poses (the first n_cam
    values, six per photo; index -1 the fixed first photo) and the tag poses (the rest, six per tag)."""
    cams, tags = poses[:n_cam].reshape(-1, 6), poses[n_cam:].reshape(-1, 6)
    world = np.einsum("tij,kj->tki", rotation_matrices(tags[:, :3]), model) + tags[:, None, 3:]
    rotations = np.concatenate([rotation_matrices(cams[:, :3]), fixed_rotation[None]])
    translations = np.concatenate([cams[:, 3:], fixed_translation[None]])
    return np.einsum("mij,mkj->mki", rotations[photo_index], world[tag_index]) + translations[photo_index][:, None]


def _leading_block_inverse(normal: np.ndarray, n: int) -> np.ndarray:
    """The leading n x n block of the inverse of a symmetric positive (semi-)definite matrix: the inverse of the Schur
    complement of the rest (the intrinsics' covariance with every pose marginalised). A direction the data do not
    determine (a near-zero eigenvalue of that complement) gets a practically infinite variance, not pinv's zero."""
    a, b, c = normal[:n, :n], normal[:n, n:], normal[n:, n:]
    c_solve = np.linalg.lstsq(c, b.T, rcond=1e-12)[0]
    schur = a - b @ c_solve
    scale = np.sqrt(np.maximum(np.diag(schur), 1e-300))
    values, vectors = np.linalg.eigh(schur / np.outer(scale, scale))
    inverse = np.where(values > 1e-10 * values.max(), 1.0 / np.maximum(values, 1e-300), 1e20)
    return (vectors * inverse) @ vectors.T / np.outer(scale, scale)


def describe(groups: list[CameraGroup]) -> list[dict]:
    """The JSON-ready record of the fitted cameras: photos, source, intrinsics and their standard uncertainties."""
    out = []
    for group in groups:
        camera = group.camera
        out.append({"name": group.name, "photos": len(group.photos), "initial": group.source,
                    "width": camera.width, "height": camera.height, "f_px": round(camera.focal_px, 3),
                    "cx": round(float(camera.matrix[0, 2]), 3), "cy": round(float(camera.matrix[1, 2]), 3),
                    "distortion": [round(float(v), 6) for v in camera.distortion.ravel()],
                    "sigma": {k: float(f"{v:.3g}") if np.isfinite(v) else None for k, v in group.sigma.items()}})
    return out


def weak_cameras(groups: list[CameraGroup]) -> list[tuple[CameraGroup, float]]:
    """Groups whose fitted focal length is uncertain beyond WEAK_FOCAL (relative), with that relative uncertainty."""
    return [(g, g.sigma.get("f", np.inf) / g.camera.focal_px) for g in groups
            if not g.sigma.get("f", np.inf) / g.camera.focal_px <= WEAK_FOCAL]
