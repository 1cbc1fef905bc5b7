"""The whole survey on a rendered photo set with known truth, plus every bad input the issue lists."""

from __future__ import annotations

import json
import shutil

import cv2
import numpy as np
import pytest

from fabline.errors import FablineError
from fabline.survey import (MeasureOptions, SyntheticSpec, detect_tags, list_photos, load_camera, load_tag_map, make_tag_map,
                            measure_survey, read_gray, saddle_network, simulate_survey, tag_image, tagmap_from_dict, tagmap_to_dict)


@pytest.fixture(scope="module")
def network():
    return saddle_network(3.0, 0.5, 4.0)


@pytest.fixture(scope="module")
def photo_set(tmp_path_factory, network):
    out = tmp_path_factory.mktemp("measure-set")
    spec = SyntheticSpec(photos=10, width=1600, height=1200, focal_px=1300, coverage=0.7, sag_mm=25.0, seed=3)
    truth = simulate_survey(network, out, spec)
    return out, truth


@pytest.fixture(scope="module")
def survey(tmp_path_factory, network, photo_set):
    """The set with four bad photos added: unreadable, no tags, another resolution, a tag of no node."""
    out, truth = photo_set
    photos = tmp_path_factory.mktemp("photos-with-bad-ones")
    for path in list_photos(out / "photos"):
        shutil.copy(path, photos / path.name)
    (photos / "x-broken.jpg").write_bytes(b"\xff\xd8 truncated jpeg")
    cv2.imwrite(str(photos / "x-blank.png"), np.full((1200, 1600), 140, np.uint8))
    small = cv2.imread(str(photos / "photo-000.jpg"), cv2.IMREAD_GRAYSCALE)
    cv2.imwrite(str(photos / "x-small.jpg"), cv2.resize(small, (800, 600)))
    stray = np.full((1200, 1600), 120, np.uint8)
    stray[500:600, 700:800] = tag_image(500, 10)
    cv2.imwrite(str(photos / "x-stray.png"), stray)
    result = tmp_path_factory.mktemp("survey")
    record = measure_survey(list_photos(photos), network, load_camera(out / "camera.json"), load_tag_map(out / "tagmap.json"),
                            result, MeasureOptions(tolerance_mm=20.0, reference="supports"))
    return record, result


def test_recovers_injected_deviations_to_a_fraction_of_a_millimetre(survey, photo_set):
    record, _ = survey
    _, truth = photo_set
    ids = list(record["nodes"])
    assert len(ids) >= 0.9 * len(truth["nodes"])
    recovered = np.array([record["nodes"][n]["deviation_mm"] for n in ids])
    injected = np.array([truth["nodes"][n]["deviation_mm"] for n in ids])
    error = np.linalg.norm(recovered - injected, axis=1)
    assert np.sqrt(np.mean(error ** 2)) < 0.5
    assert np.abs(injected[:, 2]).max() > 20  # the sag is really there and really measured
    # the reported uncertainty is honest: errors are of its size, not far beyond it
    sigma = np.array([record["nodes"][n]["sigma_mm"] for n in ids])
    assert np.all(sigma > 0)
    assert np.mean(np.abs(recovered - injected) <= 3 * sigma + 0.02) > 0.95


