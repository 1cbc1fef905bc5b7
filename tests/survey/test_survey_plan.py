"""`fabline survey plan`: the ray tests against hand-made geometry, the plan's claims against OpenCV's projection, and a
planned survey in simulation: every node in two photos by the simulator's own visibility, then measured."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from collections import Counter

import cv2
import numpy as np
import pytest

from fabline.model import save_network
from fabline.survey import make_tag_map, saddle_network
from fabline.survey.camera import Camera
from fabline.survey.plan import PlanOptions, blocked, blocked_by_discs, plan_survey
from fabline.survey.simulate import tag_centres


def test_segments_cross_a_triangle_only_between_their_ends():
    triangle = np.array([[[0.0, 0, 0], [2, 0, 0], [0, 2, 0]]])
    origins = np.array([[0.5, 0.5, -1], [0.5, 0.5, -1], [1.5, 1.5, -1], [0.5, 0.5, 1], [0.5, 0.5, -1]])
    targets = np.array([[0.5, 0.5, 1], [0.5, 0.5, -0.1], [1.5, 1.5, 1], [0.6, 0.6, 3], [2.5, 2.5, 1]])
    # through the middle; stops short; outside the hypotenuse (x + y = 3 > 2); above it; crosses z = 0 at (1.5, 1.5)
    assert blocked(origins, targets, triangle).tolist() == [True, False, False, False, False]


def test_segments_cross_other_discs_not_their_own():
    centres = np.array([[0.0, 0, 0], [0, 0, 5]])
    normals = np.array([[0.0, 0, 1], [0, 0, 1]])
    origins = np.array([[0.0, 0, 0], [0.0, 0, 0], [0.3, 0, 0]])
    targets = np.array([[0.0, 0, 10], [0.0, 0, 4], [3.3, 0, 10]])
    # through disc 1 at its centre; ends before it; crosses z = 5 at x = 1.8, outside radius 1
    assert blocked_by_discs(origins, targets, np.array([0, 0, 0]), centres, normals, 1.0).tolist() == [True, False, False]


@pytest.fixture(scope="module")
def saddle():
    return saddle_network(4.0, 0.5, 4.0)


CAMERA = Camera(np.array([[1300.0, 0, 799.5], [0, 1300.0, 599.5], [0, 0, 1]]), np.zeros(5), 1600, 1200)


def test_every_claimed_view_holds_by_opencv_projection(saddle):
    """Each station's tags are in its frame (cv2.projectPoints of the tag's corners), turned to it within the limit
    and large enough by the foreshortened side; every tag is claimed by two stations at different positions."""
    tag_map = make_tag_map(saddle)
    options = PlanOptions(height_mm=3000.0, max_angle_deg=60.0, min_side_px=16.0)
    plan = plan_survey(saddle, tag_map, CAMERA, options)
    nodes, centres, normals = tag_centres(saddle.in_mm(), tag_map)
    assert not plan.short and all(len(set(stations)) >= 2 for stations in plan.seen_by.values())
    for station in plan.stations:
        rvec, _ = cv2.Rodrigues(station.rotation)
        tvec = -station.rotation @ station.position_mm
        for nid in station.nodes:
            i = nodes.index(nid)
            ray = station.position_mm - centres[i]
            assert np.degrees(np.arccos(ray @ normals[i] / np.linalg.norm(ray))) <= 60.0 + 1e-9
            helper = np.cross(normals[i], [1.0, 0, 0])
            helper /= np.linalg.norm(helper)
            other = np.cross(normals[i], helper)
            corners = centres[i] + 32.5 * np.array([helper + other, helper - other, -helper - other, -helper + other])
            pixels, _ = cv2.projectPoints(corners, rvec, tvec, CAMERA.matrix, CAMERA.distortion)
            pixels = pixels.reshape(-1, 2)
            assert np.all(pixels >= 0) and np.all(pixels < [1600, 1200]), (nid, pixels)
            cos = ray @ normals[i] / np.linalg.norm(ray)
            assert 1300.0 * 65.0 * cos / np.linalg.norm(ray) >= 16.0
    positions = {number: tuple(s.position_mm) for number, s in enumerate(plan.stations, 1)}
    assert all(len({positions[n] for n in stations}) >= 2 for stations in plan.seen_by.values())


def test_a_low_station_leaves_tags_short_and_says_from_how_many(saddle):
    """Tags face up: from 0.3 m over the lowest node some turn away or hide behind the shell; the plan names them with
    the number of stations that see them (fewer than two), and their stations are no more than that."""
    tag_map = make_tag_map(saddle)
    plan = plan_survey(saddle, tag_map, CAMERA, PlanOptions(height_mm=300.0, max_angle_deg=75.0))
    assert plan.short and all(count < 2 for count in plan.short.values())
    assert all(len(plan.seen_by[nid]) <= count for nid, count in plan.short.items())
    assert all(len(stations) >= 2 for nid, stations in plan.seen_by.items() if nid not in plan.short)


def test_no_station_seeing_any_tag_is_an_error(saddle):
    from fabline.errors import FablineError

    with pytest.raises(FablineError, match="no station at 0.3 m sees any tag"):
        plan_survey(saddle, make_tag_map(saddle), CAMERA, PlanOptions(height_mm=300.0, max_angle_deg=40.0))


@pytest.fixture(scope="module")
def planned(tmp_path_factory, saddle):
    """`survey plan` then `survey simulate --plan` through the CLI, at 1600 x 1200 px."""
    from fabline.cli import main

    folder = tmp_path_factory.mktemp("planned")
    model = folder / "saddle.network.json"
    save_network(saddle, model)
    assert main(["survey", "plan", "--model", str(model), "--sensor", "36x27mm", "--focal-length", "29.25mm",
                 "--resolution", "1600x1200", "--height", "3 m", "-o", str(folder / "plan")]) == 0
    assert main(["survey", "simulate", "--model", str(model), "--plan", str(folder / "plan" / "plan.json"),
                 "-o", str(folder / "sim")]) == 0
    return folder


def test_a_planned_survey_sees_every_node_twice_in_simulation(planned):
    """By the simulator's own test (tag in full view, 16 px or more, within 70 degrees, not covered by another tag)."""
    plan = json.loads((planned / "plan" / "plan.json").read_text())
    truth = json.loads((planned / "sim" / "truth.json").read_text())
    assert len(truth["photos"]) == len(plan["stations"])
    views = Counter(int(tag) for photo in truth["photos"] for tag in photo["visible"])
    tags = [node["tag"] for node in truth["nodes"].values()]
    assert min(views[t] for t in tags) >= 2, sorted((views[t], t) for t in tags)[:5]
    first = truth["photos"][0]
    assert first["rotation"] == plan["stations"][0]["rotation"]


