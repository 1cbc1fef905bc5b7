"""Multi-view reconstruction of tag poses: chained PnP and triangulation, then a sparse bundle adjustment.

Unknowns are every camera pose (except the first, which fixes the frame) and every tag pose; each tag
is a square of known size, which fixes the scale. Observations are the tags' detected corners,
undistorted once to normalised coordinates (the intrinsics are known), residuals are in pixels.
scipy's least_squares minimises them with a robust loss and a sparse Jacobian; observations that still
reproject badly are rejected and the adjustment repeated. Covariances come from the Gauss-Newton
normal equations, with the tags eliminated by a Schur complement.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import csr_matrix

from fabline.survey.camera import Camera
from fabline.survey.detect import tag_object_points
from fabline.survey.register import rigid_fit

ROBUST_SCALE_PX = 1.0
OUTLIER_PX = 2.0


@dataclass
class Observation:
    """Tag `tag` seen in photo `photo` with its corners (4, 2) in undistorted normalised coordinates."""

    photo: int
    tag: int
    normalised: np.ndarray


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

    def points_below_tags(self, offset: float) -> tuple[list[int], np.ndarray, np.ndarray]:
        """Tag ids, the points `offset` behind each tag centre along its normal (N, 3), their covariances (N, 3, 3).

        With the mounting offset this is each tagged node; the covariance carries the tag's rotation
        uncertainty through the offset lever arm.
        """
        ids = sorted(self.tag_poses)
        poses = np.array([self.tag_poses[t] for t in ids]).reshape(-1, 6)
        covariances = np.array([self.tag_covariances[t] for t in ids]).reshape(-1, 6, 6)
        points = poses[:, 3:] - offset * rotation_matrices(poses[:, :3])[:, :, 2]
        jacobian = np.zeros((len(ids), 3, 6))
        jacobian[:, :, :3] = -offset * rotation_derivatives(poses[:, :3], np.tile([0.0, 0.0, 1.0], (len(ids), 1)))
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
    """Adjust all camera and tag poses to the observed corners; reject outliers; estimate covariances."""
    model = tag_object_points(tag_size)
    first, cameras, tags, unjoined = initial_poses(observations, tag_size)
    used = [o for o in observations if o.photo in cameras and o.tag in tags]
    photo_ids = [first] + sorted(p for p in cameras if p != first)
    tag_ids = sorted({o.tag for o in used})
    params = np.concatenate([np.concatenate([_rvec(cameras[p][0]), cameras[p][1]]) for p in photo_ids[1:]]
                            + [np.concatenate([_rvec(tags[t][0]), tags[t][1]]) for t in tag_ids])
    focal = np.array([camera.matrix[0, 0], camera.matrix[1, 1]])
    rejected: list[tuple[int, int]] = []
    for _ in range(3):
        result, cam_index, tag_index, errors = _solve(used, photo_ids, tag_ids, params, model, focal)
        params = result.x
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
        used = kept
    n_free = len(photo_ids) - 1
    residual = result.fun
    dof = max(len(residual) - len(params), 1)
    variance = float(residual @ residual / dof)
    covariances = _tag_covariances(result.jac, n_free, len(tag_ids), variance)
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
        rejected=rejected, unregistered_photos=unjoined)


def _solve(used, photo_ids, tag_ids, params, model, focal):
    """One robust sparse least-squares run; returns the result, index arrays and per-observation RMS px."""
    photo_pos = {p: k for k, p in enumerate(photo_ids)}
    tag_pos = {t: k for k, t in enumerate(tag_ids)}
    cam_index = np.array([photo_pos[o.photo] for o in used])
    tag_index = np.array([tag_pos[o.tag] for o in used])
    observed = np.array([o.normalised for o in used])
    n_free = len(photo_ids) - 1

    def residuals(x: np.ndarray) -> np.ndarray:
        return ((_project(x, n_free, cam_index, tag_index, model) - observed) * focal).ravel()

    m = len(used)
    cam_cols = (cam_index - 1)[:, None] * 6 + np.arange(6)
    tag_cols = 6 * n_free + tag_index[:, None] * 6 + np.arange(6)
    cols = np.repeat(np.concatenate([cam_cols, tag_cols], axis=1)[:, None, :], 8, axis=1).reshape(8 * m, 12)
    rows = np.repeat(np.arange(8 * m)[:, None], 12, axis=1)
    keep = np.repeat(np.repeat((cam_index > 0)[:, None], 12, axis=1)[:, None, :], 8, axis=1).reshape(8 * m, 12)
    keep[:, 6:] = True  # the first photo's pose is fixed: no columns for it
    rows, cols = rows[keep], cols[keep]

    def jacobian(x: np.ndarray) -> csr_matrix:
        _, derivatives = _project(x, n_free, cam_index, tag_index, model, with_jacobian=True)
        values = (derivatives * focal[None, None, :, None]).reshape(8 * m, 12)[keep]
        return csr_matrix((values, (rows, cols)), shape=(8 * m, len(params)))

    result = least_squares(residuals, params, jac=jacobian, loss="soft_l1", f_scale=ROBUST_SCALE_PX,
                           x_scale="jac", method="trf", xtol=1e-8, ftol=1e-8, max_nfev=100)
    errors = np.sqrt(np.mean(residuals(result.x).reshape(m, 8) ** 2, axis=1))
    return result, cam_index, tag_index, errors


def _tag_covariances(jac, n_free: int, n_tags: int, variance: float) -> np.ndarray:
    """Covariance (n_tags, 6, 6) of each tag's pose (rotation vector, centre), from (J^T J)^-1 with the tags eliminated (Schur)."""
    jac = jac.tocsc()
    split = 6 * n_free
    j_cam, j_tag = jac[:, :split], jac[:, split:]
    u = (j_cam.T @ j_cam).toarray()
    w = (j_cam.T @ j_tag).toarray()
    v_sparse = (j_tag.T @ j_tag).tocsr()
    v_blocks = np.array([v_sparse[6 * k:6 * k + 6, 6 * k:6 * k + 6].toarray() for k in range(n_tags)])
    v_inv = np.linalg.inv(v_blocks + 1e-12 * np.eye(6))
    w_blocks = w.reshape(split, n_tags, 6).transpose(1, 0, 2)
    wv = np.einsum("kcj,kji->kci", w_blocks, v_inv)
    schur = u - np.einsum("kci,kdi->cd", wv, w_blocks)
    schur_inv = np.linalg.pinv(schur) if split else np.zeros((0, 0))
    blocks = v_inv + np.einsum("kci,cd,kdj->kij", wv, schur_inv, wv)
    return variance * blocks