def test_per_node_record_and_summary_are_consistent(survey, photo_set):
    record, result = survey
    _, truth = photo_set
    assert json.loads((result / "survey.json").read_text()) == record
    assert record["schema"] == "fabline.survey/1"
    for nid, node in record["nodes"].items():
        deviation = np.subtract(node["measured_mm"], node["design_mm"])
        assert np.allclose(deviation, node["deviation_mm"], atol=2e-3)
        assert node["distance_mm"] == pytest.approx(np.linalg.norm(node["deviation_mm"]), abs=2e-3)
        margin = 2.0 * node["distance_sigma_mm"]
        assert node["verdict"] == ("pass" if node["distance_mm"] + margin <= 20.0 else
                                   "fail" if node["distance_mm"] - margin > 20.0 else "uncertain")
        assert np.linalg.norm(node["sigma_mm"]) + 1e-3 >= node["distance_sigma_mm"] >= 0  # at most the trace's root
        assert node["normal_mm"] < 0 or node["distance_mm"] < 3  # the sag: low along the upward normal
        assert node["design_mm"] == pytest.approx(truth["nodes"][nid]["design_mm"], abs=1e-3)
        assert node["views"] >= 2
    summary = record["summary"]
    distances = np.array([n["distance_mm"] for n in record["nodes"].values()])
    assert summary["measured"] == len(distances)
    verdicts = [n["verdict"] for n in record["nodes"].values()]
    assert summary["failed"] == verdicts.count("fail") > 0 and summary["uncertain"] == verdicts.count("uncertain")
    assert summary["passed"] + summary["failed"] + summary["uncertain"] == summary["measured"] and summary["k_sigma"] == 2
    assert summary["max_deviation_mm"] == pytest.approx(distances.max(), abs=1e-3)
    assert summary["rms_deviation_mm"] == pytest.approx(np.sqrt(np.mean(distances ** 2)), abs=1e-3)
    assert record["nodes"][summary["worst"][0]]["distance_mm"] == pytest.approx(distances.max(), abs=1e-3)
    assert summary["nodes"] == summary["measured"] + summary["not_seen"] == len(truth["nodes"])
    assert set(record["not_seen"]) == set(truth["nodes"]) - set(record["nodes"])
    assert (result / "deviation_map.png").stat().st_size > 10_000
    assert len(list((result / "detections").glob("*.jpg"))) == 10 + 2  # the ten photos, the blank and the stray one


def test_bad_photos_are_reported_by_file_and_id_and_the_rest_runs(survey):
    record, _ = survey
    problems = [p["problem"] for p in record["problems"]]
    assert any("x-broken.jpg: cannot read the image" in p for p in problems)
    assert any("x-blank.png: no tags found in this photo" in p for p in problems)
    assert any("x-small.jpg: image is 800 x 600 px but the camera file is for 1600 x 1200 px" in p for p in problems)
    assert any("x-stray.png: tag 500 maps to no node of the model" in p for p in problems)
    used = {p["file"].rsplit("/", 1)[-1]: p["used"] for p in record["photos"]}
    assert sum(used.values()) == 10 and not used["x-stray.png"]


def test_a_tag_on_the_wrong_node_is_named(tmp_path, network, photo_set):
    """Swap two nodes' tags in the map (= tags mounted the wrong way round): both nodes are flagged."""
    out, _ = photo_set
    data = tagmap_to_dict(load_tag_map(out / "tagmap.json"))
    entries = {e["node"]: e for e in data["tags"]}
    entries["n02-02"]["node"], entries["n02-03"]["node"] = "n02-03", "n02-02"
    record = measure_survey(list_photos(out / "photos"), network, load_camera(out / "camera.json"), tagmap_from_dict(data),
                            tmp_path, MeasureOptions(reference="all", pictures=False))
    flagged = {p["node"]: p["problem"] for p in record["problems"] if "node" in p}
    assert set(flagged) == {"n02-02", "n02-03"}
    assert "node n02-02: tag" in flagged["n02-02"] and "node n02-03's design position" in flagged["n02-02"]
    assert "wrong tag" in record["not_seen"]["n02-03"]
    assert record["summary"]["failed"] == 0 or record["summary"]["max_deviation_mm"] < 30


def test_reference_nodes_by_id_and_their_errors(tmp_path, network, photo_set, survey):
    """Naming the measured supports by id gives the same registration as `supports`; a bad id is named."""
    out, _ = photo_set
    photos, camera, tag_map = list_photos(out / "photos"), load_camera(out / "camera.json"), load_tag_map(out / "tagmap.json")
    with pytest.raises(FablineError, match=r"--reference: node nowhere is not in the model"):
        measure_survey(photos, network, camera, tag_map, tmp_path / "a", MeasureOptions(reference=["n00-00", "nowhere"]))
    assert not (tmp_path / "a").exists()
    by_supports, _ = survey
    supports = [n for n in by_supports["nodes"] if network.nodes[n].kind == "support"]
    assert len(supports) >= 3
    record = measure_survey(photos, network, camera, tag_map, tmp_path / "b", MeasureOptions(reference=supports, pictures=False))
    assert record["registration"]["reference"] == supports
    for nid, node in record["nodes"].items():
        assert node["deviation_mm"] == pytest.approx(by_supports["nodes"][nid]["deviation_mm"], abs=0.05)


