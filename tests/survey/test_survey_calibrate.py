"""ChArUco calibration on board photos rendered exactly through a known lens: the intrinsics come back."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from fabline.errors import FablineError
from fabline.survey import BoardSpec, Camera, board_image, calibrate, render_plane_photo, write_board

PIXELS_PER_MM = 8.0


def _view(target: np.ndarray, direction: np.ndarray, distance: float, roll: float) -> tuple[np.ndarray, np.ndarray]:
    """World-to-camera pose looking at `target` from `distance` along `direction` (board in z = 0, camera above)."""
    position = target + distance * direction / np.linalg.norm(direction)
    forward = (target - position) / np.linalg.norm(target - position)
    right = np.cross(forward, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    c, s = np.cos(roll), np.sin(roll)
    rotation = np.array([c * right + s * down, -s * right + c * down, forward])
    return rotation, -rotation @ position


@pytest.fixture(scope="module")
def board_photos(tmp_path_factory):
    folder = tmp_path_factory.mktemp("charuco")
    truth = Camera(np.array([[1100.0, 0, 652.0], [0, 1101.0, 471.0], [0, 0, 1]]), np.array([-0.12, 0.08, 5e-4, -3e-4, 0.0]), 1280, 960)
    spec = BoardSpec()
    texture = board_image(spec, PIXELS_PER_MM)
    centre = np.array([spec.squares_x * spec.square_mm / 2, spec.squares_y * spec.square_mm / 2, 0.0])
    rng = np.random.default_rng(11)
    paths = []
    for k in range(12):
        tilt = rng.uniform(-0.8, 0.8, 2) if k else np.zeros(2)
        aim = centre + np.append(rng.uniform([-110, -80], [110, 80]), 0.0)  # the board reaches every part of the image
        rotation, translation = _view(aim, np.array([tilt[0], tilt[1], -1.0]), rng.uniform(330, 420), rng.uniform(-0.3, 0.3))
        photo = render_plane_photo(texture, 1 / PIXELS_PER_MM, truth, rotation, translation)
        photo = cv2.GaussianBlur(photo, (0, 0), 0.6) + rng.normal(0, 1.5, photo.shape)
        paths.append(folder / f"board-{k}.png")
        cv2.imwrite(str(paths[-1]), np.clip(photo, 0, 255).astype(np.uint8))
    return truth, spec, paths


def test_calibration_recovers_the_lens(board_photos):
    truth, spec, paths = board_photos
    camera, skipped = calibrate(paths, spec)
    assert skipped == []
    assert (camera.width, camera.height) == (1280, 960)
    assert camera.reprojection_error_px < 0.3
    assert camera.matrix[0, 0] == pytest.approx(1100.0, rel=5e-3)
    assert camera.matrix[1, 1] == pytest.approx(1101.0, rel=5e-3)
    assert camera.matrix[0, 2] == pytest.approx(652.0, abs=4.0) and camera.matrix[1, 2] == pytest.approx(471.0, abs=4.0)
    # what matters is where the lens puts rays: compare both models' projections over the whole image
    grid = np.stack(np.meshgrid(np.linspace(-0.5, 0.5, 11), np.linspace(-0.38, 0.38, 9)), axis=-1).reshape(-1, 2)
    rays = np.column_stack([grid, np.ones(len(grid))])
    error = np.linalg.norm(camera.project(rays) - truth.project(rays), axis=1)
    # about 1 px is a principal-point shift a camera rotation absorbs; the lens itself is right (k1 alone moves corners 28 px)
    assert error.mean() < 1.5 and error.max() < 3.0


def test_bad_board_photos_are_skipped_by_name_and_too_few_is_an_error(board_photos, tmp_path):
    truth, spec, paths = board_photos
    (tmp_path / "noise.png").write_bytes(cv2.imencode(".png", np.full((960, 1280), 128, np.uint8))[1].tobytes())
    (tmp_path / "broken.jpg").write_bytes(b"nope")
    camera, skipped = calibrate(paths[:5] + [tmp_path / "noise.png", tmp_path / "broken.jpg"], spec)
    assert any("noise.png: found 0 board corners" in s for s in skipped)
    assert any("broken.jpg: cannot read the image" in s for s in skipped)
    with pytest.raises(FablineError, match=r"at least 4 photos, found it in 2"):
        calibrate(paths[:2] + [tmp_path / "noise.png"], spec)
    with pytest.raises(FablineError, match=r"marker < square"):
        BoardSpec(7, 5, 30.0, 40.0).board()


def test_written_board_is_true_to_its_spec(tmp_path):
    spec = BoardSpec(5, 4, 30.0, 22.0)
    write_board(spec, tmp_path / "board.png", pixels_per_mm=10)
    image = cv2.imread(str(tmp_path / "board.png"), cv2.IMREAD_GRAYSCALE)
    assert image.shape == (1200, 1500)
    corners, ids, _, _ = cv2.aruco.CharucoDetector(spec.board()).detectBoard(image)
    assert ids is not None and len(ids) == (5 - 1) * (4 - 1)
