"""The as-built survey: detect tags in every photo, reconstruct, register to the design, report per node.

After a first adjustment each photo is searched again where the reconstruction puts tags it did not
yield (tags too small or dim for the image alone), and the adjustment is repeated with what is found.

Bad photos (unreadable, another resolution, no tags) and unknown tag ids are reported by file and id and
left out; the survey goes on with the rest as long as the photos still join into one reconstruction.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from fabline.errors import FablineError
from fabline.fileio import write_json
from fabline.model import Network
from fabline.progress import progress
from fabline.survey.camera import Camera
from fabline.survey.detect import TagDetection, cell_width_px, detect_expected_tags, detect_tags, read_gray, write_image
from fabline.survey.reconstruct import Observation, Reconstruction, bundle_adjust
from fabline.survey.register import register
from fabline.units import mm
from fabline.survey.selfcal import (UNDETERMINED_FOCAL, CameraGroup, describe, group_photos, initial_camera, refine_cameras,
                                    weak_cameras)
from fabline.survey.tagmap import TagMap, check_tag_map

SURVEY_SCHEMA = "fabline.survey/1"
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp")
PREVIEW_WIDTH = 1600
SELF_CALIBRATION_ROUNDS = 2  # intrinsics fitted, corners normalised again, poses adjusted again


@dataclass
class MeasureOptions:
    """Tolerance (mm), the registration's reference nodes ('all', 'supports' or ids), views a node needs,
    and scale bars: (tag, tag, distance between their centres in mm) measured on site, which fix the scale.

    `scale_min_cell_px`: observations of tags whose narrowest cell is smaller than this in the photo place
    cameras and tags but do not set the scale (detection shrinks such tags by up to 1e-3; 0 uses all).
    `calibrate`: fit the intrinsics to the survey's own photos (`fabline.survey.selfcal`; always when no camera is
    given): focal length, principal point, k1, k2, p1, p2 and k3, or only the first five with `radial_only`;
    `camera_map`: photo file name -> camera name, for photos EXIF cannot group.
    `k_sigma`: a node passes when its deviation plus k times its standard uncertainty along the deviation is within the
    tolerance, fails when the deviation minus that is beyond it, and is "uncertain" otherwise (2: about 95 %).
    """

    tolerance_mm: float = 20.0
    reference: str | list[str] = "all"
    min_views: int = 2
    pictures: bool = True
    scale_bars: tuple[tuple[int, int, float], ...] = ()
    scale_min_cell_px: float = 4.0
    k_sigma: float = 2.0
    calibrate: bool = False
    radial_only: bool = False
    camera_map: dict[str, str] | None = None


def list_photos(folder: str | os.PathLike) -> list[Path]:
    """The image files in a folder, sorted by name; a missing or empty folder raises naming it."""
    folder = Path(folder)
    if not folder.is_dir():
        raise FablineError(f"{folder}: not a folder of photos")
    photos = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not photos:
        raise FablineError(f"{folder}: no photos ({', '.join(IMAGE_SUFFIXES)}) in this folder")
    return photos


def detect_photos(photos: list[Path], camera: Camera | None, known_tags: set[int] | None = None):
    """Detections per photo, the problems found (unreadable, wrong resolution, no tags, unknown ids, an id found twice
    in one photo), the ids found twice in one photo (id -> photo indices), which are left out of the detections, and
    each readable photo's size (width, height)."""
    detections: dict[int, list[TagDetection]] = {}
    sizes: dict[int, tuple[int, int]] = {}
    problems: list[dict] = []
    duplicated: dict[int, list[int]] = {}
    for k, path in enumerate(progress(photos, "detecting tags")):
        notes: list[str] = []
        try:
            gray = read_gray(path, notes)
            if camera is not None:
                camera.check_image(gray.shape, str(path))
        except FablineError as exc:
            problems.append({"file": str(path), "problem": str(exc)})
            continue
        problems += [{"file": str(path), "problem": note} for note in notes]
        sizes[k] = (gray.shape[1], gray.shape[0])
        found = detect_tags(gray)
        if not found:
            problems.append({"file": str(path), "problem": f"{path}: no tags found in this photo"})
        for det in found:
            if known_tags is not None and det.tag_id not in known_tags:
                problems.append({"file": str(path), "tag": det.tag_id,
                                 "problem": f"{path}: tag {det.tag_id} maps to no node of the model (ignored)"})
        found = [d for d in found if known_tags is None or d.tag_id in known_tags]
        ids = [d.tag_id for d in found]
        for tag in sorted({t for t in ids if ids.count(t) > 1}):
            places = ", ".join(f"({x:.0f}, {y:.0f})" for d in found if d.tag_id == tag for x, y in [d.corners.mean(axis=0)])
            problems.append({"file": str(path), "tag": tag,
                             "problem": f"{path}: tag {tag} appears {ids.count(tag)} times in this photo, at px {places}: "
                                        f"printed more than once? (left out of the survey; mount one copy only)"})
            duplicated.setdefault(tag, []).append(k)
        detections[k] = [d for d in found if d.tag_id not in duplicated]
    for k in detections:
        detections[k] = [d for d in detections[k] if d.tag_id not in duplicated]
    return detections, problems, duplicated, sizes


