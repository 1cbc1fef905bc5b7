"""`fabline run` end to end on a small design: every stage, the simulator executed every program line once,
and the report (HTML + JSON) shows pictures first, every sheet with every part labelled, and the check."""

from __future__ import annotations

import json
import re
from html.parser import HTMLParser
from pathlib import Path

import pytest

from fabline.cli import main
from fabline.geometry import analyse, lamella_table
from fabline.link import load_program
from fabline.model import load_network
from fabline.nest import load_nesting
from fabline.unroll import get_material, load_parts, parse_profile
from runner_support import executed_program_lines

JOB = """
name = "tiny"
description = "A small Enneper patch for the pipeline test."
[model]
design = "enneper"
[model.options]
size = [1.5, 1.5]
spacing = 0.5
[stock]
sheet = "1200x500"
[machine]
time_scale = 1000.0
ports = ["sim://pipeline-1?log={log}1", "sim://pipeline-2?log={log}2"]
[output]
folder = "out"
"""


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    folder = tmp_path_factory.mktemp("job")
    log = folder / "executed.log"
    job = folder / "tiny.toml"
    job.write_text(JOB.format(log=log), encoding="utf-8")
    import io
    from contextlib import redirect_stdout

    out = io.StringIO()
    with redirect_stdout(out):
        code = main(["run", str(job)])
    return {"code": code, "out": out.getvalue(), "folder": folder, "log": log, "dir": folder / "out"}


class Tags(HTMLParser):
    """The page's start tags in order, and the text inside SVG <text> labels."""

    def __init__(self):
        super().__init__()
        self.tags: list[str] = []
        self.labels: list[str] = []
        self._in_text = False

    def handle_starttag(self, tag, attrs):
        self.tags.append(tag)
        self._in_text = tag == "text"

    def handle_endtag(self, tag):
        self._in_text = False

    def handle_data(self, data):
        if self._in_text:
            self.labels.append(data)


def test_run_prints_where_the_report_is(run):
    assert run["code"] == 0
    report = run["dir"] / "report.html"
    assert f"report: {report.resolve()}" in run["out"]
    assert (run["dir"] / "report.json").is_file()


def test_every_output_stays_inside_the_output_folder(run):
    outside = [p for p in run["folder"].rglob("*") if p.is_file() and run["dir"] not in p.parents]
    assert sorted(p.name for p in outside) == ["executed.log1", "executed.log2", "tiny.toml"]


def test_the_two_simulators_executed_every_program_line_once_in_order(run):
    """Each sheet is cut whole on one machine, in order; together the machines cut every sheet exactly once."""
    nesting = load_nesting(run["dir"] / "nesting.json")
    programs = sorted((run["dir"] / "gcode").glob("*.gcode"))
    assert len(programs) == len(nesting.sheets) >= 3
    wires = {p.name: [line.wire.decode().strip() for line in load_program(p).lines] for p in programs}
    data = json.loads((run["dir"] / "report.json").read_text())
    cut_on = {Path(s["program"]).name: s["port"] for s in data["stream"]["sheets"]}
    assert sorted(cut_on) == sorted(wires)
    for k in (1, 2):
        log = Path(f"{run['log']}{k}")
        mine = [name for name in sorted(wires) if cut_on[name].startswith(f"sim://pipeline-{k}")]
        assert mine, f"machine {k} cut no sheet"
        # machines take the sheets in order, so a log is its machine's programs back to back in sheet order
        assert executed_program_lines(log) == [line for name in mine for line in wires[name]]
    assert data["stream"]["finished"]
    assert data["stream"]["executed"] == data["stream"]["lines"] == sum(len(w) for w in wires.values())


def test_every_part_is_nested_once_and_labelled_on_its_sheet_picture(run):
    parts = load_parts(run["dir"] / "parts.json")
    nesting = load_nesting(run["dir"] / "nesting.json")
    placed = [p.part for sheet in nesting.sheets for p in sheet.placements]
    assert sorted(placed) == sorted(p.id for p in parts.parts)
    page = Tags()
    page.feed((run["dir"] / "report.html").read_text())
    assert sorted(label for label in page.labels if label in set(placed)) == sorted(placed)


def test_pictures_come_first_and_the_page_is_self_contained(run):
    html = (run["dir"] / "report.html").read_text()
    page = Tags()
    page.feed(html)
    nesting = load_nesting(run["dir"] / "nesting.json")
    assert page.tags.count("svg") == 1 + len(nesting.sheets)
    assert page.tags.index("svg") < page.tags.index("table"), "pictures before tables"
    assert not re.search(r'(src|href)="(?!#|data:)', html), "no external resources"
    assert "<script" not in html


def test_structural_check_matches_the_closed_form(run):
    """Bending utilisation = E t k_g / (2 f_y) (domain.md 6.1), from the geometry's k_g, not from the report's code."""
    data = json.loads((run["dir"] / "report.json").read_text())
    network = load_network(run["dir"] / "network.json")
    material, profile = get_material("stainless"), parse_profile("100x1.5")
    rows = {r["lamella"]: r for r in data["structure"]["lamellas"]}
    table = lamella_table(analyse(network))
    assert sorted(rows) == sorted(r["lamella"] for r in table)
    for geo in table:
        expected = material.E * profile.t * (geo["max_k_g"] / 1000.0) / 2.0 / material.f_y
        assert rows[geo["lamella"]]["utilisation_bending"] == pytest.approx(expected, rel=1e-3, abs=1e-4)
    assert data["structure"]["passes"] == all(r["utilisation"] <= 1.0 for r in rows.values())


def test_missing_model_file_is_one_line_exit_2_nothing_written(tmp_path, cli):
    job = tmp_path / "bad.toml"
    job.write_text('name = "bad"\n[model]\nfile = "gone.network.json"\n[output]\nfolder = "out"\n', encoding="utf-8")
    code, out, err = cli("run", job)
    assert code == 2
    assert err.startswith("fabline run: error: bad.toml: model.file: file not found:") and err.count("\n") == 1
    assert not (tmp_path / "out").exists()


def test_report_shows_a_survey_result_with_its_deviation_map(tmp_path):
    import base64

    import cv2
    import numpy as np

    survey = {"schema": "fabline.survey/1", "summary": {"nodes": 9, "measured": 8, "rms_deviation_mm": 3.25}}
    (tmp_path / "survey").mkdir()
    (tmp_path / "survey" / "survey.json").write_text(json.dumps(survey), encoding="utf-8")
    ok, png = cv2.imencode(".png", np.full((8, 8, 3), 200, np.uint8))
    (tmp_path / "survey" / "deviation_map.png").write_bytes(png.tobytes())
    job = tmp_path / "built.toml"
    job.write_text('name = "built"\nstages = ["report"]\n[model]\ndesign = "enneper"\n[model.options]\n'
                   'size = [1.5, 1.5]\nspacing = 0.5\n[survey]\nresult = "survey/survey.json"\n[output]\nfolder = "out"\n',
                   encoding="utf-8")
    assert main(["run", str(job), "--quiet"]) == 0
    data = json.loads((tmp_path / "out" / "report.json").read_text())
    assert data["survey"] == survey and data["stream"]["sheets"] == []
    html = (tmp_path / "out" / "report.html").read_text()
    assert "<td>rms_deviation_mm</td><td>3.25</td>" in html
    assert f'src="data:image/png;base64,{base64.b64encode(png.tobytes()).decode()}"' in html
