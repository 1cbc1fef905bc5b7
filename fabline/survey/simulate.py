"""Synthetic survey photo sets with known truth: the built structure is the design plus a deviation field.

Each tag is rendered where the lens puts it (its black square's corners are projected exactly with
`cv2.projectPoints`, distortion included) by warping the tag image with a per-tag homography,
4x supersampled and area-averaged, over a textured background with the lamellas drawn in; then lighting
changes, Gaussian blur and sensor noise. Written: the photos, `camera.json`, `tagmap.json` and
`truth.json` (every node's true built position and deviation, every photo's pose and visible tags).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from fabline.fileio import atomic_output, write_json
from fabline.model import Lamella, Network, Node, validate
from fabline.progress import progress
from fabline.survey.camera import Camera, save_camera
from fabline.survey.detect import APRILTAG_ORDER, tag_object_points, write_image
from fabline.survey.tagmap import TAG_CELLS, TagMap, make_tag_map, save_tag_map, tag_image

TRUTH_SCHEMA = "fabline.survey-truth/1"
SUPERSAMPLE = 4
MAX_VIEW_ANGLE_DEG = 70.0
MAX_CELL_TEXELS = 256
"""Most texels a tag cell has in its render texture (a 2560 px square): tags up to 640 px a side get one a
supersampled pixel."""
FINE_BAND_PX = 2**23
"""Most supersampled pixels one tag renders at once (32 MB a float32 buffer): bounds memory for tags near the lens."""


@dataclass
class SyntheticSpec:
    """How to photograph the built structure: camera, photo count, image degradations and deviation."""

    photos: int = 32
    width: int = 6000
    height: int = 4000
    focal_px: float = 5000.0
    distortion: tuple[float, ...] = (-0.08, 0.05, 4e-4, -3e-4, 0.0)
    noise_sigma: float = 2.0
    blur_sigma: float = 0.7
    sag_mm: float = 25.0
    tag_size_mm: float = 65.0
    mount_offset_mm: float = 20.0
    every: int = 1
    coverage: float = 0.45
    min_side_px: float = 16.0
    jpeg_quality: int = 95
    seed: int = 1
    # site mistakes: (printed, instead_of) pairs, the tag `instead_of`'s node carrying a copy of tag `printed`
    misprints: tuple[tuple[int, int], ...] = ()
    # a camera unknown to the survey: focal length, principal point and distortion drawn at random from `seed`
    # (`focal_px` and `distortion` then unused), as a phone or a zoom lens nobody calibrated
    random_camera: bool = False
    # EXIF written into the photos (camera model and the focal length in 35 mm equivalent, whole mm as phones
    # write it); None writes none
    exif_model: str | None = None

    def camera(self) -> Camera:
        """The simulated camera's intrinsics (principal point slightly off centre, as in real lenses); drawn at random
        with `random_camera`: focal length 0.6-1.2 of the width, principal point within 2 % of the centre, square
        pixels, k1 -0.25..0.05, k2 -0.05..0.2, p1 and p2 within 1e-3, k3 -0.05..0.05."""
        if self.random_camera:
            rng = np.random.default_rng([self.seed, 1802])
            focal = self.width * rng.uniform(0.6, 1.2)
            centre = [(self.width - 1) / 2, (self.height - 1) / 2] + rng.uniform(-0.02, 0.02, 2) * [self.width, self.height]
            distortion = [rng.uniform(-0.25, 0.05), rng.uniform(-0.05, 0.2), *rng.uniform(-1e-3, 1e-3, 2),
                          rng.uniform(-0.05, 0.05)]
            matrix = np.array([[focal, 0, centre[0]], [0, focal, centre[1]], [0, 0, 1]])
            return Camera(matrix, np.array(distortion), self.width, self.height)
        matrix = np.array([[self.focal_px, 0, self.width / 2 - 0.5 + 0.004 * self.width],
                           [0, self.focal_px * 1.0005, self.height / 2 - 0.5 - 0.003 * self.height], [0, 0, 1]])
        return Camera(matrix, np.array(self.distortion, dtype=float), self.width, self.height)


def saddle_network(span_m: float = 9.0, spacing_m: float = 0.35, radius_m: float = 8.0, name: str = "saddle") -> Network:
    """A demonstration gridshell: nodes on the saddle z = (x^2 - y^2) / 2R on a square grid, in metres.

    Lamellas are the grid's rows (family A) and columns (family B); the corner nodes are the supports.
    """
    count = max(int(round(span_m / spacing_m)), 1) + 1
    ticks = np.linspace(-span_m / 2, span_m / 2, count)
    nodes, grid = {}, {}
    for i, x in enumerate(ticks):
        for j, y in enumerate(ticks):
            normal = np.array([-x / radius_m, y / radius_m, 1.0])
            corner = i in (0, count - 1) and j in (0, count - 1)
            nid = f"n{i:02d}-{j:02d}"
            nodes[nid] = Node(nid, np.array([x, y, (x * x - y * y) / (2 * radius_m)]), normal / np.linalg.norm(normal),
                              "support" if corner else ("edge-end" if i in (0, count - 1) or j in (0, count - 1) else "grid"))
            grid[i, j] = nid
    lamellas = []
    for family, chains in (("A", [[grid[i, j] for j in range(count)] for i in range(count)]),
                           ("B", [[grid[i, j] for i in range(count)] for j in range(count)])):
        for k, chain in enumerate(chains):
            lamellas.append(Lamella(f"{family}{k}", family, chain, np.array([nodes[n].xyz for n in chain]),
                                    np.array([nodes[n].normal for n in chain])))
    return validate(Network("m", nodes, lamellas, name))


def sag_field(design_mm: np.ndarray, kinds: list[str], amplitude_mm: float) -> np.ndarray:
    """A smooth downward sag (N, 3) in mm: zero at the supports, `amplitude_mm` at the node farthest from them.

    Without supports the sag is a paraboloid over the plan, largest at the centre, zero at the farthest node.
    """
    supports = design_mm[[k == "support" for k in kinds]]
    if len(supports):
        distance = np.min(np.linalg.norm(design_mm[:, None, :2] - supports[None, :, :2], axis=2), axis=1)
        weight = np.sin(0.5 * np.pi * distance / max(distance.max(), 1e-9)) ** 2
    else:
        radius = np.linalg.norm(design_mm[:, :2] - design_mm[:, :2].mean(axis=0), axis=1)
        weight = 1.0 - (radius / max(radius.max(), 1e-9)) ** 2
    deviation = np.zeros_like(design_mm)
    deviation[:, 2] = -amplitude_mm * weight
    return deviation


def look_at(position: np.ndarray, target: np.ndarray, roll: float) -> np.ndarray:
    """World-to-camera rotation of a camera at `position` looking at `target`, image x level with the ground (the
    view not vertical), turned by `roll` radians about its axis."""
    forward = (target - position) / np.linalg.norm(target - position)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    c, s = np.cos(roll), np.sin(roll)
    return np.array([c * right + s * down, -s * right + c * down, forward])


def tag_centres(model: Network, tag_map: TagMap, positions: np.ndarray | None = None):
    """The tagged nodes in tag order, their tags' centres (N, 3) mm and the tags' normals (N, 3): tags sit on the top
    washer, so along the node normal turned upwards, `mount_offset_mm` above the node (`positions`: the nodes' own
    positions in `model.node_array()` order, default the design's)."""
    ids, design, normals = model.node_array()
    index_of = {nid: i for i, nid in enumerate(ids)}
    tags = sorted(tag_map.node_of_tag)
    rows = np.array([index_of[tag_map.node_of_tag[t]] for t in tags], dtype=int)
    up = normals[rows] * np.where(normals[rows][:, 2] < 0, -1.0, 1.0)[:, None]
    where = design if positions is None else positions
    return [ids[r] for r in rows], where[rows] + tag_map.mount_offset_mm * up, up


def camera_poses(points_mm: np.ndarray, normals: np.ndarray, spec: SyntheticSpec,
                 rng: np.random.Generator) -> list[tuple[np.ndarray, np.ndarray]]:
    """World-to-camera (R, t) for each photo: aimed at spread-out nodes, looking along their local normal.

    Aim points are picked by farthest-point sampling over the nodes; each view direction is the mean
    tag normal around the aim point, tilted by up to 25 degrees, kept above the horizon.
    """
    extent = np.ptp(points_mm, axis=0)
    half_fov = np.arctan(0.5 * min(spec.width, spec.height) / spec.camera().matrix[0, 0])
    distance = spec.coverage * max(extent[0], extent[1]) / (2 * np.tan(half_fov))
    chosen = [int(rng.integers(len(points_mm)))]
    gap = np.linalg.norm(points_mm - points_mm[chosen[0]], axis=1)
    while len(chosen) < spec.photos:
        chosen.append(int(np.argmax(gap)))
        gap = np.minimum(gap, np.linalg.norm(points_mm - points_mm[chosen[-1]], axis=1))
    poses = []
    for index in chosen:
        aim = points_mm[index]
        near = np.linalg.norm(points_mm - aim, axis=1) < 0.25 * max(extent[0], extent[1])
        view = normals[near].mean(axis=0) + rng.normal(0, 0.3, 3)
        view[2] = max(view[2], 0.35 * np.linalg.norm(view[:2]))
        view /= np.linalg.norm(view)
        position = aim + distance * view
        rotation = look_at(position, aim, rng.uniform(-0.15, 0.15))
        poses.append((rotation, -rotation @ position))
    return poses


def _tag_frames(normals: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Tag orientations (N, 3, 3), columns x, y, z: z along the node normal, a random turn about it."""
    frames = np.empty((len(normals), 3, 3))
    for i, n in enumerate(normals):
        helper = np.array([1.0, 0, 0]) if abs(n[0]) < 0.9 else np.array([0, 1.0, 0])
        x = np.cross(helper, n)
        x /= np.linalg.norm(x)
        y = np.cross(n, x)
        angle = rng.uniform(0, 2 * np.pi)
        frames[i] = np.column_stack([np.cos(angle) * x + np.sin(angle) * y, -np.sin(angle) * x + np.cos(angle) * y, n])
    return frames


def _background(spec: SyntheticSpec, rng: np.random.Generator) -> np.ndarray:
    coarse = rng.uniform(70, 170, size=(max(spec.height // 150, 2), max(spec.width // 150, 2))).astype(np.float32)
    image = cv2.resize(coarse, (spec.width, spec.height), interpolation=cv2.INTER_CUBIC)
    fine = rng.normal(0, 12, size=(spec.height // 8 + 1, spec.width // 8 + 1)).astype(np.float32)
    image += cv2.resize(fine, (spec.width, spec.height), interpolation=cv2.INTER_LINEAR)
    return image


def _draw_lamella(photo: np.ndarray, curve_cam: np.ndarray, camera: Camera) -> None:
    """Draw a lamella (its centre line in camera coordinates, mm) as a dark 30 mm wide band.

    Only the stretches inside the field of view (with a margin) are drawn: far outside it the lens
    polynomial is meaningless.
    """
    reach = 1.2 * max(camera.width, camera.height) / camera.focal_px
    inside = (curve_cam[:, 2] > 0) & np.all(np.abs(curve_cam[:, :2]) < reach * np.abs(curve_cam[:, 2:3]), axis=1)
    runs = np.split(np.arange(len(curve_cam)), np.flatnonzero(np.diff(inside.astype(int))) + 1)
    for run in runs:
        if len(run) < 2 or not inside[run[0]]:
            continue
        line = camera.project(curve_cam[run])
        width = max(2, int(camera.focal_px * 30.0 / np.median(curve_cam[run, 2])))
        cv2.polylines(photo, [np.round(line * 16).astype(np.int32)], False, 55.0, width, cv2.LINE_8, shift=4)


def _render_tag(photo: np.ndarray, tag_id: int, black_corners: np.ndarray, shade: float) -> None:
    """Warp tag `tag_id` (with its white quiet zone) into `photo` so its black square lands on `black_corners` (4, 2) px,
    in the AprilTag order (`fabline.survey.detect`).

    Supersampled 4x from a texture of about one texel per supersampled pixel (bilinear) and area-averaged. Memory is
    bounded whatever the tag's size in the photo (a tag near the lens spans it): the texture has at most
    MAX_CELL_TEXELS a cell (a larger tag's edges are then a ramp of a few supersampled pixels, centred on the true
    edge), and a tag whose supersampled window exceeds FINE_BAND_PX is rendered in bands of rows.
    """
    side = np.max(np.linalg.norm(black_corners - np.roll(black_corners, 1, axis=0), axis=1))
    cell = min(max(4, int(np.ceil(SUPERSAMPLE * side / TAG_CELLS))), MAX_CELL_TEXELS)
    texture = tag_image(tag_id, cell).astype(np.float32) * (195.0 / 255.0) + 25.0
    source = np.array([[cell, cell], [9 * cell, cell], [9 * cell, 9 * cell], [cell, 9 * cell]], dtype=np.float64) - 0.5
    to_image = cv2.getPerspectiveTransform(source.astype(np.float32), black_corners[APRILTAG_ORDER].astype(np.float32))
    outer = cv2.perspectiveTransform(np.array([[[-0.5, -0.5], [10 * cell - 0.5, -0.5], [10 * cell - 0.5, 10 * cell - 0.5],
                                                [-0.5, 10 * cell - 0.5]]]), to_image)[0]
    x0, y0 = np.floor(outer.min(axis=0)).astype(int) - 2
    x1, y1 = np.ceil(outer.max(axis=0)).astype(int) + 3
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, photo.shape[1]), min(y1, photo.shape[0])
    if x1 <= x0 or y1 <= y0:
        return
    s = SUPERSAMPLE
    rows = max(1, FINE_BAND_PX // ((x1 - x0) * s * s))
    for top in range(y0, y1, rows):
        bottom = min(top + rows, y1)
        to_fine = np.array([[s, 0, -s * x0 + (s - 1) / 2], [0, s, -s * top + (s - 1) / 2], [0, 0, 1]]) @ to_image
        size = ((x1 - x0) * s, (bottom - top) * s)
        fine = cv2.warpPerspective(texture, to_fine, size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        cover = cv2.warpPerspective(np.ones_like(texture), to_fine, size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        fine = cv2.resize(fine, (x1 - x0, bottom - top), interpolation=cv2.INTER_AREA)
        cover = cv2.resize(cover, (x1 - x0, bottom - top), interpolation=cv2.INTER_AREA)
        roi = photo[top:bottom, x0:x1]
        roi[:] = roi * (1 - cover) + fine * shade


def simulate_survey(network: Network, out_dir: str | os.PathLike, spec: SyntheticSpec | None = None,
                    tag_map: TagMap | None = None, poses: list[tuple[np.ndarray, np.ndarray]] | None = None) -> dict:
    """Render a photo set of the built structure into `out_dir`; return the truth record (also written).

    `poses`: the photos' world-to-camera (rotation matrix, translation mm), e.g. a photo plan's stations
    (`fabline.survey.plan`), instead of the simulator's own placement (`spec.photos` is then unused)."""
    spec = spec or SyntheticSpec()
    rng = np.random.default_rng(spec.seed)
    cv2.setRNGSeed(spec.seed)
    out_dir = Path(out_dir)
    model = network.in_mm()
    tag_map = tag_map or make_tag_map(model, spec.tag_size_mm, spec.mount_offset_mm, spec.every)
    ids, design, _ = model.node_array()
    kinds = [model.nodes[i].kind for i in ids]
    deviation = sag_field(design, kinds, spec.sag_mm)
    built = design + deviation
    tags = sorted(tag_map.node_of_tag)
    _, centres, facing_up = tag_centres(model, tag_map, built)
    frames = _tag_frames(facing_up, rng)
    # the AprilTag frame of each tag: x, y in its face, z into it (the tag image upright to an observer outside)
    apriltag_frames = frames @ np.diag([-1.0, 1.0, -1.0])
    corners_world = centres[:, None, :] + np.einsum("nij,kj->nki", apriltag_frames, tag_object_points(tag_map.tag_size_mm))
    outer_world = centres[:, None, :] + np.einsum("nij,kj->nki", frames, tag_object_points(tag_map.tag_size_mm * 10 / TAG_CELLS))
    camera = spec.camera()
    printed = {instead_of: copy for copy, instead_of in spec.misprints}
    sun = np.array([0.3, -0.4, 0.87])
    photos_dir = out_dir / "photos"
    photos_dir.mkdir(parents=True, exist_ok=True)
    photo_records = []
    placed = camera_poses(centres, frames[:, :, 2], spec, rng)  # drawn even when unused: the same noise either way
    poses = placed if poses is None else poses
    for k, (rotation, translation) in enumerate(progress(poses, "rendering photos")):
        photo = _background(spec, rng)
        for lamella in model.lamellas:
            _draw_lamella(photo, lamella.curve @ rotation.T + translation, camera)
        position = -rotation.T @ translation
        to_camera = position[None, :] - centres
        depth = np.linalg.norm(to_camera, axis=1)
        facing = np.einsum("ij,ij->i", frames[:, :, 2], to_camera) / depth
        cam_corners = corners_world @ rotation.T + translation
        cam_outer = outer_world @ rotation.T + translation
        drawable = (facing > np.cos(np.radians(85))) & np.all(cam_outer[..., 2] > 0.1 * depth[:, None], axis=1)
        label = np.full((spec.height, spec.width), -1, dtype=np.int32)
        pixels, outers = {}, {}
        for n in np.argsort(-depth):
            if not drawable[n]:
                continue
            pixels[n] = camera.project(cam_corners[n])
            outers[n] = camera.project(cam_outer[n])
            if np.any(np.abs(outers[n]) > 4 * max(spec.width, spec.height)):
                continue
            shade = float(np.clip(0.75 + 0.25 * np.dot(frames[n][:, 2], sun), 0.6, 1.0))
            _render_tag(photo, printed.get(tags[n], tags[n]), pixels[n], shade)
            cv2.fillConvexPoly(label, np.round(outers[n]).astype(np.int32), int(n))
        visible = {}
        for n, quad in pixels.items():
            side = np.min(np.linalg.norm(quad - np.roll(quad, 1, axis=0), axis=1))
            inside = np.all((outers[n] >= 3) & (outers[n] <= [spec.width - 4, spec.height - 4]))
            if not inside or side < spec.min_side_px or facing[n] < np.cos(np.radians(MAX_VIEW_ANGLE_DEG)):
                continue
            x0, y0 = np.floor(outers[n].min(axis=0)).astype(int)
            x1, y1 = np.ceil(outers[n].max(axis=0)).astype(int) + 1
            sub = np.zeros((y1 - y0, x1 - x0), dtype=np.uint8)
            cv2.fillConvexPoly(sub, np.round(outers[n] - [x0, y0]).astype(np.int32), 1)
            own = label[y0:y1, x0:x1][sub > 0]
            if own.size and np.mean(own == n) > 0.995 and tags[n] not in printed:
                visible[int(tags[n])] = np.round(quad, 4).tolist()
        del label  # one photo's buffers at a time: rendered, written, freed
        photo = _degrade(photo, spec, rng)
        name = f"photo-{k:03d}.jpg"
        if spec.exif_model:
            _write_with_exif(photos_dir / name, photo, spec.jpeg_quality, spec.exif_model, camera)
        else:
            write_image(photos_dir / name, photo, (cv2.IMWRITE_JPEG_QUALITY, spec.jpeg_quality))
        rvec, _ = cv2.Rodrigues(rotation)
        photo_records.append({"file": f"photos/{name}", "rotation": np.round(rvec.ravel(), 9).tolist(),
                              "translation_mm": np.round(translation, 4).tolist(),
                              "rendered": sorted(int(printed.get(tags[n], tags[n])) for n in pixels), "visible": visible})
    centre_of_node = {tag_map.node_of_tag[t]: centres[n] for n, t in enumerate(tags)}
    camera_path, tagmap_path = out_dir / "camera.json", out_dir / "tagmap.json"
    save_camera(camera, camera_path)
    save_tag_map(tag_map, tagmap_path)
    truth = {
        "schema": TRUTH_SCHEMA, "model": model.name, "units": "mm",
        "deviation": {"kind": "sag", "amplitude_mm": spec.sag_mm},
        "misprints": [{"printed": copy, "instead_of": instead_of} for copy, instead_of in spec.misprints],
        "camera": "camera.json", "tag_map": "tagmap.json",
        "nodes": {nid: {"design_mm": np.round(design[i], 4).tolist(), "built_mm": np.round(built[i], 4).tolist(),
                        "deviation_mm": np.round(deviation[i], 4).tolist(), "tag": tag_map.tag_of_node.get(nid),
                        "tag_centre_mm": (np.round(centre_of_node[nid], 4).tolist() if nid in centre_of_node else None)}
                  for i, nid in enumerate(ids)},
        "photos": photo_records,
    }
    write_json(out_dir / "truth.json", truth)
    return truth


def _write_with_exif(path: Path, photo: np.ndarray, quality: int, model: str, camera: Camera) -> None:
    """A JPEG (Pillow) with EXIF naming the camera `model` and its focal length in 35 mm equivalent, whole mm."""
    import io

    from PIL import Image

    exif = Image.Exif()
    exif[0x010F], exif[0x0110] = "fabline", model
    focal_35mm = int(round(camera.focal_px * np.hypot(36.0, 24.0) / np.hypot(camera.width, camera.height)))
    exif.get_ifd(0x8769)[0xA405] = focal_35mm
    buffer = io.BytesIO()
    Image.fromarray(photo).save(buffer, "JPEG", quality=quality, exif=exif)
    with atomic_output(path, "wb") as handle:
        handle.write(buffer.getvalue())


def _degrade(photo: np.ndarray, spec: SyntheticSpec, rng: np.random.Generator) -> np.ndarray:
    """Lighting gradient and exposure change, lens blur, and sensor noise; back to 8 bits."""
    h, w = photo.shape
    gain = rng.uniform(0.75, 1.15)
    tilt = rng.uniform(-0.2, 0.2, size=2)
    ramp_x = np.linspace(-1, 1, w, dtype=np.float32) * np.float32(tilt[0])
    ramp_y = np.linspace(-1, 1, h, dtype=np.float32) * np.float32(tilt[1])
    photo *= np.float32(gain)
    for top in range(0, h, 256):  # the gradient row band by row band: no second whole-image buffer
        photo[top:top + 256] *= (1 + ramp_y[top:top + 256, None]) * (1 + ramp_x[None, :])
    if spec.blur_sigma > 0:
        cv2.GaussianBlur(photo, (0, 0), spec.blur_sigma, dst=photo)
    if spec.noise_sigma > 0:
        noise = np.empty_like(photo)
        cv2.randn(noise, 0.0, spec.noise_sigma)
        photo += noise
        del noise
    photo += np.float32(0.5)
    np.clip(photo, 0, 255, out=photo)
    return photo.astype(np.uint8)


def render_plane_photo(texture: np.ndarray, mm_per_texel: float, camera: Camera, rotation: np.ndarray,
                       translation: np.ndarray, background: float = 110.0) -> np.ndarray:
    """Photograph a flat printed texture lying in the world plane z = 0 (texture x, y = world x, y in mm).

    Exact per pixel: each pixel's ray (lens distortion removed) is intersected with the plane and the
    texture sampled there; used for calibration boards, which span the whole lens.
    """
    v, u = np.mgrid[0:camera.height, 0:camera.width].astype(np.float64)
    rays = np.column_stack([camera.normalise(np.column_stack([u.ravel(), v.ravel()])), np.ones(u.size)])
    origin = -rotation.T @ translation
    directions = rays @ rotation
    depth = -origin[2] / directions[:, 2]
    plane = origin[None, :2] + depth[:, None] * directions[:, :2]
    map_x = (plane[:, 0] / mm_per_texel - 0.5).reshape(u.shape).astype(np.float32)
    map_y = (plane[:, 1] / mm_per_texel - 0.5).reshape(u.shape).astype(np.float32)
    map_x[(depth <= 0).reshape(u.shape)] = -1e6
    return cv2.remap(texture.astype(np.float32), map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                     borderValue=background)