def find_predicted_tags(photos: list[Path], camera_of: dict[int, Camera], tag_size: float, reconstruction: Reconstruction,
                        detections: dict[int, list[TagDetection]]) -> list[tuple[int, TagDetection]]:
    """Look again, in each photo that joined, for the reconstructed tags it should show but did not yield.

    A tag too small or too blurred for the image alone to give its quad is found where the other photos
    put it (`detect_expected_tags`: refined there and kept only if it reads as that tag); the finds are
    added to `detections` and returned as (photo index, detection).
    """
    added = []
    for k in progress(sorted(reconstruction.camera_rotations), "looking for predicted tags"):
        seen = {d.tag_id for d in detections[k]}
        expected = {t: corners for t, corners in reconstruction.predict_corners(k, camera_of[k], tag_size).items() if t not in seen}
        if not expected:
            continue
        found = detect_expected_tags(read_gray(photos[k]), expected)
        detections[k] = sorted(detections[k] + found, key=lambda d: d.tag_id)
        added += [(k, d) for d in found]
    return added


def _observations(found: list[tuple[int, TagDetection]], camera_of: dict[int, Camera], scale_min_cell_px: float) -> list[Observation]:
    """(photo index, detection) pairs as observations: corners normalised, scale-free where the cells are small.

    Tags cut by the photo's edge (`partial`) are left out: a corner of theirs is extrapolated, not measured.
    """
    return [Observation(k, d.tag_id, camera_of[k].normalise(d.corners), cell_width_px(d.corners) < scale_min_cell_px)
            for k, d in found if not d.partial]


def _reference_mask(option: str | list[str], node_ids: list[str], network: Network) -> np.ndarray:
    if option == "all":
        return np.ones(len(node_ids), dtype=bool)
    if option == "supports":
        mask = np.array([network.nodes[n].kind == "support" for n in node_ids], dtype=bool)
        if mask.sum() < 3:
            raise FablineError(f"--reference supports: only {int(mask.sum())} support nodes were measured, need 3")
        return mask
    missing = [n for n in option if n not in network.nodes]
    if missing:
        raise FablineError(f"--reference: node {missing[0]} is not in the model")
    unmeasured = [n for n in option if n not in node_ids]
    if unmeasured:
        raise FablineError(f"--reference: node {unmeasured[0]} was not measured")
    return np.isin(node_ids, option)


