"""`fabline survey ...` end to end in-process: outputs, JSON, and one-line errors with exit code 2."""

from __future__ import annotations

import json
import re

import cv2
import numpy as np
import pytest

from fabline.model import save_network
from fabline.survey import rigid_fit, saddle_network


@pytest.fixture(scope="module")
def model_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("model") / "saddle.network.json"
    save_network(saddle_network(2.0, 0.5, 3.0), path)
    return path


@pytest.fixture(scope="module")
def simulated(tmp_path_factory, model_file):
    """`survey simulate` run once through the CLI: a small, fast photo set."""
    from fabline.cli import main

    out = tmp_path_factory.mktemp("sim")
    code = main(["survey", "simulate", "--model", str(model_file), "-o", str(out), "--photos", "8", "--resolution", "1600x1200",
                 "--focal", "1300", "--coverage", "0.8", "--seed", "5"])
    assert code == 0
    return out


def test_tags_writes_sheets_and_map(cli, model_file, tmp_path):
    code, out, err = cli("survey", "tags", "--model", model_file, "-o", tmp_path, "--tag-size", "50", "--mount-offset", "15")
    assert code == 0, err
    tag_map = json.loads((tmp_path / "tagmap.json").read_text())
    assert tag_map["schema"] == "fabline.tagmap/1" and tag_map["tag_size_mm"] == 50 and tag_map["mount_offset_mm"] == 15
    assert len(tag_map["tags"]) == 25
    assert (tmp_path / "tags.pdf").read_bytes().startswith(b"%PDF") and list(tmp_path.glob("tags-*.svg"))


def test_simulate_writes_photos_camera_and_truth(simulated):
    truth = json.loads((simulated / "truth.json").read_text())
    assert truth["schema"] == "fabline.survey-truth/1" and len(truth["photos"]) == 8
    node = next(iter(truth["nodes"].values()))
    assert np.allclose(np.subtract(node["built_mm"], node["design_mm"]), node["deviation_mm"], atol=1e-3)
    assert json.loads((simulated / "camera.json").read_text())["width"] == 1600
    assert cv2.imread(str(simulated / truth["photos"][0]["file"])).shape == (1200, 1600, 3)


def test_detect_json_with_poses(cli, simulated):
    truth = json.loads((simulated / "truth.json").read_text())
    record = max(truth["photos"], key=lambda p: len(p["visible"]))
    photo = simulated / record["file"]
    code, out, err = cli("survey", "detect", photo, "--camera", simulated / "camera.json", "--tag-size", "65", "--json")
    assert code == 0, err
    (entry,) = json.loads(out)
    found = {t["id"]: t for t in entry["tags"]}
    assert set(map(int, record["visible"])) <= set(found)
    for tag_id, corners in record["visible"].items():
        tag = found[int(tag_id)]
        assert np.abs(np.array(tag["corners_px"]) - corners).max() < 0.5
        assert tag["partial"] is False  # wholly inside the photo
        assert len(tag["rotation"]) == 3 and 500 < tag["translation_mm"][2] < 10000  # mm, in front of the camera
        assert tag["reprojection_px"] < 0.5 and 0 <= tag["ambiguity"] <= 1 and tag["ambiguous"] == (tag["ambiguity"] > 0.5)


def test_measure_prints_a_summary_and_writes_the_survey(cli, model_file, simulated, tmp_path):
    code, out, err = cli("survey", "measure", simulated / "photos", "--model", model_file, "--camera", simulated / "camera.json",
                         "--tags", simulated / "tagmap.json", "-o", tmp_path, "--tolerance", "15")
    assert code == 0, err
    assert re.search(r"nodes measured from \d+ of \d+ photos: RMS deviation \d+\.\d mm, max \d+\.\d mm;", out), out
    record = json.loads((tmp_path / "survey.json").read_text())
    assert record["tolerance_mm"] == 15 and record["registration"]["reference"] == "all"
    assert record["scale"]["min_cell_px"] == 4.0 and record["scale"]["observations_without_scale"] >= 0
    truth = json.loads((simulated / "truth.json").read_text())
    ids = list(record["nodes"])
    measured = np.array([record["nodes"][n]["measured_mm"] for n in ids])
    built = np.array([truth["nodes"][n]["built_mm"] for n in ids])
    rotation, translation = rigid_fit(measured, built)  # the measured shape, whatever the registration
    assert len(ids) > 10 and np.sqrt(np.mean(np.sum((measured @ rotation.T + translation - built) ** 2, axis=1))) < 1.0


