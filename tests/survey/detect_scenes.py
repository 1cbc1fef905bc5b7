"""Camera-like photos of AprilTag 36h11 tags with known ids and corners, drawn by OpenCV's own aruco module
(`cv2.aruco.generateImageMarker`), not by fabline: shared by tests/survey/test_detect_hard.py and
benchmarks/detect_bench.py.

Each tag is a square in space seen by a pinhole camera (slant up to 70 degrees, turned in the image plane), its
black square's corners projected exactly; the tag is warped in 4x supersampled and area-averaged, with its white
quiet zone (one cell, or a thin one of a fraction of a cell, on a dark background), at its own black and white
levels (dim, low contrast). The photo then gets a lighting gradient, Gaussian lens blur, gamma, sensor noise and
JPEG compression. Corners are in the AprilTag library's order (fabline.survey.detect's docstring), pixel centres on
integers. Tags seen edge-on (`edge_on`: 4-7 px across) are drawn too: their corners cannot be measured, so a
detector should not report them as tags.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

SUPERSAMPLE = 4
DICTIONARY = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)
TAG_IDS = 587
# the black square's corners of the tag as aruco draws it, upright: top-right, top-left, bottom-left, bottom-right
# (the AprilTag library's p0..p3), as unit-square coordinates
UNIT_SQUARE = np.array([[1.0, 0.0], [0.0, 0.0], [0.0, 1.0], [1.0, 1.0]])


@dataclass
class TagLook:
    """How one tag appears: black square side (px, before the slant), slant from frontal (deg), black and white
    grey levels, quiet zone width (cells), and the background grey around it (None: the photo's own)."""

    side_px: float
    slant_deg: float = 0.0
    black: float = 30.0
    white: float = 220.0
    quiet_cells: float = 1.0
    background: float | None = None


@dataclass
class Scene:
    """A rendered photo: the image, the tags a detector must find (id -> corners (4, 2)), and tags drawn edge-on that it
    must not report (id -> corners)."""

    image: np.ndarray
    tags: dict[int, np.ndarray] = field(default_factory=dict)
    edge_on: dict[int, np.ndarray] = field(default_factory=dict)
    looks: dict[int, TagLook] = field(default_factory=dict)


def tag_texture(tag_id: int, cell: int, quiet_cells: float) -> tuple[np.ndarray, int]:
    """Aruco's tag `tag_id` at `cell` px per cell, 0 black 1 white, padded with a white quiet zone of `quiet_cells`
    cells; and the padding in px."""
    marker = cv2.aruco.generateImageMarker(DICTIONARY, tag_id, 8 * cell, borderBits=1).astype(np.float32) / 255.0
    pad = int(round(quiet_cells * cell))
    return np.pad(marker, pad, constant_values=1.0), pad


def projected_corners(centre: np.ndarray, side_px: float, slant_deg: float, tilt_axis_deg: float, turn_deg: float,
                      focal_px: float, principal: np.ndarray) -> np.ndarray:
    """The black square's corners (4, 2) in px, AprilTag order, of a square tag whose centre is seen at `centre`,
    `side_px` across were it frontal, slanted from the line of sight about an in-plane axis at `tilt_axis_deg`,
    turned by `turn_deg`."""
    depth = focal_px * 1.0 / side_px  # a tag of unit side at this depth is side_px across frontal
    ray = np.array([(centre[0] - principal[0]) / focal_px, (centre[1] - principal[1]) / focal_px, 1.0])
    middle = ray * depth
    turn, axis, slant = np.radians([turn_deg, tilt_axis_deg, slant_deg])
    local = (UNIT_SQUARE - 0.5) @ np.array([[np.cos(turn), np.sin(turn)], [-np.sin(turn), np.cos(turn)]])
    points = np.column_stack([local, np.zeros(4)])
    rotation, _ = cv2.Rodrigues(np.array([np.cos(axis), np.sin(axis), 0.0]) * slant)
    # the slant is from the line of sight: the tag's frame turned so that its normal looks along the ray
    to_ray = np.cross([0.0, 0.0, 1.0], ray)
    towards, _ = cv2.Rodrigues(to_ray / max(np.linalg.norm(to_ray), 1e-12) * np.arctan(np.linalg.norm(ray[:2])))
    world = middle + points @ (towards @ rotation).T
    return focal_px * world[:, :2] / world[:, 2:] + principal


def draw_tag(canvas: np.ndarray, cover: np.ndarray, tag_id: int, corners: np.ndarray, look: TagLook) -> None:
    """Warp tag `tag_id` into `canvas` (float32 grey) so its black square lands on `corners` (AprilTag order, pixel
    centres on integers), 4x supersampled and area-averaged; `cover` (float32) gets its coverage."""
    side = np.max(np.linalg.norm(corners - np.roll(corners, 1, axis=0), axis=1))
    cell = max(2, int(np.ceil(SUPERSAMPLE * side / 8)))
    texture, pad = tag_texture(tag_id, cell, look.quiet_cells)
    # texture pixel centres on integers: the black square from pad - 0.5 to pad + 8 cell - 0.5
    source = (pad - 0.5 + 8 * cell * UNIT_SQUARE).astype(np.float32)
    to_image = cv2.getPerspectiveTransform(source, corners.astype(np.float32))
    size = texture.shape[0]
    outline = cv2.perspectiveTransform(np.array([[[-0.5, -0.5], [size - 0.5, -0.5], [size - 0.5, size - 0.5],
                                                  [-0.5, size - 0.5]]]), to_image)[0]
    x0, y0 = np.maximum(np.floor(outline.min(axis=0)).astype(int) - 2, 0)
    x1, y1 = np.minimum(np.ceil(outline.max(axis=0)).astype(int) + 3, [canvas.shape[1], canvas.shape[0]])
    if x1 <= x0 or y1 <= y0:
        return
    s = SUPERSAMPLE
    to_fine = np.array([[s, 0, -s * x0 + (s - 1) / 2], [0, s, -s * y0 + (s - 1) / 2], [0, 0, 1]]) @ to_image
    fine_size = ((x1 - x0) * s, (y1 - y0) * s)
    levels = look.black + (look.white - look.black) * texture
    fine = cv2.warpPerspective(levels, to_fine, fine_size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    inside = cv2.warpPerspective(np.ones_like(texture), to_fine, fine_size, flags=cv2.INTER_LINEAR,
                                 borderMode=cv2.BORDER_CONSTANT)
    fine = cv2.resize(fine, (x1 - x0, y1 - y0), interpolation=cv2.INTER_AREA)
    inside = cv2.resize(inside, (x1 - x0, y1 - y0), interpolation=cv2.INTER_AREA)
    region = canvas[y0:y1, x0:x1]
    if look.background is not None:  # the tag's own surround (a dark beam), a cell and a half beyond its quiet zone
        reach = cv2.dilate(inside, np.ones((2 * int(1.5 * side / 8) + 1,) * 2, np.uint8))
        region[:] = region * (1 - reach) + look.background * reach
    region[:] = region * (1 - inside) + fine
    cover[y0:y1, x0:x1] = np.maximum(cover[y0:y1, x0:x1], inside)


def background(height: int, width: int, rng: np.random.Generator) -> np.ndarray:
    """A cluttered grey background (float32): smooth blotches, dark and light bars and rectangles of a building site,
    a lighting gradient."""
    small = rng.normal(0, 1, (max(height // 64, 2), max(width // 64, 2))).astype(np.float32)
    image = 110 + 25 * cv2.resize(small, (width, height), interpolation=cv2.INTER_CUBIC)
    scale = max(width, height) / 1000
    for _ in range(int(40 * (width * height) ** 0.5 / 1000)):
        x, y = rng.uniform(0, width), rng.uniform(0, height)
        grey = float(rng.choice([rng.uniform(10, 60), rng.uniform(170, 240)]))
        if rng.random() < 0.5:  # a bar (lamella, strap, cable)
            length, angle = rng.uniform(50, 400) * scale, rng.uniform(0, np.pi)
            end = (int(x + length * np.cos(angle)), int(y + length * np.sin(angle)))
            cv2.line(image, (int(x), int(y)), end, grey, max(1, int(rng.uniform(2, 14) * scale)), cv2.LINE_AA)
        else:  # a box, a sign, a window
            w, h = rng.uniform(8, 120, 2) * scale
            box = cv2.boxPoints(((x, y), (w, h), rng.uniform(0, 90)))
            cv2.fillConvexPoly(image, box.astype(np.int32), grey, cv2.LINE_AA)
    ramp = np.linspace(0.75, 1.15, width, dtype=np.float32)[None, :] * np.linspace(1.1, 0.85, height,
                                                                                 dtype=np.float32)[:, None]
    return image * ramp


def finish(canvas: np.ndarray, rng: np.random.Generator, blur: float, noise: float, gamma: float,
           jpeg_quality: int) -> np.ndarray:
    """Lens blur, gamma, sensor noise and JPEG compression: the 8-bit photo."""
    photo = cv2.GaussianBlur(canvas, (0, 0), blur)
    photo = 255.0 * (np.clip(photo, 0, 255) / 255.0) ** gamma
    photo += rng.normal(0, noise, photo.shape).astype(np.float32)
    _, encoded = cv2.imencode(".jpg", np.clip(photo + 0.5, 0, 255).astype(np.uint8),
                              [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality])
    return cv2.imdecode(encoded, cv2.IMREAD_GRAYSCALE)


def random_look(rng: np.random.Generator, kind: str, scale: float) -> TagLook:
    """A tag's look of one `kind`: small, dim, low contrast, slanted, thin quiet zone, or plain (sizes by `scale`, the
    photo's width over 1000 px, for the large ones)."""
    if kind == "small":
        return TagLook(rng.uniform(10, 20), rng.uniform(0, 45))
    if kind == "dim":  # in the shade: a dark surround
        black = rng.uniform(5, 15)
        return TagLook(rng.uniform(12, 40), rng.uniform(0, 50), black, black + rng.uniform(35, 60),
                       background=black + rng.uniform(10, 25))
    if kind == "low contrast":
        black = rng.uniform(80, 120)
        return TagLook(rng.uniform(14, 80) * max(1.0, scale / 2), rng.uniform(0, 50), black, black + rng.uniform(25, 40))
    if kind == "slanted":
        return TagLook(rng.uniform(22, 60), rng.uniform(55, 70))
    if kind == "thin quiet zone":
        black = rng.uniform(15, 30)
        return TagLook(rng.uniform(13, 24), rng.uniform(0, 40), black, black + rng.uniform(60, 110),
                       rng.uniform(0.3, 0.6), background=rng.uniform(5, 20))
    return TagLook(rng.uniform(20, 120) * max(1.0, scale / 2), rng.uniform(0, 60))


KINDS = ("small", "dim", "low contrast", "slanted", "thin quiet zone", "plain")


def render_scene(width: int, height: int, seed: int, tags: int | None = None, edge_on: int = 2,
                 jpeg_quality: int = 90, kinds: tuple[str, ...] = KINDS) -> Scene:
    """A camera-like photo of `width` x `height` with `tags` tags (default: about one per 10 000 px, 8 to 120) of each
    of `kinds` in turn, and `edge_on` tags seen edge-on (tilted about an edge to 4-7 px across), none overlapping; ids
    at random."""
    rng = np.random.default_rng(seed)
    count = tags if tags is not None else int(np.clip(width * height / 10000, 8, 120))
    canvas = background(height, width, rng)
    cover = np.zeros_like(canvas)
    focal = 1.1 * max(width, height)
    principal = np.array([(width - 1) / 2, (height - 1) / 2])
    ids = rng.choice(TAG_IDS, count + edge_on, replace=False)
    scene = Scene(canvas)
    scale = width / 1000
    placed: list[tuple[np.ndarray, float]] = []
    for k, tag_id in enumerate(ids):
        edge = k >= count
        look = (TagLook(rng.uniform(40, 90), 0.0, 25.0, 220.0) if edge
                else random_look(rng, kinds[k % len(kinds)], scale))
        for _ in range(200):
            centre = rng.uniform([look.side_px, look.side_px], [width - look.side_px, height - look.side_px])
            axis, turn = rng.uniform(0, 180), rng.uniform(0, 360)
            if edge:  # tilted about its edge so that the tag is 4-7 px across: cells under a pixel
                axis = turn
                look.slant_deg = float(np.degrees(np.arccos(rng.uniform(4, 7) / look.side_px)))
            corners = projected_corners(centre, look.side_px, look.slant_deg, axis, turn, focal, principal)
            reach = 1.6 * np.max(np.linalg.norm(corners - corners.mean(axis=0), axis=1)) + 6
            if np.all(corners > 8) and np.all(corners < [width - 9, height - 9]) and all(
                    np.linalg.norm(corners.mean(axis=0) - c) > reach + r for c, r in placed):
                break
        else:
            continue
        placed.append((corners.mean(axis=0), reach))
        draw_tag(canvas, cover, int(tag_id), corners, look)
        (scene.edge_on if edge else scene.tags)[int(tag_id)] = corners
        scene.looks[int(tag_id)] = look
    blur = float(rng.uniform(0.6, 0.9)) * max(1.0, (width * height / 2e6) ** 0.25)
    scene.image = finish(canvas, rng, blur, float(rng.uniform(1.5, 3.0)), float(rng.uniform(0.8, 1.25)), jpeg_quality)
    return scene