def measure_survey(photos: list[Path], network: Network, camera: Camera | None, tag_map: TagMap,
                   out_dir: str | os.PathLike, options: MeasureOptions | None = None) -> dict:
    """Run the whole survey and write `survey.json` and the pictures into `out_dir`; return the record.

    Without a `camera` (or with `options.calibrate`) the photos calibrate their cameras themselves (see
    `fabline.survey.selfcal`); the fitted intrinsics are in the record's "cameras"."""
    options = options or MeasureOptions()
    if not (options.tolerance_mm > 0 and np.isfinite(options.tolerance_mm)):
        raise FablineError(f"--tolerance {options.tolerance_mm:g}: must be a distance in mm, more than 0")
    if options.min_views < 2:
        raise FablineError(f"--min-views {options.min_views}: a tag must be seen in at least 2 photos to be measured")
    if not (options.k_sigma >= 0 and np.isfinite(options.k_sigma)):
        raise FablineError(f"--k-sigma {options.k_sigma:g}: must be a number of standard deviations, 0 or more")
    if not options.scale_min_cell_px >= 0:
        raise FablineError(f"--scale-min-cell {options.scale_min_cell_px:g}: must be a number of px, 0 or more")
    model = network.in_mm()
    check_tag_map(tag_map, model)
    check_scale_bars(options.scale_bars, tag_map)
    detections, problems, duplicated, sizes = detect_photos(photos, camera, set(tag_map.node_of_tag))
    groups = _camera_groups(photos, sizes, detections, camera, tag_map.tag_size_mm, options, problems) \
        if camera is None or options.calibrate else None
    camera_of = {k: camera for k in sizes} if groups is None else {k: g.camera for g in groups for k in g.photos}
    pairs = [(k, d) for k, found in detections.items() for d in found]
    observations = _observations(pairs, camera_of, options.scale_min_cell_px)
    if not observations:
        detail = f" ({problems[0]['problem']}" + (f"; {len(problems) - 1} more problem(s))" if len(problems) > 1 else ")") if problems else ""
        raise FablineError(f"no tags of the tag map were found in any usable photo{detail}")
    reference_camera = camera or groups[0].camera
    reconstruction = bundle_adjust(observations, reference_camera, tag_map.tag_size_mm)
    misplaced = reconstruction.misplaced(observations, tag_map.tag_size_mm)
    if misplaced:
        for tag, (away, agreeing) in sorted(misplaced.items()):
            names = ", ".join(photos[k].name for k in away)
            others = ", ".join(photos[k].name for k in agreeing) or "none"
            problems.append({"tag": tag, "files": [str(photos[k]) for k in away + agreeing],
                             "problem": f"tag {tag}: photo(s) {names} show it away from where photo(s) {others} put it: "
                                        f"printed more than once? (left out of the survey; mount one copy only)"})
            duplicated[tag] = away + agreeing
        observations = [o for o in observations if o.tag not in misplaced]
        for k in detections:
            detections[k] = [d for d in detections[k] if d.tag_id not in misplaced]
        pairs = [(k, d) for k, d in pairs if d.tag_id not in misplaced]
        reconstruction = bundle_adjust(observations, reference_camera, tag_map.tag_size_mm)
    if groups is not None:
        for _ in range(SELF_CALIBRATION_ROUNDS):
            rejected = set(reconstruction.rejected)
            refine_cameras(groups, reconstruction, [(k, d) for k, d in pairs if (k, d.tag_id) not in rejected],
                           tag_map.tag_size_mm, not options.radial_only)
            camera_of = {k: g.camera for g in groups for k in g.photos}
            observations = _observations(pairs, camera_of, options.scale_min_cell_px)
            reconstruction = bundle_adjust(observations, groups[0].camera, tag_map.tag_size_mm)
        _check_determined(groups, problems)
        reference_camera = groups[0].camera
    predicted = find_predicted_tags(photos, camera_of, tag_map.tag_size_mm, reconstruction, detections)
    if predicted:
        observations += _observations(predicted, camera_of, options.scale_min_cell_px)
        reconstruction = bundle_adjust(observations, reference_camera, tag_map.tag_size_mm)
    scale = None
    if options.scale_bars:
        unmeasured = [t for bar in options.scale_bars for t in bar[:2] if t not in reconstruction.tag_poses]
        if unmeasured:
            raise FablineError(f"--scale-bar: tag {unmeasured[0]} was not measured (seen in no photo that joined)")
        factor, misfits = reconstruction.scale_to_bars(list(options.scale_bars))
        scale = {"source": "scale bars", "factor": round(factor, 9),
                 "bars": [{"tags": [a, b], "distance_mm": length, "misfit_mm": round(misfit, 4)}
                          for (a, b, length), misfit in zip(options.scale_bars, misfits)]}
    small = sum(o.scale_free for o in observations)
    if small and not reconstruction.scale_free_observations:
        problems.append({"problem": f"every tag seen in two or more photos has cells narrower than {options.scale_min_cell_px:g} px: "
                                    f"they set the scale anyway (expect a scale error of up to 1e-3; take closer photos or use --scale-bar)"})
    for k in reconstruction.unregistered_photos:
        problems.append({"file": str(photos[k]), "problem": f"{photos[k]}: shares too few tags with the other photos (left out)"})
    for k, tag in reconstruction.rejected:
        problems.append({"file": str(photos[k]), "tag": tag, "problem": f"{photos[k]}: tag {tag} rejected as an outlier"})
    tag_ids, points, covariances = reconstruction.points_below_tags(tag_map.mount_offset_mm)
    views = np.array([reconstruction.observation_count[t] for t in tag_ids], dtype=int)
    keep = views >= options.min_views
    tag_ids = [t for t, k in zip(tag_ids, keep) if k]
    points, covariances, views = points[keep], covariances[keep], views[keep]
    node_ids = [tag_map.node_of_tag[t] for t in tag_ids]
    if len(node_ids) < 3:
        raise FablineError(f"only {len(node_ids)} tagged node(s) were seen in {options.min_views} or more photos that join "
                           f"into one reconstruction ({len(reconstruction.unregistered_photos)} photo(s) share too few tags "
                           f"with the rest); take more photos that overlap")
    design = np.array([model.nodes[n].xyz for n in node_ids]).reshape(-1, 3)
    reference = _reference_mask(options.reference, node_ids, model)
    rotation, translation, fit_rms = register(points, design, reference)
    wrong = wrong_tags(points @ rotation.T + translation, node_ids, model, options.tolerance_mm)
    if wrong and reference[[node_ids.index(n) for n in wrong]].any():
        # a tag on the wrong node would pull the fit: fit again without it
        reference[[node_ids.index(n) for n in wrong]] = False
        rotation, translation, fit_rms = register(points, design, reference)
        wrong = wrong_tags(points @ rotation.T + translation, node_ids, model, options.tolerance_mm)
    for nid, likely in wrong.items():
        problems.append({"node": nid, "tag": tag_map.tag_of_node[nid],
                         "problem": f"node {nid}: tag {tag_map.tag_of_node[nid]} was measured at node {likely}'s design "
                                    f"position: wrong tag mounted? (node {nid} reported as not measured)"})
    measured_all = points @ rotation.T + translation
    keep = np.array([n not in wrong for n in node_ids], dtype=bool)
    tag_ids = [t for t, k in zip(tag_ids, keep) if k]
    node_ids = [n for n, k in zip(node_ids, keep) if k]
    measured, design, covariances, views = measured_all[keep], design[keep], covariances[keep], views[keep]
    deviation = measured - design
    distance = np.linalg.norm(deviation, axis=1)
    covariances = rotation @ covariances @ rotation.T
    sigma = np.sqrt(np.einsum("nii->ni", covariances))
    normals = np.array([model.nodes[n].normal for n in node_ids]).reshape(-1, 3)
    verdict, sigma_along = verdicts(deviation, covariances, options.tolerance_mm, options.k_sigma)
    record = _record(model, tag_map, options, node_ids, tag_ids, design, measured, deviation, distance, sigma, views,
                     (verdict, sigma_along, np.einsum("ni,ni->n", deviation, normals)),
                     rotation, translation, fit_rms, reconstruction, photos, detections, problems, wrong, duplicated)
    record["summary"]["tags_found_where_predicted"] = len(predicted)
    record["cameras"] = describe(groups) if groups is not None else None
    record["scale"] = scale or {"source": f"tag size {tag_map.tag_size_mm:g} mm", "factor": 1.0, "bars": []}
    record["scale"].update(min_cell_px=options.scale_min_cell_px,
                           observations_without_scale=reconstruction.scale_free_observations)
    out_dir = Path(out_dir)
    write_json(out_dir / "survey.json", record)
    if options.pictures:
        write_deviation_map(model, record, out_dir / "deviation_map.png")
        write_detection_pictures(photos, detections, out_dir / "detections")
    return record


