"""Self-calibration: the survey's photos fix cameras unknown to fabline (drawn at random by the simulator)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fabline.errors import FablineError
from fabline.jobs.survey_stage import compare_with_truth
from fabline.survey import (MeasureOptions, SyntheticSpec, list_photos, load_camera, load_tag_map, measure_survey,
                            saddle_network, simulate_survey, tag_object_points)
from fabline.survey.camera import Camera
from fabline.survey.detect import TagDetection
from fabline.survey.reconstruct import Reconstruction, rotation_matrices
from fabline.survey.selfcal import CameraGroup, exif_camera, refine_cameras, weak_cameras


@pytest.fixture(scope="module")
def network():
    return saddle_network(3.0, 0.5, 4.0)


@pytest.fixture(scope="module")
def unknown_cameras(tmp_path_factory, network):
    """Two photo sets, each from a camera drawn at random (focal length, principal point, k1, k2, p1, p2, k3): the
    first with EXIF (model, 35 mm-equivalent focal length in whole mm), the second without; each measured without a
    camera file."""
    sets = []
    for seed, model in ((21, "Pixel 7"), (22, None)):
        out = tmp_path_factory.mktemp(f"unknown-{seed}")
        spec = SyntheticSpec(photos=10, width=1600, height=1200, coverage=0.7, sag_mm=25.0, seed=seed, random_camera=True,
                             exif_model=model)
        truth = simulate_survey(network, out, spec)
        record = measure_survey(list_photos(out / "photos"), network, None, load_tag_map(out / "tagmap.json"), out / "survey",
                                MeasureOptions(reference="all", pictures=False))
        sets.append((out, truth, record))
    return sets


def test_unknown_cameras_are_calibrated_by_the_survey_photos(unknown_cameras, network):
    """Focal length within 0.5 % (its reported uncertainty of the size of the error), principal point within a few px,
    and the deviations measured to under a millimetre RMS, as with the camera known."""
    for out, truth, record in unknown_cameras:
        camera = load_camera(out / "camera.json")  # the truth, which the survey did not see
        [fitted] = record["cameras"]
        assert fitted["photos"] == 10
        assert abs(fitted["f_px"] / camera.focal_px - 1) < 0.005
        assert 0 < fitted["sigma"]["f"] < 0.005 * camera.focal_px
        assert abs(fitted["f_px"] - camera.focal_px) < 6 * fitted["sigma"]["f"] + 0.5
        assert np.hypot(fitted["cx"] - camera.matrix[0, 2], fitted["cy"] - camera.matrix[1, 2]) < 5
        assert compare_with_truth(record, truth, network)["rms_error_mm"] < 1.0
        assert json.loads((out / "survey" / "survey.json").read_text())["cameras"] == record["cameras"]


def test_exif_starts_the_focal_length_and_photos_without_it_are_named(unknown_cameras):
    with_exif, without_exif = unknown_cameras[0][2], unknown_cameras[1][2]
    assert exif_camera(unknown_cameras[0][0] / "photos" / "photo-000.jpg")["model"] == "Pixel 7"
    assert exif_camera(unknown_cameras[1][0] / "photos" / "photo-000.jpg") == {}
    assert with_exif["cameras"][0]["name"] == "fabline Pixel 7 1600x1200"
    assert with_exif["cameras"][0]["initial"].startswith("EXIF focal length ")
    assert not any("without EXIF" in p["problem"] for p in with_exif["problems"])
    assert without_exif["cameras"][0]["initial"].startswith("tag squares (")
    assert any(p["problem"].startswith("10 photo(s) without EXIF (photo-000.jpg, photo-001.jpg, photo-002.jpg, ...)")
               for p in without_exif["problems"])


def test_a_camera_map_makes_two_cameras_of_one_set(unknown_cameras, network, tmp_path):
    """Photos mapped to two cameras (as two phones would be) each get their own fit; here both are the same camera."""
    out, truth, _ = unknown_cameras[1]
    names = [p.name for p in list_photos(out / "photos")]
    mapping = {name: "phone-a" if k % 2 else "phone-b" for k, name in enumerate(names)}
    record = measure_survey(list_photos(out / "photos"), network, None, load_tag_map(out / "tagmap.json"), tmp_path,
                            MeasureOptions(reference="all", pictures=False, camera_map=mapping))
    camera = load_camera(out / "camera.json")
    assert sorted(c["name"] for c in record["cameras"]) == ["phone-a 1600x1200", "phone-b 1600x1200"]
    assert all(abs(c["f_px"] / camera.focal_px - 1) < 0.01 for c in record["cameras"])
    assert compare_with_truth(record, truth, network)["rms_error_mm"] < 1.0


def test_photos_all_square_on_at_one_distance_cannot_fix_the_focal_length():
    """A flat field of tags photographed straight down from one height: focal length and distance trade off, so the
    fit reports the focal length as undetermined (and the survey stops naming the camera and what to do)."""
    from fabline.survey.measure import _check_determined

    rng = np.random.default_rng(0)
    camera = Camera(np.array([[1200.0, 0, 799.5], [0, 1200.0, 599.5], [0, 0, 1]]), np.array([-0.05, 0.01, 0, 0, 0]), 1600, 1200)
    grid = np.array([[x, y, 0.0] for x in range(-1200, 1201, 600) for y in range(-800, 801, 800)])
    down = np.diag([1.0, -1.0, -1.0])  # camera looking down (-z), tags facing up: their z into the face is down
    model = tag_object_points(65.0)
    shifts = [np.array([dx, dy, 3000.0]) for dx in (-400, 400) for dy in (-300, 300)]
    cameras = {k: (down, -down @ position) for k, position in enumerate(shifts)}
    found = []
    for k, (rotation, translation) in cameras.items():
        for t, centre in enumerate(grid):
            corners = camera.project((centre + model @ down.T) @ rotation.T + translation)
            if np.all((corners > 0) & (corners < [1600, 1200])):
                found.append((k, TagDetection(t, corners + rng.normal(0, 0.1, corners.shape))))
    # the survey frame is the first photo's
    r0, t0 = cameras[0]
    reconstruction = Reconstruction(
        camera_rotations={k: r @ r0.T for k, (r, _) in cameras.items()},
        camera_translations={k: tr - r @ r0.T @ t0 for k, (r, tr) in cameras.items()},
        tag_poses={t: np.concatenate([cv2_rvec(r0 @ down), r0 @ c + t0]) for t, c in enumerate(grid)},
        tag_covariances={}, observation_count={}, rms_px=0.0)
    start = Camera(camera.matrix * [[1.05], [1.05], [1]], np.zeros(5), 1600, 1200)
    groups = [CameraGroup("phone", list(cameras), start, "guess")]
    refine_cameras(groups, reconstruction, found, 65.0)
    [(group, relative)] = weak_cameras(groups)
    assert relative > 0.05
    with pytest.raises(FablineError, match=r"camera phone: the photos cannot determine its focal length .*add photos at "
                                           r"30-60 degrees and at other distances, or give --camera camera.json"):
        _check_determined(groups, [])


def cv2_rvec(rotation):
    import cv2
    return cv2.Rodrigues(rotation)[0].ravel()


def test_measure_without_a_camera_file_prints_the_fitted_camera(cli, unknown_cameras, network, tmp_path):
    from fabline.model import save_network

    out = unknown_cameras[0][0]
    save_network(network, tmp_path / "model.json")
    code, text, err = cli("survey", "measure", out / "photos", "--model", tmp_path / "model.json", "--tags",
                          out / "tagmap.json", "-o", tmp_path / "survey")
    assert code == 0, err
    assert "camera fabline Pixel 7 1600x1200 (10 photos, from EXIF focal length" in text and " +/- " in text
    (tmp_path / "map.json").write_text("[1, 2]")
    code, text, err = cli("survey", "measure", out / "photos", "--model", tmp_path / "model.json", "--camera-map",
                          tmp_path / "map.json", "-o", tmp_path / "other")
    assert code == 2 and "map.json: a camera map is a JSON object of photo file names to camera names" in err
    assert err.count("\n") == 1 and not (tmp_path / "other").exists()