def test_camera_for_another_resolution_stops_with_the_reason(tmp_path, network, photo_set):
    out, _ = photo_set
    camera = load_camera(out / "camera.json")
    camera.width, camera.height = 3200, 2400
    with pytest.raises(FablineError, match=r"no tags of the tag map were found in any usable photo "
                                           r"\(.*photo-000.jpg: image is 1600 x 1200 px but the camera file is for 3200 x 2400 px; 9 more"):
        measure_survey(list_photos(out / "photos"), network, camera, load_tag_map(out / "tagmap.json"), tmp_path / "s")
    assert not (tmp_path / "s" / "survey.json").exists()


def test_tag_map_naming_a_node_the_model_lacks(tmp_path, network, photo_set):
    out, _ = photo_set
    data = tagmap_to_dict(load_tag_map(out / "tagmap.json"))
    data["tags"][3]["node"] = "ghost"
    with pytest.raises(FablineError, match=r"tag 3 is mapped to node ghost, which the model does not define"):
        measure_survey(list_photos(out / "photos"), network, load_camera(out / "camera.json"), tagmap_from_dict(data), tmp_path)
    assert not (tmp_path / "survey.json").exists()


def test_photos_that_do_not_overlap_are_reported(tmp_path, network, photo_set):
    """Two photos that share no tag cannot both join; with too few nodes left the error says why."""
    out, truth = photo_set
    visible = [set(p["visible"]) for p in truth["photos"]]
    pair = next((a, b) for a in range(len(visible)) for b in range(a + 1, len(visible))
                if visible[a] and visible[b] and not visible[a] & visible[b])
    photos = [out / truth["photos"][k]["file"] for k in pair]
    with pytest.raises(FablineError, match=r"only \d tagged node\(s\) were seen in 2 or more photos .* share too few tags"):
        measure_survey(photos, network, load_camera(out / "camera.json"), load_tag_map(out / "tagmap.json"), tmp_path)


def test_a_tag_the_photo_alone_does_not_yield_is_found_where_the_other_photos_put_it(tmp_path, network, photo_set):
    """A thin dark strap across one corner of a tag in one photo: its black square no longer has a four-cornered
    outline, so detection alone misses it; the survey, having placed that tag from the other photos, looks for it
    where it must be and finds it (its edges and cells still read), and nothing that is not there."""
    out, truth = photo_set
    photos = tmp_path / "photos"
    shutil.copytree(out / "photos", photos)
    gray = read_gray(photos / "photo-005.jpg")
    corners = np.array(truth["photos"][5]["visible"][19])
    outward = (corners[0] - corners.mean(axis=0)) / np.linalg.norm(corners[0] - corners.mean(axis=0))
    cell = np.linalg.norm(corners[1] - corners[0]) / 8
    across = 3 * cell * np.array([-outward[1], outward[0]])
    ends = [tuple(np.round((corners[0] + sign * across) * 16).astype(int)) for sign in (1, -1)]
    cv2.line(gray, ends[0], ends[1], 40, max(1, int(0.5 * cell)), cv2.LINE_AA, 4)
    (photos / "photo-005.jpg").unlink()
    cv2.imwrite(str(photos / "photo-005.png"), gray)
    visible = set(map(int, truth["photos"][5]["visible"]))
    assert 19 in visible and 19 not in {d.tag_id for d in detect_tags(gray)}  # the kind of miss this is about
    record = measure_survey(list_photos(photos), network, load_camera(out / "camera.json"), load_tag_map(out / "tagmap.json"),
                            tmp_path / "survey", MeasureOptions(reference="supports", pictures=False))
    assert record["summary"]["tags_found_where_predicted"] >= 1
    for found, rendered in zip(record["photos"], truth["photos"]):
        assert set(found["tags"]) <= set(rendered["rendered"])
        assert set(map(int, rendered["visible"])) <= set(found["tags"]), f"missed in {found['file']}"