def verdicts(deviation: np.ndarray, covariances: np.ndarray, tolerance_mm: float, k_sigma: float):
    """Per node "pass", "fail" or "uncertain" and the standard uncertainty (mm) of its distance from the design.

    That uncertainty is the deviation's along its own direction, sqrt(u^T C u) (at a deviation too small to have a
    direction, the largest along any); pass: distance + k sigma within the tolerance, fail: distance - k sigma beyond.
    """
    distance = np.linalg.norm(deviation, axis=1)
    direction = deviation / np.maximum(distance, 1e-9)[:, None]
    along = np.einsum("ni,nij,nj->n", direction, covariances, direction)
    largest = np.linalg.eigvalsh(covariances)[:, -1] if len(covariances) else np.zeros(0)
    sigma = np.sqrt(np.maximum(np.where(distance > 1e-6, along, largest), 0.0))
    verdict = np.where(distance + k_sigma * sigma <= tolerance_mm, "pass",
                       np.where(distance - k_sigma * sigma > tolerance_mm, "fail", "uncertain"))
    return verdict, sigma


def _camera_groups(photos, sizes, detections, camera, tag_size, options, problems) -> list[CameraGroup]:
    """The cameras to calibrate, each with its photos and a starting point: the camera file given, else EXIF's focal
    length or the tags' squares; photos without EXIF are noted in `problems`."""
    found, without = group_photos(photos, sizes, options.camera_map)
    if without:
        problems.append({"problem": f"{len(without)} photo(s) without EXIF ({', '.join(without[:3])}"
                                    f"{', ...' if len(without) > 3 else ''}): taken as one camera per image size, its "
                                    f"focal length estimated from the tags (give --camera-map to group them otherwise)"})
    groups = []
    for name, (indices, exif) in found.items():
        if camera is not None:
            start, source = camera, "camera file"
        else:
            views = [d.corners for k in indices for d in detections.get(k, []) if not d.partial]
            try:
                start, source = initial_camera(sizes[indices[0]], exif, views, tag_size)
            except FablineError as exc:
                raise FablineError(f"{name} ({photos[indices[0]].name}, ...): {exc}") from None
        groups.append(CameraGroup(name, indices, start, source))
    return sorted(groups, key=lambda g: -len(g.photos))