def test_a_scale_bar_corrects_a_wrong_tag_size(cli, model_file, simulated, tmp_path):
    """The tag map claims 63 mm tags (printed 65 mm): a measured distance between two tag centres fixes the scale."""
    truth = json.loads((simulated / "truth.json").read_text())
    tag_map = json.loads((simulated / "tagmap.json").read_text())
    (tmp_path / "small.json").write_text(json.dumps({**tag_map, "tag_size_mm": 63.0}))
    seen = {int(t) for p in truth["photos"] for t in p["visible"]}
    centre = {n["tag"]: np.array(n["tag_centre_mm"]) for n in truth["nodes"].values() if n["tag"] in seen}
    a, b = max(((a, b) for a in centre for b in centre), key=lambda pair: np.linalg.norm(centre[pair[0]] - centre[pair[1]]))
    length = np.linalg.norm(centre[a] - centre[b])
    common = ["survey", "measure", simulated / "photos", "--model", model_file, "--camera", simulated / "camera.json",
              "--tags", tmp_path / "small.json"]
    built = {n: np.array(v["built_mm"]) for n, v in truth["nodes"].items()}

    def span_error(record):
        ids = list(record["nodes"])
        measured = np.array([record["nodes"][n]["measured_mm"] for n in ids])
        return np.ptp(measured[:, 0]) / np.ptp(np.array([built[n][0] for n in ids])) - 1

    assert cli(*common, "-o", tmp_path / "plain")[0] == 0
    code, out, err = cli(*common, "-o", tmp_path / "bar", "--scale-bar", str(a), str(b), f"{length:.1f}")
    assert code == 0, err
    plain = json.loads((tmp_path / "plain" / "survey.json").read_text())
    record = json.loads((tmp_path / "bar" / "survey.json").read_text())
    assert span_error(plain) == pytest.approx(63 / 65 - 1, abs=2e-3)  # without the bar the shell is 3 % small
    assert abs(span_error(record)) < 1e-3
    assert record["scale"]["factor"] == pytest.approx(65 / 63, rel=1e-3)
    assert record["scale"]["bars"][0]["tags"] == [a, b] and abs(record["scale"]["bars"][0]["misfit_mm"]) < 0.1


@pytest.mark.parametrize("args, message", [
    (["survey", "detect", "{tmp}/missing.jpg"], "missing.jpg: file not found"),
    (["survey", "detect", "{sim}/photos/photo-000.jpg", "--camera", "{sim}/camera.json"], "poses need both --camera and --tag-size"),
    (["survey", "detect", "{sim}/photos/photo-000.jpg", "--camera", "{sim}/camera.json", "--tag-size", "0.065"],
     "--tag-size 0.065: a tag's black-square edge in millimetres must be 5 to 2000; 0.065 looks like metres: give 65"),
    (["survey", "tags", "--model", "{model}", "-o", "{tmp}/out", "--tag-size", "0.05"], "0.05 looks like metres: give 50"),
    (["survey", "simulate", "--model", "{model}", "-o", "{tmp}/out", "--tag-size", "6500"],
     "--tag-size 6500: a tag's black-square edge in millimetres must be 5 to 2000"),
    (["survey", "measure", "{sim}/photos", "--model", "{model}", "--camera", "{sim}/camera.json", "--tags", "{tmp}/metres.json",
      "-o", "{tmp}/out"], "metres.json: field 'tag_size_mm' 0.065: a tag's black-square edge in millimetres"),
    (["survey", "tags", "--model", "{tmp}/none.json", "-o", "{tmp}/out"], "none.json: file not found"),
    (["survey", "measure", "{tmp}", "--model", "{model}", "--camera", "{sim}/camera.json", "-o", "{tmp}/out"], "no photos"),
    (["survey", "measure", "{sim}/photos", "--model", "{model}", "--camera", "{tmp}/bad-camera.json", "-o", "{tmp}/out"],
     "bad-camera.json: field 'fx' must be a positive number"),
    (["survey", "measure", "{sim}/photos", "--model", "{model}", "--camera", "{tmp}/other-camera.json", "-o", "{tmp}/out"],
     "photo-000.jpg: image is 1600 x 1200 px but the camera file is for 4000 x 3000 px"),
    (["survey", "measure", "{sim}/photos", "--model", "{model}", "--camera", "{sim}/camera.json", "--tags", "{tmp}/two.json",
      "-o", "{tmp}/out"], "two.json: tag 1 is given to two nodes"),
    (["survey", "measure", "{sim}/photos", "--model", "{model}", "--camera", "{sim}/camera.json", "--tags", "{tmp}/ghost.json",
      "-o", "{tmp}/out"], "tag 2 is mapped to node ghost, which the model does not define"),
    (["survey", "measure", "{sim}/photos", "--model", "{model}", "--camera", "{sim}/camera.json", "-o", "{tmp}/out",
      "--scale-bar", "0", "999", "1500"], "--scale-bar 0 999 1500: tag 999 is not in the tag map"),
    (["survey", "measure", "{sim}/photos", "--model", "{model}", "--camera", "{sim}/camera.json", "-o", "{tmp}/out",
      "--scale-bar", "3", "3", "1500"], "--scale-bar 3 3 1500: a bar needs two different tags"),
    (["survey", "measure", "{sim}/photos", "--model", "{model}", "--camera", "{sim}/camera.json", "-o", "{tmp}/out",
      "--scale-bar", "0", "4", "0"], "--scale-bar 0 4 0: the distance must be a positive number of mm"),
    (["survey", "measure", "{sim}/photos", "--model", "{model}", "--camera", "{sim}/camera.json", "-o", "{tmp}/out",
      "--scale-bar", "0", "4", "1.5 furlong"], "--scale-bar 0 4 1.5 furlong: expected two tag ids and a distance in mm"),
    (["survey", "measure", "{sim}/photos", "--model", "{model}", "--camera", "{sim}/camera.json", "-o", "{tmp}/out",
      "--scale-min-cell", "-1"], "--scale-min-cell -1: must be a number of px, 0 or more"),
    *[(["survey", "measure", "{sim}/photos", "--model", "{model}", "--camera", "{sim}/camera.json", "-o", "{tmp}/out",
        option, value], message) for option, value, message in [
        ("--tolerance", "0", "--tolerance 0: must be a distance in mm, more than 0"),
        ("--tolerance", "-5", "--tolerance -5: must be a distance in mm, more than 0"),
        ("--tolerance", "-5", "--tolerance -5: must be a distance in mm, more than 0"),
        ("--min-views", "0", "--min-views 0: a tag must be seen in at least 2 photos")]],
    (["survey", "calibrate", "{tmp}", "-o", "{tmp}/cam.json"], "no photos"),
    (["survey", "simulate", "--model", "{model}", "-o", "{tmp}/out", "--resolution", "big"], "--resolution 'big': expected WIDTHxHEIGHT"),
])
def test_bad_input_is_one_line_exit_2_nothing_written(cli, model_file, simulated, tmp_path, args, message):
    camera = json.loads((simulated / "camera.json").read_text())
    (tmp_path / "bad-camera.json").write_text(json.dumps({**camera, "fx": -1}))
    (tmp_path / "other-camera.json").write_text(json.dumps({**camera, "width": 4000, "height": 3000}))
    tag_map = json.loads((simulated / "tagmap.json").read_text())
    (tmp_path / "two.json").write_text(json.dumps({**tag_map, "tags": tag_map["tags"] + [{"tag": 1, "node": "n00-00"}]}))
    (tmp_path / "metres.json").write_text(json.dumps({**tag_map, "tag_size_mm": 0.065}))
    ghost = json.loads(json.dumps(tag_map))
    ghost["tags"][2]["node"] = "ghost"
    (tmp_path / "ghost.json").write_text(json.dumps(ghost))
    fill = {"tmp": str(tmp_path), "sim": str(simulated), "model": str(model_file)}
    code, out, err = cli(*[a.format(**fill) for a in args])
    assert code == 2 and out == ""
    assert err.startswith("fabline survey: error: ") and message in err and err.count("\n") == 1
    assert not (tmp_path / "out").exists() and not (tmp_path / "cam.json").exists()