def test_tags_cut_by_the_photo_edge_stay_out_of_the_adjustment(photo_set):
    """A partial detection (a corner extrapolated past the photo's edge) gives no observation; a whole one does."""
    from fabline.survey.detect import TagDetection
    from fabline.survey.measure import _observations

    out, _ = photo_set
    camera = load_camera(out / "camera.json")
    square = np.array([[10.0, 10.0], [60.0, 10.0], [60.0, 60.0], [10.0, 60.0]])
    found = [(0, TagDetection(5, square)), (0, TagDetection(6, square - [12, 0], partial=True)), (1, TagDetection(6, square))]
    assert [(o.photo, o.tag) for o in _observations(found, {0: camera, 1: camera}, 4.0)] == [(0, 5), (1, 6)]


def test_an_id_printed_twice_and_seen_twice_in_a_photo_is_named_and_left_out(tmp_path, network):
    """Node n02-04 carries a second print of n02-02's tag: photos showing both name the tag and the photo, both nodes
    stay unmeasured (which copy is the node's cannot be told), and the rest is measured as before."""
    tag_map = make_tag_map(network)
    copy, instead_of = tag_map.tag_of_node["n02-02"], tag_map.tag_of_node["n02-04"]
    spec = SyntheticSpec(photos=10, width=1600, height=1200, focal_px=1300, coverage=0.7, sag_mm=25.0, seed=3,
                         misprints=((copy, instead_of),))
    truth = simulate_survey(network, tmp_path / "set", spec)
    record = measure_survey(list_photos(tmp_path / "set" / "photos"), network, load_camera(tmp_path / "set" / "camera.json"),
                            load_tag_map(tmp_path / "set" / "tagmap.json"), tmp_path / "survey",
                            MeasureOptions(reference="supports", pictures=False))
    twice = [p for p in record["problems"] if p.get("tag") == copy]
    assert twice and all(f"tag {copy} appears 2 times in this photo" in p["problem"] and p["file"] in p["problem"]
                         and "printed more than once" in p["problem"] for p in twice)
    assert "n02-02" not in record["nodes"] and "printed more than once" in record["not_seen"]["n02-02"]
    assert "n02-04" not in record["nodes"]
    ids = list(record["nodes"])
    error = np.array([record["nodes"][n]["deviation_mm"] for n in ids]) - [truth["nodes"][n]["deviation_mm"] for n in ids]
    assert len(ids) >= 0.85 * len(truth["nodes"]) and np.sqrt(np.mean(np.sum(error ** 2, axis=1))) < 0.5


def test_an_id_seen_at_another_place_in_one_photo_is_named_and_left_out(tmp_path, network, photo_set):
    """One photo shows a tag's print on another node's spot (and not the tag itself, which the other photos show where
    it is): inconsistent across photos, reported naming the tag and the photos, kept out of the adjustment; the other
    nodes are measured."""
    from fabline.survey.simulate import _render_tag

    out, truth = photo_set
    photos = tmp_path / "photos"
    shutil.copytree(out / "photos", photos)
    k = min(range(len(truth["photos"])), key=lambda k: len(truth["photos"][k]["rendered"]))
    record = truth["photos"][k]
    seen = [sum(t in p["visible"] for p in truth["photos"]) for t in range(len(truth["nodes"]))]
    tag = next(t for t in range(len(seen)) if t not in record["rendered"] and seen[t] >= 3)
    victim = min(record["visible"])
    gray = read_gray(photos / f"photo-{k:03d}.jpg").astype(np.float32)
    _render_tag(gray, tag, np.array(record["visible"][victim]), 0.9)
    (photos / f"photo-{k:03d}.jpg").unlink()
    cv2.imwrite(str(photos / f"photo-{k:03d}.png"), np.clip(gray + 0.5, 0, 255).astype(np.uint8))
    result = measure_survey(list_photos(photos), network, load_camera(out / "camera.json"), load_tag_map(out / "tagmap.json"),
                            tmp_path / "survey", MeasureOptions(reference="supports", pictures=False))
    problems = [p["problem"] for p in result["problems"] if p.get("tag") == tag]
    assert len(problems) == 1 and f"tag {tag}: photo(s) photo-{k:03d}.png show it away from where photo(s) " in problems[0]
    assert "printed more than once" in problems[0]
    node = next(n for n, v in truth["nodes"].items() if v["tag"] == tag)
    assert node not in result["nodes"] and "printed more than once" in result["not_seen"][node]
    assert len(result["nodes"]) >= 0.85 * len(truth["nodes"])