def _check_determined(groups: list[CameraGroup], problems: list[dict]) -> None:
    """Warn of a camera whose focal length the photos determine poorly; refuse one they cannot determine."""
    for group, relative in weak_cameras(groups):
        advice = ("its photos are square-on at one distance, or too few: add photos at 30-60 degrees and at other "
                  "distances, or give --camera camera.json")
        if not relative <= UNDETERMINED_FOCAL:
            raise FablineError(f"camera {group.name}: the photos cannot determine its focal length "
                               f"(uncertainty {100 * relative:.1f} %): {advice}")
        problems.append({"problem": f"camera {group.name}: focal length {group.camera.focal_px:.1f} px determined only "
                                    f"to {100 * relative:.2f} %: {advice}"})


def check_scale_bars(bars, tag_map: TagMap) -> None:
    """Raise naming the bar at fault: a tag the map lacks, a bar from a tag to itself, a length that is not positive."""
    for a, b, length in bars:
        for tag in (a, b):
            if tag not in tag_map.node_of_tag:
                raise FablineError(f"--scale-bar {a} {b} {length:g}: tag {tag} is not in the tag map")
        if a == b:
            raise FablineError(f"--scale-bar {a} {b} {length:g}: a bar needs two different tags")
        if not np.isfinite(length) or length <= 0:
            raise FablineError(f"--scale-bar {a} {b} {length:g}: the distance must be a positive number of mm")


def wrong_tags(measured: np.ndarray, node_ids: list[str], model: Network, tolerance_mm: float) -> dict[str, str]:
    """Nodes whose tag was measured out of tolerance but within tolerance of another node's design position.

    Such a tag is most likely mounted on that other node; returns node id -> the node it seems to sit on.
    """
    ids, design, _ = model.node_array()
    index = {nid: i for i, nid in enumerate(ids)}
    suspects = {}
    for nid, point in zip(node_ids, measured):
        gaps = np.linalg.norm(design - point, axis=1)
        own, nearest = gaps[index[nid]], int(np.argmin(gaps))
        if own > tolerance_mm and ids[nearest] != nid and gaps[nearest] <= min(tolerance_mm, 0.5 * own):
            suspects[nid] = ids[nearest]
    return suspects