def test_calibrate_write_board(cli, tmp_path):
    code, out, err = cli("survey", "calibrate", "--write-board", tmp_path / "board.png", "--board", "6x4", "--square", "30",
                         "--marker", "22")
    assert code == 0, err
    assert cv2.imread(str(tmp_path / "board.png"), cv2.IMREAD_GRAYSCALE).shape == (1200, 1800)
    assert "print at 180 x 120 mm" in out


def test_a_photo_bomb_is_skipped_and_a_cut_jpeg_noted_the_survey_goes_on(cli, model_file, simulated, tmp_path):
    """A PNG whose header claims 100000 x 100000 px is refused before decoding (one problem, the survey goes on);
    a JPEG cut short is used, and survey.json says so."""
    import shutil
    import zlib

    photos = tmp_path / "photos"
    shutil.copytree(simulated / "photos", photos)

    def chunk(kind: bytes, data: bytes) -> bytes:
        return len(data).to_bytes(4, "big") + kind + data + zlib.crc32(kind + data).to_bytes(4, "big")

    header = (100000).to_bytes(4, "big") * 2 + bytes([8, 0, 0, 0, 0])
    (photos / "bomb.png").write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header)
                                      + chunk(b"IDAT", zlib.compress(b"\0" * 64)) + chunk(b"IEND", b""))
    cut = sorted(photos.glob("*.jpg"))[-1]
    cut.write_bytes(cut.read_bytes()[: cut.stat().st_size * 9 // 10])
    code, out, err = cli("survey", "measure", photos, "--model", model_file, "--camera", simulated / "camera.json",
                         "--tags", simulated / "tagmap.json", "-o", tmp_path / "out")
    assert code == 0, err
    problems = json.loads((tmp_path / "out" / "survey.json").read_text())["problems"]
    assert [p["problem"] for p in problems if p.get("file") == str(photos / "bomb.png")] == [
        f"{photos / 'bomb.png'}: the image is 100000 x 100000 px by its header, more than 150 megapixels: not read"]
    assert any(p.get("file") == str(cut) and "JPEG is cut short" in p["problem"] for p in problems), problems
