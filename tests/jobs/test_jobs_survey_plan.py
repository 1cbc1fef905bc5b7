"""The survey stage photographing from a photo plan (`survey.plan`): planned from the design or read from a plan file,
and its line of how many nodes two or more photos saw, on a small design."""

from __future__ import annotations

import json
import shutil
from collections import Counter

import pytest

from fabline.errors import FablineError
from fabline.jobs.jobfile import load_job_file
from fabline.jobs.pipeline import run_job
from jobfiles import GOOD, write

JOB = GOOD.replace('name = "small"', 'name = "small"\nstages = ["unroll", "survey", "report"]') + """
[survey]
simulate = true
plan = true
resolution = "1200x800"
"""


@pytest.fixture(scope="module")
def planned(tmp_path_factory):
    folder = tmp_path_factory.mktemp("planned")
    lines: list[str] = []
    run_job(write(folder, JOB), say=lines.append)
    return folder, lines


def test_the_stage_photographs_from_the_planned_stations(planned):
    folder, lines = planned
    survey = folder / "out" / "survey"
    plan = json.loads((survey / "plan.json").read_text())
    assert (survey / "plan.svg").is_file()
    truth = json.loads((survey / "truth.json").read_text())
    photos = sorted((survey / "photos").iterdir())
    assert len(photos) == len(truth["photos"]) == len(plan["stations"]) >= 2
    # every photo is taken from its station, in order: the truth's pose is the plan's
    for photo, station in zip(truth["photos"], plan["stations"]):
        assert photo["rotation"] == pytest.approx(station["rotation"], abs=1e-6)
        assert photo["translation_mm"] == pytest.approx(station["translation_mm"], abs=1e-3)
    views = Counter(int(tag) for photo in truth["photos"] for tag in photo["visible"])  # JSON keys: strings
    tagged = [node["tag"] for node in truth["nodes"].values() if node["tag"] is not None]
    twice = sum(views[tag] >= 2 for tag in tagged)
    said = next(line for line in lines if "photos of 1200 x 800 px from the plan's stations" in line)
    assert said.endswith(f"; {twice} of {len(tagged)} tagged nodes in 2 or more photos")
    report = json.loads((folder / "out" / "report.json").read_text())
    assert report["survey"]["simulated"]["seen_twice"] == twice
    assert report["survey"]["simulated"]["plan"] == str(survey / "plan.json")
    page = (folder / "out" / "report.html").read_text()
    assert f"{twice} of {len(tagged)} tagged nodes in 2 or more photos" in page


def test_a_plan_file_sets_the_photos_and_bad_plans_are_one_line(planned, tmp_path):
    folder, _ = planned
    shutil.copy(folder / "out" / "survey" / "plan.json", tmp_path / "plan.json")
    stations = len(json.loads((tmp_path / "plan.json").read_text())["stations"])
    text = JOB.replace("plan = true\n", 'plan = "plan.json"\n').replace('resolution = "1200x800"\n', "")
    spec = load_job_file(write(tmp_path, text))
    assert (spec.survey["plan"], spec.survey["photos"], spec.survey["resolution"]) == \
        (str(tmp_path / "plan.json"), stations, "1200x800")
    for table, message in (
            ('plan = "plan.json"\nphotos = 8', "job.toml: survey.photos: the plan sets it (one photo per station); leave it out"),
            ("plan = 3", "job.toml: survey.plan: expected true, false or a string, got integer 3"),
            ('plan = "none.json"', f"job.toml: survey.plan: file not found: {tmp_path / 'none.json'}")):
        with pytest.raises(FablineError) as err:
            load_job_file(write(tmp_path, text.replace('plan = "plan.json"', table)))
        assert str(err.value) == message
    (tmp_path / "bad.json").write_text('{"schema": "fabline.survey-plan/1"}')
    with pytest.raises(FablineError, match=r"^job.toml: survey.plan: .*bad.json"):
        load_job_file(write(tmp_path, text.replace('plan = "plan.json"', 'plan = "bad.json"')))