def test_a_planned_survey_measures_every_node(planned, cli):
    code, out, err = cli("survey", "measure", planned / "sim" / "photos", "--model", planned / "saddle.network.json",
                         "--camera", planned / "sim" / "camera.json", "--tags", planned / "sim" / "tagmap.json",
                         "-o", planned / "survey")
    assert code == 0, err
    record = json.loads((planned / "survey" / "survey.json").read_text())
    assert record["summary"]["not_seen"] == 0 and record["not_seen_regions"] == []
    assert "not seen: every one of the 81 nodes seen" in out


def test_plan_prints_draws_and_lists_unseen_nodes_after_a_survey(planned, cli, tmp_path):
    plan = json.loads((planned / "plan" / "plan.json").read_text())
    svg = ET.parse(planned / "plan" / "plan.svg").getroot()
    labels = [t.text for t in svg.iter("{http://www.w3.org/2000/svg}text")]
    assert [str(n) for n in range(1, len(plan["stations"]) + 1)] == labels[1:]
    node = next(iter(plan["seen_by"]))
    survey = {"schema": "fabline.survey/1", "not_seen": {node: "tag 0 not seen"}}
    (tmp_path / "survey.json").write_text(json.dumps(survey))
    code, out, err = cli("survey", "plan", "--model", planned / "saddle.network.json", "--sensor", "36x27mm",
                         "--focal-length", "29.25mm", "--resolution", "1600x1200", "--height", "3 m",
                         "-o", tmp_path / "again", "--survey", tmp_path / "survey.json")
    assert code == 0, err
    stations = ", ".join(map(str, plan["seen_by"][node]))
    assert f"{node} (tag 0 not seen): seen from stations {stations}" in out
    assert json.loads((tmp_path / "again" / "plan.json").read_text())["stations"] == plan["stations"]


@pytest.mark.parametrize("args, words", [
    ((), "plan needs the camera one way"),
    (("--sensor", "36x24mm"), "go together"),
    (("--camera", "c.json", "--sensor", "36x24mm"), "plan needs the camera one way"),
    (("--sensor", "36x24mm", "--focal-length", "24mm", "--resolution", "6000x4000", "--max-angle", "95"), "--max-angle"),
])
def test_plan_mistakes_are_one_line(cli, planned, args, words, tmp_path):
    code, out, err = cli("survey", "plan", "--model", planned / "saddle.network.json", "-o", tmp_path / "p", *args)
    assert code == 2 and words in err and len(err.strip().splitlines()) == 1, err


def test_height_takes_units(cli, planned, tmp_path):
    code, out, err = cli("survey", "plan", "--model", planned / "saddle.network.json", "--sensor", "36x27mm",
                         "--focal-length", "29.25mm", "--resolution", "1600x1200", "--height", "300cm",
                         "-o", tmp_path / "p")
    assert code == 0 and json.loads((tmp_path / "p" / "plan.json").read_text())["height_mm"] == 3000.0


def test_a_test_photo_gives_the_camera_by_its_exif(cli, planned, tmp_path):
    """A photo written with EXIF (35 mm-equivalent focal length in whole mm, as phones write it): the plan's camera
    has its size and that focal length (1300 px -> 28.1, written 28 mm equivalent -> 1294.3 px at 1600 x 1200)."""
    from fabline.survey import SyntheticSpec, simulate_survey

    simulate_survey(saddle_network(2.0, 0.5, 3.0), tmp_path / "exif",
                    SyntheticSpec(photos=2, width=1600, height=1200, focal_px=1300, exif_model="Phone X"))
    code, out, err = cli("survey", "plan", "--model", planned / "saddle.network.json", "--photo",
                         tmp_path / "exif" / "photos" / "photo-000.jpg", "--height", "3 m", "-o", tmp_path / "p")
    assert code == 0, err
    camera = json.loads((tmp_path / "p" / "plan.json").read_text())["camera"]
    assert (camera["width"], camera["height"]) == (1600, 1200)
    assert abs(camera["fx"] - 28 * np.hypot(1600, 1200) / np.hypot(36, 24)) < 1e-6