def _record(model, tag_map, options, node_ids, tag_ids, design, measured, deviation, distance, sigma, views, judged,
            rotation, translation, fit_rms, reconstruction, photos, detections, problems, wrong, duplicated) -> dict:
    seen_once = {tag_map.node_of_tag[t] for t, n in reconstruction.observation_count.items() if n < options.min_views}
    measured_set = set(node_ids)
    not_seen = {}
    for nid in model.nodes:
        if nid in measured_set:
            continue
        tag = tag_map.tag_of_node.get(nid)
        not_seen[nid] = ("no tag" if tag is None else
                         f"tag {tag} found at more than one place: printed more than once?" if tag in duplicated else
                         f"wrong tag? tag {tag} was found at node {wrong[nid]}" if nid in wrong else
                         f"tag {tag} seen in fewer than {options.min_views} photos" if nid in seen_once else f"tag {tag} not seen")
    order = np.argsort(-distance)
    verdict, sigma_along, along_normal = judged
    regions = unseen_regions(model, list(not_seen))
    return {
        "schema": SURVEY_SCHEMA, "model": model.name, "units": "mm", "tolerance_mm": options.tolerance_mm,
        "registration": {"method": "rigid", "reference": options.reference if isinstance(options.reference, str) else list(options.reference),
                         "rms_mm": round(fit_rms, 4), "rotation": np.round(rotation, 9).tolist(),
                         "translation_mm": np.round(translation, 4).tolist()},
        "summary": {
            "nodes": len(model.nodes), "measured": len(node_ids), "passed": int(np.sum(verdict == "pass")),
            "failed": int(np.sum(verdict == "fail")), "uncertain": int(np.sum(verdict == "uncertain")),
            "k_sigma": options.k_sigma, "not_seen": len(not_seen),
            "rms_deviation_mm": round(float(np.sqrt(np.mean(distance ** 2))), 4) if len(distance) else None,
            "max_deviation_mm": round(float(distance.max()), 4) if len(distance) else None,
            "worst": [node_ids[i] for i in order[:10]],
            "reprojection_rms_px": round(reconstruction.rms_px, 4),
            "photos": len(photos), "photos_used": len(reconstruction.camera_rotations),
        },
        "nodes": {
            nid: {"tag": tag_ids[i], "design_mm": np.round(design[i], 3).tolist(), "measured_mm": np.round(measured[i], 3).tolist(),
                  "deviation_mm": np.round(deviation[i], 3).tolist(), "distance_mm": round(float(distance[i]), 3),
                  "sigma_mm": np.round(sigma[i], 3).tolist(), "distance_sigma_mm": round(float(sigma_along[i]), 3),
                  "normal_mm": round(float(along_normal[i]), 3), "views": int(views[i]), "verdict": str(verdict[i])}
            for i, nid in enumerate(node_ids)
        },
        "not_seen": not_seen,
        "not_seen_regions": regions,
        "photos": [{"file": str(p), "tags": [d.tag_id for d in detections.get(k, [])],
                    "used": k in reconstruction.camera_rotations} for k, p in enumerate(photos)],
        "problems": problems,
    }


def unseen_regions(model: Network, unseen: list[str]) -> list[dict]:
    """Where the unmeasured nodes are: the groups of them that join along lamellas (neighbours on a lamella),
    largest first, each with its nodes, the centre of their design positions and the plan radius (mm) around it."""
    if not unseen:
        return []
    index = {nid: i for i, nid in enumerate(unseen)}
    parent = list(range(len(unseen)))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for lamella in model.lamellas:
        for a, b in zip(lamella.nodes, lamella.nodes[1:]):
            if a in index and b in index:
                parent[root(index[a])] = root(index[b])
    groups: dict[int, list[str]] = {}
    for nid in unseen:
        groups.setdefault(root(index[nid]), []).append(nid)
    regions = []
    for members in sorted(groups.values(), key=lambda g: (-len(g), g[0])):
        xyz = np.array([model.nodes[n].xyz for n in members], dtype=float)
        centre = xyz.mean(axis=0)
        regions.append({"nodes": members, "centre_mm": np.round(centre, 1).tolist(),
                        "radius_mm": round(float(np.max(np.linalg.norm(xyz[:, :2] - centre[:2], axis=1))), 1)})
    return regions


def _diverging(levels: np.ndarray) -> np.ndarray:
    """BGR colours (N, 3) for levels in [-1, 1]: blue (low), through white, to red (high)."""
    low, middle, high = np.array([180.0, 70, 20]), np.array([245.0, 245, 245]), np.array([30.0, 30, 200])
    t = np.clip(levels, -1, 1)[:, None]
    return np.where(t < 0, middle + (middle - low) * t, middle + (high - middle) * t).round().astype(np.uint8)