def test_verdicts_count_the_uncertainty():
    """The issue's case: 12 mm off with a 7 mm sigma (14 mm at 2 sigma) against 20 mm is uncertain, not a pass; the
    sigma that counts is the one along the deviation; k = 0 is the bare distance."""
    from fabline.survey.measure import verdicts

    deviation = np.array([[12.0, 0, 0], [0, 12.0, 0], [25.0, 0, 0], [0, 0, 25.0], [0, 0, 0], [19.0, 0, 0]])
    covariances = np.array([np.diag(v) ** 2 for v in ([7.0, 1, 1], [7.0, 1, 1], [1.0, 1, 1], [1.0, 1, 5], [1.0, 3, 1],
                                                       [0.1, 1, 1])])
    verdict, sigma = verdicts(deviation, covariances, 20.0, 2.0)
    assert verdict.tolist() == ["uncertain", "pass", "fail", "uncertain", "pass", "pass"]
    assert sigma == pytest.approx([7.0, 1.0, 1.0, 5.0, 3.0, 0.1])
    assert verdicts(deviation, covariances, 20.0, 0.0)[0].tolist() == ["pass", "pass", "fail", "fail", "pass", "pass"]


def test_deviation_map_shows_high_and_low_and_names_failing_nodes(tmp_path, network):
    """Red for a node high along its normal, blue for one low, a red ring around a failing node and its id written
    beside it, an orange ring around an uncertain one."""
    from fabline.survey.measure import write_deviation_map

    model = network.in_mm()
    node = {"distance_mm": 15.0, "distance_sigma_mm": 1.0, "views": 3, "tag": 0}
    record = {"tolerance_mm": 10.0, "nodes": {"n02-02": {**node, "normal_mm": 15.0, "verdict": "fail"},
                                               "n04-04": {**node, "normal_mm": -15.0, "verdict": "fail"},
                                               "n01-03": {**node, "normal_mm": 3.0, "verdict": "uncertain"}},
              "summary": {"measured": 3, "rms_deviation_mm": 15, "max_deviation_mm": 15, "passed": 0, "failed": 2,
                          "uncertain": 1, "k_sigma": 2.0, "not_seen": len(model.nodes) - 3}}
    write_deviation_map(model, record, tmp_path / "map.png")
    image = cv2.imread(str(tmp_path / "map.png"))
    ids, xyz, _ = model.node_array()
    low, high = xyz[:, :2].min(axis=0), xyz[:, :2].max(axis=0)
    scale = (1600 - 160) / max(high - low)
    height = int((high[1] - low[1]) * scale) + 160

    def pixel(nid, dx=0):
        x, y = xyz[ids.index(nid), :2]
        return image[int(round(height - 80 - (y - low[1]) * scale)), int(round(80 + (x - low[0]) * scale)) + dx].astype(int)

    blue, green, red = pixel("n02-02")
    assert red > 150 and blue < 100  # high: red
    blue, green, red = pixel("n04-04")
    assert blue > 150 and red < 100  # low: blue
    radius = max(4, int(min(12, 0.3 * scale * np.median(np.linalg.norm(np.diff(xyz, axis=0), axis=1)))))
    assert pixel("n04-04", radius + 3).tolist() == [0, 0, 255]  # the failing node's ring
    assert tuple(pixel("n01-03", radius + 3)) == (0, 150, 255)  # the uncertain node's ring
    x, y = xyz[ids.index("n02-02"), :2]
    label = image[int(height - 80 - (y - low[1]) * scale) - 30:int(height - 80 - (y - low[1]) * scale),
                  int(80 + (x - low[0]) * scale) + radius + 4:int(80 + (x - low[0]) * scale) + radius + 80]
    assert np.sum(np.all(label == [0, 0, 160], axis=2)) > 20  # the node's id written beside it, dark red
