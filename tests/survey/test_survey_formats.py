"""Survey file formats: camera.json, the tag map and the printable tag sheets."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET

import cv2
import numpy as np
import pytest

from fabline.errors import FablineError
from fabline.survey import (Camera, camera_from_dict, camera_to_dict, check_tag_map, load_camera, make_tag_map,
                            saddle_network, save_camera, tag_image, tagmap_from_dict, tagmap_to_dict, write_tag_sheets)


def test_camera_round_trip_and_projection(tmp_path):
    camera = Camera(np.array([[1400.0, 0, 801], [0, 1401, 598], [0, 0, 1]]), np.array([-0.1, 0.05, 1e-3, -1e-3, 0.0]), 1600, 1200)
    save_camera(camera, tmp_path / "camera.json")
    back = load_camera(tmp_path / "camera.json")
    assert np.allclose(back.matrix, camera.matrix) and np.allclose(back.distortion, camera.distortion)
    points = np.random.default_rng(0).uniform([-1, -1, 2], [1, 1, 4], size=(50, 3))
    assert np.allclose(back.normalise(back.project(points)), points[:, :2] / points[:, 2:], atol=1e-9)


@pytest.mark.parametrize("field, value, message", [
    ("fx", -3, "'fx' must be a positive number"),
    ("width", 1600.5, "'width' must be a whole number"),
    ("distortion", [0.1, "a"], "'distortion' must be a list"),
    ("schema", "other", "not a fabline.camera/1 file"),
])
def test_camera_bad_fields_are_named(field, value, message):
    camera = Camera(np.eye(3) * [1000, 1000, 1] + [[0, 0, 500], [0, 0, 400], [0, 0, 0]], np.zeros(5), 1000, 800)
    data = camera_to_dict(camera)
    data[field] = value
    with pytest.raises(FablineError, match=message):
        camera_from_dict(data, "cam.json")


def test_camera_rejects_image_of_another_resolution():
    camera = Camera(np.eye(3), np.zeros(5), 1600, 1200)
    with pytest.raises(FablineError, match=r"photo.jpg: image is 800 x 600 px but the camera file is for 1600 x 1200 px"):
        camera.check_image((600, 800), "photo.jpg")


def test_tag_map_round_trip_and_errors():
    network = saddle_network(2.0, 0.5, 3.0)
    tag_map = make_tag_map(network, 65.0, 20.0)
    assert len(tag_map.node_of_tag) == len(network.nodes)
    data = tagmap_to_dict(tag_map)
    assert tagmap_from_dict(json.loads(json.dumps(data))).node_of_tag == tag_map.node_of_tag
    twice = json.loads(json.dumps(data))
    twice["tags"].append({"tag": 0, "node": "n01-01"})
    with pytest.raises(FablineError, match=r"map.json: tag 0 is given to two nodes, n00-00 and n01-01"):
        tagmap_from_dict(twice, "map.json")
    outside = json.loads(json.dumps(data))
    outside["tags"][0]["tag"] = 600
    with pytest.raises(FablineError, match=r"tag id 600 is outside tag36h11"):
        tagmap_from_dict(outside, "map.json")
    stray = json.loads(json.dumps(data))
    stray["tags"].append({"tag": 500, "node": "nowhere"})
    with pytest.raises(FablineError, match=r"tag 500 is mapped to node nowhere, which the model does not define"):
        check_tag_map(tagmap_from_dict(stray), network)


def test_too_many_nodes_for_the_family_is_an_error():
    network = saddle_network(9.0, 0.35, 8.0)  # 27 x 27 = 729 nodes > 587 ids
    with pytest.raises(FablineError, match=r"729 nodes to tag but tag36h11 has only 587 ids"):
        make_tag_map(network)
    sparse = make_tag_map(network, every=2)
    assert len(sparse.node_of_tag) <= 587
    assert all(n in sparse.node_of_tag.values() for n, node in network.nodes.items() if node.kind == "support")


def test_tag_images_decode_to_their_ids():
    """The tag artwork, checked with OpenCV's own aruco decoder (not our refinement)."""
    detector = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11))
    for tag_id in (0, 17, 586):
        canvas = np.pad(tag_image(tag_id, 10), 30, constant_values=255)
        _, ids, _ = detector.detectMarkers(canvas)
        assert ids is not None and ids.ravel().tolist() == [tag_id]


def test_tag_sheets_are_true_size_svg_and_pdf(tmp_path):
    network = saddle_network(1.0, 0.5, 3.0)
    tag_map = make_tag_map(network, 50.0, 15.0)
    written = write_tag_sheets(tag_map, tmp_path)
    svgs = [p for p in written if p.suffix == ".svg"]
    root = ET.parse(svgs[0]).getroot()
    assert root.get("width") == "210.0mm" and root.get("viewBox") == "0 0 210.0 297.0"
    texts = [t.text for t in root.iter("{http://www.w3.org/2000/svg}text")]
    assert texts[0] == "node n00-00 · tag 0"
    # the black rectangles of the first tag span exactly the 50 mm black square
    group = next(root.iter("{http://www.w3.org/2000/svg}g"))
    rects = [r for r in group.iter("{http://www.w3.org/2000/svg}rect") if r.get("fill") is None]
    xs = [float(r.get("x")) for r in rects] + [float(r.get("x")) + float(r.get("width")) for r in rects]
    assert max(xs) - min(xs) == pytest.approx(50.0)
    pdf = (tmp_path / "tags.pdf").read_bytes()
    assert pdf.startswith(b"%PDF-1.4") and pdf.rstrip().endswith(b"%%EOF")
    assert pdf.count(b"/Type /Page ") == len(svgs)
    assert json.loads((tmp_path / "tagmap.json").read_text())["tag_size_mm"] == 50.0