def write_deviation_map(model: Network, record: dict, path: Path, width: int = 1600) -> None:
    """Plan view of the design: lamellas in grey, measured nodes coloured by their deviation along the node normal
    (red high, blue low, full colour at the tolerance), failing nodes ringed red and named, uncertain ones ringed
    orange, unseen nodes hollow."""
    ids, xyz, _ = model.node_array()
    low, high = xyz[:, :2].min(axis=0), xyz[:, :2].max(axis=0)
    scale = (width - 160) / max(high[0] - low[0], high[1] - low[1], 1e-9)
    height = int((high[1] - low[1]) * scale) + 160
    canvas = np.full((height, width + 240, 3), 255, dtype=np.uint8)

    def to_px(points: np.ndarray) -> np.ndarray:
        return np.column_stack([80 + (points[:, 0] - low[0]) * scale, height - 80 - (points[:, 1] - low[1]) * scale])

    for lamella in model.lamellas:
        cv2.polylines(canvas, [np.round(to_px(lamella.curve) * 16).astype(np.int32)], False, (200, 200, 200), 2, cv2.LINE_AA, shift=4)
    tolerance = record["tolerance_mm"]
    radius = max(4, int(min(12, 0.3 * scale * np.median(np.linalg.norm(np.diff(xyz, axis=0), axis=1)))))
    labels = []
    for nid, (x, y) in zip(ids, to_px(xyz)):
        centre = (int(round(x)), int(round(y)))
        node = record["nodes"].get(nid)
        if node is None:
            cv2.circle(canvas, centre, radius, (120, 120, 120), 1, cv2.LINE_AA)
            continue
        colour = _diverging(np.array([node["normal_mm"] / tolerance]))[0].tolist()
        cv2.circle(canvas, centre, radius, colour, -1, cv2.LINE_AA)
        cv2.circle(canvas, centre, radius, (90, 90, 90), 1, cv2.LINE_AA)
        if node["verdict"] == "fail":
            cv2.circle(canvas, centre, radius + 3, (0, 0, 255), 2, cv2.LINE_AA)
            labels.append((f"{nid} {node['normal_mm']:+.0f}", (centre[0] + radius + 4, centre[1] - radius)))
        elif node["verdict"] == "uncertain":
            cv2.circle(canvas, centre, radius + 3, (0, 150, 255), 2, cv2.LINE_AA)
    for text, at in labels:  # on top of every node
        cv2.putText(canvas, text, at, cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 3, cv2.LINE_AA)
        cv2.putText(canvas, text, at, cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 160), 1, cv2.LINE_AA)
    bar = _diverging(np.linspace(1, -1, height - 160))[:, None, :].repeat(30, axis=1)
    canvas[80:height - 80, width + 40:width + 70] = bar
    for label, y in ((f"+{tolerance:g} mm high", 90), ("0", height // 2 + 5), (f"-{tolerance:g} mm low", height - 75)):
        cv2.putText(canvas, label, (width + 80, y), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (0, 0, 0), 1, cv2.LINE_AA)
    summary = record["summary"]
    cv2.putText(canvas, f"{model.name}: {summary['measured']} nodes measured, RMS {mm(summary['rms_deviation_mm'])} mm, "
                        f"max {mm(summary['max_deviation_mm'])} mm; {summary['passed']} pass, {summary['failed']} fail "
                        f"(red), {summary['uncertain']} uncertain (orange), {summary['not_seen']} not seen (hollow) at "
                        f"{tolerance:g} mm, {summary['k_sigma']:g} sigma",
                (20, 40), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 1, cv2.LINE_AA)
    write_image(path, canvas)


def write_detection_pictures(photos: list[Path], detections: dict[int, list[TagDetection]], folder: Path) -> None:
    """A reduced copy of each photo with its detected tags outlined and labelled."""
    for k, found in detections.items():
        image = cv2.imread(str(photos[k]), cv2.IMREAD_COLOR)
        factor = min(1.0, PREVIEW_WIDTH / image.shape[1])
        image = cv2.resize(image, None, fx=factor, fy=factor, interpolation=cv2.INTER_AREA)
        for det in found:
            quad = (det.corners + 0.5) * factor - 0.5
            cv2.polylines(image, [np.round(quad * 16).astype(np.int32)], True, (0, 220, 0), 2, cv2.LINE_AA, shift=4)
            cv2.circle(image, tuple(np.round(quad[0]).astype(int)), 3, (0, 0, 255), -1)
            cv2.putText(image, str(det.tag_id), tuple(np.round(quad.mean(axis=0)).astype(int)), cv2.FONT_HERSHEY_SIMPLEX,
                        0.5, (255, 0, 0), 1, cv2.LINE_AA)
        write_image(folder / f"{photos[k].stem}.jpg", image)
