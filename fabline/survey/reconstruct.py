"""Multi-view reconstruction of tag poses: chained PnP and triangulation, then a sparse bundle adjustment.

Unknowns are every camera pose (except the first, which fixes the frame) and every tag pose; each tag
is a square of known size, which fixes the scale. Observations marked scale-free (tags small in the
photo, whose detected size is biased) still place cameras and tags but do not set the scale: their
residual is projected off its derivative with respect to the tag's size (a free size per observation,
eliminated in closed form). Observations are the tags' detected corners,
undistorted once to normalised coordinates (the intrinsics are known), residuals are in pixels.
A Levenberg-Marquardt solver with a soft-L1 robust loss and an analytic sparse Jacobian minimises them,
solving each step through the Schur complement on the camera poses (scipy's least_squares with its
iterative sparse solver needed 80-100 s on the pavilion set, this solver a few seconds); observations
that still reproject badly are rejected and the adjustment repeated. Covariances come from the same
normal equations.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from fabline.survey.camera import Camera
from fabline.survey.detect import tag_object_points
from fabline.survey.register import rigid_fit
from fabline.survey.tagmap import TAG_CELLS

ROBUST_SCALE_PX = 1.0
OUTLIER_PX = 2.0


@dataclass
class Observation:
    """Tag `tag` seen in photo `photo` with its corners (4, 2) in undistorted normalised coordinates.

    `scale_free`: use the corners for the tag's direction and orientation only, not its apparent size.
    """

    photo: int
    tag: int
    normalised: np.ndarray
    scale_free: bool = False


@dataclass
class Reconstruction:
    """Camera and tag poses in the survey frame (mm), with tag-centre covariances and fit statistics."""

    camera_rotations: dict[int, np.ndarray]
    camera_translations: dict[int, np.ndarray]
    tag_poses: dict[int, np.ndarray]
    tag_covariances: dict[int, np.ndarray]
    observation_count: dict[int, int]
    rms_px: float
    rejected: list[tuple[int, int]] = field(default_factory=list)
    unregistered_photos: list[int] = field(default_factory=list)
    scale_free_observations: int = 0

    def scale_to_bars(self, bars: list[tuple[int, int, float]]) -> tuple[float, list[float]]:
        """Rescale the survey so measured distances between tag centres (tag, tag, mm) hold; return the factor and misfits.

        Reprojection is unchanged when all positions and the tag size scale together, so this is the
        adjustment's own solution with the tag size left free and the bars as hard constraints (several
        bars: the least-squares factor). Tag-centre covariances scale with the positions.
        """
        measured = np.array([np.linalg.norm(self.tag_poses[a][3:] - self.tag_poses[b][3:]) for a, b, _ in bars])
        lengths = np.array([length for _, _, length in bars], dtype=float)
        factor = float(np.dot(measured, lengths) / np.dot(measured, measured))
        scaling = np.diag([1.0, 1.0, 1.0, factor, factor, factor])
        for photo in self.camera_translations:
            self.camera_translations[photo] = factor * self.camera_translations[photo]
        for tag, pose in self.tag_poses.items():
            self.tag_poses[tag] = np.concatenate([pose[:3], factor * pose[3:]])
            self.tag_covariances[tag] = scaling @ self.tag_covariances[tag] @ scaling
        return factor, (factor * measured - lengths).tolist()

    def misplaced(self, observations: list["Observation"], tag_size: float) -> dict[int, tuple[list[int], list[int]]]:
        """Tags some photo shows away from where the reconstruction puts them, as a tag printed twice is: id -> (photos
        whose view of it is farther than its own side from where the adjustment projects it, the photos that agree).

        Bad corners move a tag by a fraction of its side; another copy of it lies elsewhere in the scene.
        """
        model = tag_object_points(tag_size)
        away: dict[int, list[int]] = {}
        agree: dict[int, list[int]] = {}
        for obs in observations:
            if obs.photo not in self.camera_rotations or obs.tag not in self.tag_poses:
                continue
            pose = self.tag_poses[obs.tag]
            world = model @ rotation_matrices(pose[None, :3])[0].T + pose[3:]
            in_camera = world @ self.camera_rotations[obs.photo].T + self.camera_translations[obs.photo]
            side = np.linalg.norm(obs.normalised - np.roll(obs.normalised, 1, axis=0), axis=1).min()
            behind = np.any(in_camera[:, 2] <= 0)
            gap = np.inf if behind else np.linalg.norm((in_camera[:, :2] / in_camera[:, 2:]).mean(axis=0)
                                                       - obs.normalised.mean(axis=0))
            (away if gap > side else agree).setdefault(obs.tag, []).append(obs.photo)
        return {tag: (photos, agree.get(tag, [])) for tag, photos in away.items()}

    def predict_corners(self, photo: int, camera: Camera, tag_size: float,
                        max_view_angle_deg: float = 80.0) -> dict[int, np.ndarray]:
        """Where photo `photo` should show each reconstructed tag: id -> corners (4, 2) in px, detection order.

        Only tags in front of the camera, facing it within `max_view_angle_deg`, whose quiet zone (one
        cell around the black square) lies inside the photo.
        """
        if photo not in self.camera_rotations or not self.tag_poses:
            return {}
        ids = sorted(self.tag_poses)
        poses = np.array([self.tag_poses[t] for t in ids])
        rotations = rotation_matrices(poses[:, :3])
        square = tag_object_points(tag_size)
        outer = square * (TAG_CELLS + 2) / TAG_CELLS
        rotation, translation = self.camera_rotations[photo], self.camera_translations[photo]
        centre = -rotation.T @ translation
        to_camera = centre - poses[:, 3:]
        facing = -np.einsum("ni,ni->n", rotations[:, :, 2], to_camera) / np.linalg.norm(to_camera, axis=1)  # z: into the face
        points = np.einsum("nij,kj->nki", rotations, np.concatenate([square, outer])) + poses[:, None, 3:]
        in_camera = points @ rotation.T + translation
        reach = 1.2 * max(camera.width, camera.height) / min(camera.matrix[0, 0], camera.matrix[1, 1])
        ahead = np.all(in_camera[..., 2] > 0, axis=1)
        ahead[ahead] &= np.all(np.abs(in_camera[ahead, :, :2]) < reach * in_camera[ahead, :, 2:], axis=(1, 2))
        candidates = np.flatnonzero(ahead & (facing > np.cos(np.radians(max_view_angle_deg))))
        if not len(candidates):
            return {}
        pixels = camera.project(in_camera[candidates].reshape(-1, 3)).reshape(len(candidates), 8, 2)
        inside = np.all((pixels[:, 4:] >= 0) & (pixels[:, 4:] <= [camera.width - 1, camera.height - 1]), axis=(1, 2))
        return {ids[n]: pixels[k, :4] for k, n in enumerate(candidates) if inside[k]}

    def points_below_tags(self, offset: float) -> tuple[list[int], np.ndarray, np.ndarray]:
        """Tag ids, the points `offset` behind each tag centre along its normal (N, 3), their covariances (N, 3, 3).

        With the mounting offset this is each tagged node (the tag frame's z points into the face, towards it); the
        covariance carries the tag's rotation uncertainty through the offset lever arm.
        """
        ids = sorted(self.tag_poses)
        poses = np.array([self.tag_poses[t] for t in ids]).reshape(-1, 6)
        covariances = np.array([self.tag_covariances[t] for t in ids]).reshape(-1, 6, 6)
        points = poses[:, 3:] + offset * rotation_matrices(poses[:, :3])[:, :, 2]
        jacobian = np.zeros((len(ids), 3, 6))
        jacobian[:, :, :3] = offset * rotation_derivatives(poses[:, :3], np.tile([0.0, 0.0, 1.0], (len(ids), 1)))
        jacobian[:, :, 3:] = np.eye(3)
        return ids, points, np.einsum("nij,njk,nlk->nil", jacobian, covariances, jacobian)


def rotation_matrices(rvecs: np.ndarray) -> np.ndarray:
    """Rodrigues formula for many rotation vectors at once: (N, 3) -> (N, 3, 3)."""
    theta = np.linalg.norm(rvecs, axis=1)
    small = theta < 1e-12
    axis = rvecs / np.where(small, 1.0, theta)[:, None]
    k = _cross_matrices(axis)
    s, c = np.sin(theta)[:, None, None], (1 - np.cos(theta))[:, None, None]
    return np.eye(3)[None] + s * k + c * (k @ k)


def _rvec(matrix: np.ndarray) -> np.ndarray:
    return cv2.Rodrigues(np.ascontiguousarray(matrix))[0].ravel()


def _triangulate(rays: list[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> np.ndarray:
    """Linear (DLT) triangulation of one point from (R, t, normalised xy) in two or more views."""
    rows = []
    for rotation, translation, xy in rays:
        projection = np.column_stack([rotation, translation])
        rows.append(xy[0] * projection[2] - projection[0])
        rows.append(xy[1] * projection[2] - projection[1])
    _, _, vt = np.linalg.svd(np.array(rows))
    return vt[-1, :3] / vt[-1, 3]


def initial_poses(observations: list[Observation], tag_size: float):
    """Camera and tag poses before adjustment: start from the photo with most tags, add photos by PnP.

    Each new tag is triangulated from the registered photos that see it (or, seen once, placed by its
    single-view square pose). Returns camera poses, tag poses and the photos that could not be joined.
    """
    model = tag_object_points(tag_size)
    by_photo: dict[int, list[Observation]] = {}
    for obs in observations:
        by_photo.setdefault(obs.photo, []).append(obs)
    single = {}
    for obs in observations:
        ok, rvecs, tvecs, errors = cv2.solvePnPGeneric(model, obs.normalised.reshape(4, 1, 2), np.eye(3), None,
                                                        flags=cv2.SOLVEPNP_IPPE_SQUARE)
        best = int(np.argmin(np.ravel(errors)))
        single[obs.photo, obs.tag] = (cv2.Rodrigues(rvecs[best])[0], np.ravel(tvecs[best]))
    cameras: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    tags: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    seen_by: dict[int, list[Observation]] = {}
    single_view: set[int] = set()
    first = max(by_photo, key=lambda p: (len(by_photo[p]), -p))
    pending = set(by_photo)

    def triangulate(tag: int) -> None:
        views = [o for o in seen_by[tag] if o.photo in cameras]
        corners = np.array([_triangulate([(*cameras[o.photo], o.normalised[c]) for o in views]) for c in range(4)])
        tags[tag] = rigid_fit(model, corners)
        single_view.discard(tag)

    def join(photo: int, rotation: np.ndarray, translation: np.ndarray) -> None:
        cameras[photo] = (rotation, translation)
        pending.discard(photo)
        for obs in by_photo[photo]:
            seen_by.setdefault(obs.tag, []).append(obs)
            if obs.tag not in tags:
                tag_rotation, tag_translation = single[photo, obs.tag]
                tags[obs.tag] = (rotation.T @ tag_rotation, rotation.T @ (tag_translation - translation))
                single_view.add(obs.tag)
            elif obs.tag in single_view:
                triangulate(obs.tag)  # a second view: replace the (possibly flipped) one-view square pose

    join(first, np.eye(3), np.zeros(3))
    while pending:
        counts = {p: sum(o.tag in tags and o.tag not in single_view for o in by_photo[p]) + 0.5 * sum(o.tag in single_view for o in by_photo[p])
                  for p in pending}
        photo = max(counts, key=lambda p: (counts[p], -p))
        if counts[photo] < 1.5:
            break
        known = [o for o in by_photo[photo] if o.tag in tags and o.tag not in single_view]
        if len(known) < 3:
            known = [o for o in by_photo[photo] if o.tag in tags]
        world = np.concatenate([model @ tags[o.tag][0].T + tags[o.tag][1] for o in known])
        image = np.concatenate([o.normalised for o in known])
        ok, rvec, tvec, inliers = cv2.solvePnPRansac(world, image.reshape(-1, 1, 2), np.eye(3), None,
                                                     reprojectionError=0.002, flags=cv2.SOLVEPNP_SQPNP)
        if not ok or inliers is None or len(inliers) < 6:
            pending.discard(photo)
            continue
        rvec, tvec = cv2.solvePnPRefineLM(world[inliers.ravel()], image[inliers.ravel()].reshape(-1, 1, 2),
                                          np.eye(3), None, rvec, tvec)
        join(photo, cv2.Rodrigues(rvec)[0], tvec.ravel())
    for tag in [t for t in tags if len(seen_by[t]) >= 2]:
        triangulate(tag)  # with every view that joined, not only those before the tag's second one
    unjoined = sorted(set(by_photo) - set(cameras))
    return first, cameras, tags, unjoined


def rotation_derivatives(rvecs: np.ndarray, vectors: np.ndarray) -> np.ndarray:
    """d(R(r) v)/dr (N, 3, 3) for rotation vectors r (N, 3) and vectors v (N, 3), in closed form.

    Gallego & Yezzi (2015): d(Rv)/dr = -R [v]x (r r^T + (R^T - I) [r]x) / |r|^2, and -[v]x at r = 0.
    """
    theta2 = np.einsum("ni,ni->n", rvecs, rvecs)
    rotations = rotation_matrices(rvecs)
    v_cross, r_cross = _cross_matrices(vectors), _cross_matrices(rvecs)
    small = theta2 < 1e-14
    inner = (np.einsum("ni,nj->nij", rvecs, rvecs)
             + (rotations.transpose(0, 2, 1) - np.eye(3)[None]) @ r_cross) / np.where(small, 1.0, theta2)[:, None, None]
    inner[small] = np.eye(3)
    return -rotations @ v_cross @ inner


def _cross_matrices(vectors: np.ndarray) -> np.ndarray:
    """[v]x (N, 3, 3), the matrices with [v]x w = v x w."""
    out = np.zeros((len(vectors), 3, 3))
    out[:, 0, 1], out[:, 0, 2], out[:, 1, 2] = -vectors[:, 2], vectors[:, 1], -vectors[:, 0]
    out[:, 1, 0], out[:, 2, 0], out[:, 2, 1] = vectors[:, 2], -vectors[:, 1], vectors[:, 0]
    return out


def _project(params: np.ndarray, n_free: int, cam_index: np.ndarray, tag_index: np.ndarray, model: np.ndarray,
             with_jacobian: bool = False):
    """Normalised projections (M, 4, 2) of each observation's four tag corners.

    With `with_jacobian`, also their derivatives (M, 4, 2, 12): six columns for the photo's pose
    (rotation vector, translation), six for the tag's.
    """
    cam = np.concatenate([np.zeros((1, 6)), params[:6 * n_free].reshape(-1, 6)])
    tag = params[6 * n_free:].reshape(-1, 6)
    cam_r = rotation_matrices(cam[:, :3])
    tag_r = rotation_matrices(tag[:, :3])
    world = np.einsum("tij,kj->tki", tag_r, model) + tag[:, None, 3:]
    rotation = cam_r[cam_index]
    points = np.einsum("mij,mkj->mki", rotation, world[tag_index]) + cam[cam_index][:, None, 3:]
    projected = points[..., :2] / points[..., 2:3]
    if not with_jacobian:
        return projected
    m = len(cam_index)
    inverse_depth = 1.0 / points[..., 2]
    d_proj = np.zeros((m, 4, 2, 3))
    d_proj[..., 0, 0] = d_proj[..., 1, 1] = inverse_depth
    d_proj[..., :, 2] = -projected * inverse_depth[..., None]
    d_points = np.empty((m, 4, 3, 12))
    d_points[..., 0:3] = rotation_derivatives(np.repeat(cam[cam_index, :3], 4, axis=0),
                                              world[tag_index].reshape(-1, 3)).reshape(m, 4, 3, 3)
    d_points[..., 3:6] = np.eye(3)
    tag_derivative = rotation_derivatives(tag[:, :3].repeat(4, axis=0), np.tile(model, (len(tag), 1))).reshape(-1, 4, 3, 3)
    d_points[..., 6:9] = np.einsum("mij,mkjl->mkil", rotation, tag_derivative[tag_index])
    d_points[..., 9:12] = rotation[:, None]
    return projected, d_proj @ d_points


def bundle_adjust(observations: list[Observation], camera: Camera, tag_size: float) -> Reconstruction:
    """Adjust all camera and tag poses to the observed corners; reject outliers; estimate covariances.

    Scale-free observations are honoured for tags seen in two or more photos (one view alone cannot place
    a tag without its size) and only while some observation is left to set the scale.
    """
    model = tag_object_points(tag_size)
    first, cameras, tags, unjoined = initial_poses(observations, tag_size)
    used = _scale_free_where_possible([o for o in observations if o.photo in cameras and o.tag in tags])
    photo_ids = [first] + sorted(p for p in cameras if p != first)
    tag_ids = sorted({o.tag for o in used})
    params = np.concatenate([np.concatenate([_rvec(cameras[p][0]), cameras[p][1]]) for p in photo_ids[1:]]
                            + [np.concatenate([_rvec(tags[t][0]), tags[t][1]]) for t in tag_ids])
    focal = np.array([camera.matrix[0, 0], camera.matrix[1, 1]])
    rejected: list[tuple[int, int]] = []
    for _ in range(3):
        params, blocks, residual, cam_index, tag_index, errors = _solve(used, photo_ids, tag_ids, params, model, focal)
        sigma = 1.4826 * np.median(errors)
        bad = errors > max(OUTLIER_PX, 5 * sigma)
        if not bad.any():
            break
        rejected += [(used[i].photo, used[i].tag) for i in np.flatnonzero(bad)]
        kept = [o for o, b in zip(used, bad) if not b]
        still_seen = {o.tag for o in kept}
        params = np.concatenate([params[:6 * (len(photo_ids) - 1)]]
                                + [params[6 * (len(photo_ids) - 1) + 6 * k:][:6] for k, t in enumerate(tag_ids) if t in still_seen])
        tag_ids = [t for t in tag_ids if t in still_seen]
        used = _scale_free_where_possible(kept)
    n_free = len(photo_ids) - 1
    dof = max(residual.size - len(params), 1)
    variance = float(np.sum(residual ** 2) / dof)
    covariances = _tag_covariances(blocks, variance)
    cam = params[:6 * n_free].reshape(-1, 6)
    tag = params[6 * n_free:].reshape(-1, 6)
    counts = np.bincount(tag_index, minlength=len(tag_ids))
    return Reconstruction(
        camera_rotations={first: np.eye(3), **{p: rotation_matrices(cam[k:k + 1, :3])[0] for k, p in enumerate(photo_ids[1:])}},
        camera_translations={first: np.zeros(3), **{p: cam[k, 3:].copy() for k, p in enumerate(photo_ids[1:])}},
        tag_poses={t: tag[k].copy() for k, t in enumerate(tag_ids)},
        tag_covariances=dict(zip(tag_ids, covariances)),
        observation_count={t: int(counts[k]) for k, t in enumerate(tag_ids)},
        rms_px=float(np.sqrt(np.mean(errors[errors <= max(OUTLIER_PX, 5 * 1.4826 * np.median(errors))] ** 2))),
        rejected=rejected, unregistered_photos=unjoined, scale_free_observations=sum(o.scale_free for o in used))


def _scale_free_where_possible(observations: list[Observation]) -> list[Observation]:
    """The observations with `scale_free` kept only where the tag has other views and some observation still sets the scale."""
    views: dict[int, int] = {}
    for obs in observations:
        views[obs.tag] = views.get(obs.tag, 0) + 1
    free = [obs.scale_free and views[obs.tag] >= 2 for obs in observations]
    if all(free):
        free = [False] * len(observations)
    return [Observation(o.photo, o.tag, o.normalised, f) for o, f in zip(observations, free)]


def _solve(used, photo_ids, tag_ids, params, model, focal):
    """One robust adjustment run; returns the solution, its normal-equation blocks, index arrays and per-observation RMS px."""
    photo_pos = {p: k for k, p in enumerate(photo_ids)}
    tag_pos = {t: k for k, t in enumerate(tag_ids)}
    cam_index = np.array([photo_pos[o.photo] for o in used])
    tag_index = np.array([tag_pos[o.tag] for o in used])
    observed = np.array([o.normalised for o in used])
    scale_free = np.array([o.scale_free for o in used], dtype=bool)
    n_free = len(photo_ids) - 1

    def evaluate(x: np.ndarray, with_jacobian: bool):
        out = _project(x, n_free, cam_index, tag_index, model, with_jacobian)
        projected, derivatives = out if with_jacobian else (out, None)
        residual = ((projected - observed) * focal).reshape(len(used), 8)
        if derivatives is not None:
            derivatives = (derivatives * focal[None, None, :, None]).reshape(len(used), 8, 12)
        if scale_free.any():
            size = _size_directions(x, n_free, cam_index[scale_free], tag_index[scale_free], model, focal)
            residual[scale_free] -= size * np.einsum("fr,fr->f", size, residual[scale_free])[:, None]
            if derivatives is not None:
                derivatives[scale_free] -= size[:, :, None] * np.einsum("fr,frc->fc", size, derivatives[scale_free])[:, None, :]
        return residual, derivatives

    x, blocks = _levenberg_marquardt(params, evaluate, cam_index, tag_index, n_free, len(tag_ids))
    residual, _ = evaluate(x, False)
    errors = np.sqrt(np.mean(residual ** 2, axis=1))
    return x, blocks, residual, cam_index, tag_index, errors


def _size_directions(params, n_free, cam_index, tag_index, model, focal, step: float = 1e-4) -> np.ndarray:
    """Unit directions (F, 8) in which the observations' residuals move when the tag's size changes (central difference).

    Projecting a residual and its Jacobian off this direction is the linearised elimination of a free
    size per observation (variable projection), so the observation carries no information on the scale.
    """
    larger = _project(params, n_free, cam_index, tag_index, model * (1 + step))
    smaller = _project(params, n_free, cam_index, tag_index, model * (1 - step))
    direction = ((larger - smaller) * focal).reshape(len(cam_index), 8)
    return direction / np.linalg.norm(direction, axis=1, keepdims=True)


def _robust_cost(residual: np.ndarray) -> float:
    """Soft-L1 cost: quadratic below ROBUST_SCALE_PX, linear above, so a few bad corners cannot dominate."""
    z = (residual / ROBUST_SCALE_PX) ** 2
    return float(ROBUST_SCALE_PX ** 2 * np.sum(np.sqrt(1 + z) - 1))


def _levenberg_marquardt(params, evaluate, cam_index, tag_index, n_free, n_tags, iterations: int = 50):
    """Minimise the soft-L1 reprojection cost by Levenberg-Marquardt with iteratively reweighted Gauss-Newton steps.

    Each step solves the sparse normal equations through the Schur complement on the camera poses
    (the standard bundle-adjustment solver): the tag blocks are 6 x 6 and inverted directly.
    Returns the solution and the unweighted normal-equation blocks at it, for the covariances.
    """
    x = params.copy()
    residual, derivatives = evaluate(x, True)
    cost, damping = _robust_cost(residual), 1e-4
    for _ in range(iterations):
        weights = 1.0 / np.sqrt(np.sqrt(1 + (residual / ROBUST_SCALE_PX) ** 2))  # square root of the IRLS weight
        blocks = _normal_blocks(derivatives * weights[..., None], residual * weights, cam_index, tag_index, n_free, n_tags)
        while True:
            step = _schur_solve(blocks, damping)
            trial = x + step
            trial_residual, _ = evaluate(trial, False)
            trial_cost = _robust_cost(trial_residual)
            if trial_cost < cost or damping > 1e8:
                break
            damping *= 10
        if trial_cost >= cost:
            break
        improvement = cost - trial_cost
        x, cost, damping = trial, trial_cost, max(damping / 10, 1e-9)
        residual, derivatives = evaluate(x, True)
        if improvement < 1e-9 * cost or np.linalg.norm(step) < 1e-10 * (np.linalg.norm(x) + 1e-10):
            break
    return x, _normal_blocks(derivatives, residual, cam_index, tag_index, n_free, n_tags)


def _normal_blocks(derivatives, residual, cam_index, tag_index, n_free, n_tags):
    """J^T J and J^T r in blocks: cameras U (6C, 6C) dense, tags V (T, 6, 6), coupling W (6C, T, 6), gradients.

    `derivatives` (M, 8, 12) holds each observation's Jacobian rows: six camera columns, six tag columns;
    the first photo's pose is fixed, so its camera columns are dropped.
    """
    d_cam, d_tag = derivatives[..., :6], derivatives[..., 6:]
    free = cam_index > 0
    u = np.zeros((n_free + 1, 6, 6))
    np.add.at(u, cam_index, d_cam.transpose(0, 2, 1) @ d_cam)
    v = np.zeros((n_tags, 6, 6))
    np.add.at(v, tag_index, d_tag.transpose(0, 2, 1) @ d_tag)
    w = np.zeros((n_free + 1, n_tags, 6, 6))
    np.add.at(w, (cam_index, tag_index), d_cam.transpose(0, 2, 1) @ d_tag)
    g_cam = np.zeros((n_free + 1, 6))
    np.add.at(g_cam, cam_index[free], np.einsum("mri,mr->mi", d_cam[free], residual[free]))
    g_tag = np.zeros((n_tags, 6))
    np.add.at(g_tag, tag_index, np.einsum("mri,mr->mi", d_tag, residual))
    u_dense = np.zeros((6 * n_free, 6 * n_free))
    for k in range(n_free):
        u_dense[6 * k:6 * k + 6, 6 * k:6 * k + 6] = u[k + 1]
    w_dense = w[1:].transpose(0, 2, 1, 3).reshape(6 * n_free, n_tags, 6)
    return u_dense, v, w_dense, g_cam[1:].ravel(), g_tag


def _schur_solve(blocks, damping: float) -> np.ndarray:
    """The damped Gauss-Newton step (camera part first, then tags) from the normal-equation blocks."""
    u, v, w, g_cam, g_tag = blocks
    u = u + damping * np.diag(np.diag(u)) + 1e-9 * np.eye(len(u))  # a photo left without observations: no step
    v = v + damping * np.einsum("tii->ti", v)[:, :, None] * np.eye(6)[None]
    v_inv = np.linalg.inv(v)
    wv, schur = _eliminate_tags(u, v_inv, w)
    rhs = -g_cam + wv @ g_tag.ravel()
    step_cam = np.linalg.solve(schur, rhs) if len(rhs) else rhs
    step_tag = (v_inv @ (-g_tag - (w.reshape(len(u), 6 * len(v)).T @ step_cam).reshape(-1, 6))[:, :, None])[:, :, 0]
    return np.concatenate([step_cam, step_tag.ravel()])


def _eliminate_tags(u, v_inv, w):
    """W V^-1 as (6C, 6T) and the Schur complement U - W V^-1 W^T on the camera poses."""
    cams, tags = len(u), len(v_inv)
    wv = (w.transpose(1, 0, 2) @ v_inv).transpose(1, 0, 2).reshape(cams, 6 * tags)
    return wv, u - wv @ w.reshape(cams, 6 * tags).T


def _tag_covariances(blocks, variance: float) -> np.ndarray:
    """Covariance (T, 6, 6) of each tag's pose (rotation vector, centre): variance x the tag blocks of (J^T J)^-1 (Schur)."""
    u, v, w, _, _ = blocks
    v_inv = np.linalg.inv(v + 1e-12 * np.eye(6))
    wv, schur = _eliminate_tags(u, v_inv, w)
    schur_inv = np.linalg.pinv(schur) if len(schur) else schur
    per_tag = wv.reshape(len(u), len(v), 6).transpose(1, 0, 2)  # (T, 6C, 6)
    return variance * (v_inv + per_tag.transpose(0, 2, 1) @ schur_inv @ per_tag)
