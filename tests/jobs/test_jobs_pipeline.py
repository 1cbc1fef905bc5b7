"""`fabline run` end to end on a small design: every stage, the simulator executed every program line once,
the simulated survey agrees with the deviations it injected, and the report (HTML + JSON) shows pictures
first, every sheet with every part labelled, the check and the survey."""

from __future__ import annotations

import base64
import json
import re
import shutil
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

from fabline.cli import main
from fabline.geometry import analyse, lamella_table
from fabline.machine import load_program
from fabline.mechanics import get_material, parse_profile
from fabline.model import load_network
from fabline.nest import load_nesting
from fabline.unroll import load_parts
from runner_support import executed_program_lines, headless_chromium

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
[survey]
simulate = true
photos = 6
resolution = "1200x800"
coverage = 1.5
sag_mm = 25.0
tolerance_mm = 10.0
scale_bars = 2
[output]
folder = "out"
"""
SURVEY_PHOTOS = 6
SURVEY_TOLERANCE_MM = 10.0


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    folder = tmp_path_factory.mktemp("job")
    log = folder / "out" / "executed.log"  # a port writes only inside the output folder
    job = folder / "tiny.toml"
    job.write_text(JOB.format(log=log), encoding="utf-8")
    import io
    from contextlib import redirect_stdout

    stale = folder / "out" / "survey" / "photos" / "photo-099.jpg"  # an earlier, larger photo set's last photo
    stale.parent.mkdir(parents=True)
    stale.write_bytes(b"not this job's photo")
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
    assert sorted(p.name for p in outside) == ["tiny.toml"]  # the simulators' logs too: a port writes only inside


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


def test_pictures_come_first_and_the_page_works_offline_from_its_folder(run, tmp_path):
    """The model and each sheet inline, each sheet's cut order and the deviation map the files in the output folder,
    linked relatively and loaded lazily: the page still finds them when the folder is moved."""
    html = (run["dir"] / "report.html").read_text()
    page = Tags()
    page.feed(html)
    nesting = load_nesting(run["dir"] / "nesting.json")
    assert page.tags.count("svg") == 1 + len(nesting.sheets)      # the model and each sheet
    assert page.tags.index("table") < page.tags.index("svg") < page.tags.index("table", page.tags.index("table") + 1), \
        "the summary, then the pictures, then the other tables"
    assert "<script" not in html and "data:" not in html
    moved = tmp_path / "moved"
    shutil.copytree(run["dir"], moved)
    links = re.findall(r'<img src="([^"]+)" loading=lazy', html) + re.findall(r'<img alt="[^"]*" src="([^"]+)" loading=lazy', html)
    assert len(links) == len(nesting.sheets) + 1 and len(re.findall(r"(?:src|href)=", html)) == len(links)
    for link in links:
        assert not link.startswith(("/", "http:", "https:", "file:")) and ".." not in link, link
        assert (moved / link).is_file(), link
    assert sorted(l for l in links if l.endswith(".order.svg")) == sorted(
        f"gcode/{Path(s['preview']).name}" for s in json.loads((run["dir"] / "report.json").read_text())["nesting"]["sheets"])


def test_report_starts_with_a_summary_and_lists_materials_hardware_and_cut_order(run):
    """The summary's machine time is the export's, its mass the sheets' volume times the material's density
    (worked out here from nesting.json and parts.json); every sheet has its cut-order preview; the streaming
    table gives short port names and the time at machine speed (wall seconds times the simulator's time scale)."""
    import csv

    html = (run["dir"] / "report.html").read_text()
    data = json.loads((run["dir"] / "report.json").read_text())
    nesting = load_nesting(run["dir"] / "nesting.json")
    parts = load_parts(run["dir"] / "parts.json")
    summary = html[html.index("<table id=summary"):html.index("</table>", html.index("<table id=summary"))]
    assert html.index("<table id=summary") < html.index("<svg")
    total = sum(json.loads((run["dir"] / "report.json").read_text())["nesting"]["sheets"][k]["time_s"]
                for k in range(len(nesting.sheets)))
    assert data["machine_time_s"] == pytest.approx(total)
    minutes, seconds = divmod(round(total), 60)
    assert f"{minutes // 60}:{minutes % 60:02d}:{seconds:02d}" in summary
    density = get_material(parts.material).density
    mass = sum(s.width * s.height for s in nesting.sheets) * parts.profile["t"] * density * 1e-9
    assert data["bill_of_materials"]["totals"]["mass_kg"] == pytest.approx(mass, abs=0.05 * len(nesting.sheets))
    shown = f"{mass / 1000:.2f} t" if mass >= 1000 else f"{mass:.1f} kg"
    structure = data["structure"]
    verdict = (f"all {len(structure['lamellas'])} lamellas pass" if structure["passes"]
               else f"{len(structure['failing'])} of {len(structure['lamellas'])} lamellas exceed yield")
    assert f"{shown} of sheet" in summary and verdict in summary and "survey" in summary
    assert "<table id=bom>" in html and "<table id=hardware>" in html
    assert html.count("<details class=preview") == len(nesting.sheets)
    stream = html[html.index("<table id=stream>"):]
    for sheet in data["stream"]["sheets"]:
        assert "?" in sheet["port"] and f"<td>{sheet['port'].split('?')[0]}</td>" in stream
        minutes, seconds = divmod(round(sheet["machine_s"]), 60)  # the simulator's own clock, not wall x 1000
        assert f"<td>{minutes // 60}:{minutes % 60:02d}:{seconds:02d}</td>" in stream
    assert ">sim://pipeline-1?" not in stream
    with open(run["dir"] / "cutlist.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert [r["part"] for r in rows] == [p.part for s in nesting.sheets for p in s.placements]
    with open(run["dir"] / "bom.csv", newline="") as handle:  # the bill beside the report, as its JSON has it
        bill = list(csv.DictReader(handle))
    assert len(bill) == len(data["bill_of_materials"]["items"])
    sheets = sum(int(r["count"]) for r in bill if r["kind"] == "sheet")
    assert sheets == len(nesting.sheets)
    washers = sum(1 for p in parts.parts if p.kind == "washer")
    assert sum(int(r["count"]) for r in bill if r["item"].startswith("carriage bolt")) == washers // 2


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


def _kabsch(source: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Best rigid fit of source onto target with scipy's own solver (independent of fabline's registration)."""
    from scipy.spatial.transform import Rotation

    rotation, _ = Rotation.align_vectors(target - target.mean(axis=0), source - source.mean(axis=0))
    matrix = rotation.as_matrix()
    return matrix, target.mean(axis=0) - matrix @ source.mean(axis=0)


def test_simulated_survey_writes_a_fresh_photo_set_and_its_survey(run):
    folder = run["dir"] / "survey"
    assert sorted(p.name for p in (folder / "photos").iterdir()) == [f"photo-{k:03d}.jpg" for k in range(SURVEY_PHOTOS)]
    for name in ("camera.json", "tagmap.json", "truth.json", "survey.json", "deviation_map.png"):
        assert (folder / name).is_file(), name
    assert not (run["dir"] / "survey.new").exists()
    truth = json.loads((folder / "truth.json").read_text())
    network = load_network(run["dir"] / "network.json")
    assert sorted(truth["nodes"]) == sorted(network.nodes)
    assert re.search(r"survey: \d+ of 9 nodes measured in [\d.]+ s: RMS deviation \d+\.\d mm, max \d+\.\d mm; at "
                     r"[\d.]+ mm \d+ pass, \d+ fail, \d+ uncertain, \d+ not seen of 9 nodes; against the injected "
                     r"truth RMS error \d+\.\d mm", run["out"]), run["out"]   # mm to 0.1, all four verdict counts


def test_report_survey_figures_agree_with_the_injected_truth(run):
    """The report's figures against truth.json: the simulator's injected deviations, fitted the way the survey fits."""
    data = json.loads((run["dir"] / "report.json").read_text())["survey"]
    record = json.loads((run["dir"] / "survey" / "survey.json").read_text())
    truth = json.loads((run["dir"] / "survey" / "truth.json").read_text())
    assert data["summary"] == record["summary"] and data["tolerance_mm"] == SURVEY_TOLERANCE_MM
    ids = list(record["nodes"])
    assert len(ids) >= 8 and data["summary"]["measured"] == len(ids)
    assert data["summary"]["not_seen"] == len(truth["nodes"]) - len(ids) == len(data["not_seen"])
    injected = np.array([truth["nodes"][n]["deviation_mm"] for n in truth["nodes"]])
    assert np.abs(injected[:, 2]).max() == pytest.approx(25.0)  # the sag is really there
    design = np.array([truth["nodes"][n]["design_mm"] for n in ids])
    built = np.array([truth["nodes"][n]["built_mm"] for n in ids])
    assert data["reference"] == "all"
    rotation, translation = _kabsch(built, design)
    true_deviation = built @ rotation.T + translation - design
    true_distance = np.linalg.norm(true_deviation, axis=1)
    measured = np.array([record["nodes"][n]["deviation_mm"] for n in ids])
    error = np.linalg.norm(measured - true_deviation, axis=1)
    rms_error = float(np.sqrt(np.mean(error ** 2)))
    assert rms_error < 1.5, "the survey recovers the sag to about a millimetre"
    comparison = data["truth"]
    assert comparison["nodes_compared"] == len(ids)
    bars = data["scale"]["bars"]  # simulated tape measurements: the true distances between the tags' centres
    centre = {node["tag"]: np.array(node["tag_centre_mm"]) for node in truth["nodes"].values()}
    assert len(bars) == 2 and data["simulated"]["scale_bars"] == [{k: b[k] for k in ("tags", "distance_mm")} for b in bars]
    for bar in bars:
        assert bar["distance_mm"] == pytest.approx(np.linalg.norm(centre[bar["tags"][0]] - centre[bar["tags"][1]]), abs=1e-3)
    assert comparison["rms_error_mm"] == pytest.approx(rms_error, abs=2e-3)
    assert comparison["max_error_mm"] == pytest.approx(error.max(), abs=2e-3)
    assert comparison["true_rms_deviation_mm"] == pytest.approx(np.sqrt(np.mean(true_distance ** 2)), abs=2e-3)
    summary = data["summary"]
    assert summary["rms_deviation_mm"] == pytest.approx(np.sqrt(np.mean(true_distance ** 2)), abs=1.5)
    assert summary["max_deviation_mm"] == pytest.approx(true_distance.max(), abs=1.5)
    true_pass = true_distance <= SURVEY_TOLERANCE_MM
    assert 0 < (~true_pass).sum() < len(ids), "the tolerance splits the nodes"
    verdict = np.array([record["nodes"][n]["verdict"] for n in ids])
    margin = 2 * np.array([record["nodes"][n]["distance_sigma_mm"] for n in ids])
    clear = np.abs(true_distance - SURVEY_TOLERANCE_MM) > 3 * rms_error + margin  # away from the threshold: agree
    assert clear.any() and np.array_equal(verdict[clear] == "pass", true_pass[clear])
    assert not np.any(np.where(true_pass, verdict == "fail", verdict == "pass"))  # near it: uncertain, never wrong
    assert summary["passed"] == int(np.sum(verdict == "pass")) and summary["failed"] == int(np.sum(verdict == "fail"))
    assert summary["uncertain"] == int(np.sum(verdict == "uncertain"))
    assert comparison["true_failed"] == int((~true_pass).sum()) and comparison["wrong_verdicts"] == 0
    assert comparison["pass_fail_agreement"] == int(np.sum(np.where(true_pass, verdict == "pass", verdict == "fail")))


def test_report_page_shows_the_survey_map_first_then_its_figures(run):
    html = (run["dir"] / "report.html").read_text()
    section = html[html.index("<h2>Survey</h2>"):html.index("<h2>Run</h2>")]
    assert (run["dir"] / "survey" / "deviation_map.png").is_file()
    assert re.match(r'<h2>Survey</h2><figure id=deviation-map[^>]*><img alt="deviation map" '
                    r'src="survey/deviation_map.png" loading=lazy>', section)
    data = json.loads((run["dir"] / "report.json").read_text())["survey"]
    s, truth = data["summary"], data["truth"]
    assert f"<tr><td>RMS deviation mm</td><td>{s['rms_deviation_mm']:.1f}</td></tr>" in section   # mm to 0.1
    assert f"<tr><td>max deviation mm</td><td>{s['max_deviation_mm']:.1f}</td></tr>" in section
    assert f"<tr><td>worst nodes</td><td>{', '.join(s['worst'])}</td></tr>" in section
    assert (f"({s['passed']} pass, {s['failed']} fail, {s['uncertain']} uncertain, {s['not_seen']} not seen of "
            f"{s['nodes']} nodes, against 10 mm with 2 sigma of margin)") in section
    assert s["passed"] + s["failed"] + s["uncertain"] + s["not_seen"] == s["nodes"]
    assert f"<tr><td>RMS of measured minus true deviation mm</td><td>{truth['rms_error_mm']:.1f}</td></tr>" in section
    assert not re.search(r"<td>\d+\.\d{3,}", section), "no survey figure with more than 2 decimals"
    assert section.index("id=deviation-map") < section.index("id=survey>") < section.index("id=survey-truth")
    stages = json.loads((run["dir"] / "report.json").read_text())["job"]["stages"]
    assert stages == ["unroll", "nest", "export", "stream", "survey", "report"]


def test_report_shows_an_existing_survey_result_with_its_deviation_map(run, tmp_path):
    """`survey.result` names a survey.json made elsewhere: the report shows it (and its map) without a survey stage."""
    (tmp_path / "measured").mkdir()
    for name in ("survey.json", "deviation_map.png"):
        shutil.copy(run["dir"] / "survey" / name, tmp_path / "measured" / name)
    job = tmp_path / "built.toml"
    job.write_text('name = "built"\nstages = ["report"]\n[model]\ndesign = "enneper"\n[model.options]\n'
                   'size = [1.5, 1.5]\nspacing = 0.5\n[survey]\nresult = "measured/survey.json"\n[output]\nfolder = "out"\n',
                   encoding="utf-8")
    assert main(["run", str(job), "--quiet"]) == 0
    data = json.loads((tmp_path / "out" / "report.json").read_text())
    record = json.loads((tmp_path / "measured" / "survey.json").read_text())
    assert data["survey"]["summary"] == record["summary"] and data["survey"]["truth"] is None
    assert data["stream"]["sheets"] == [] and data["job"]["stages"] == ["report"]
    assert not (tmp_path / "out" / "survey").exists()
    html = (tmp_path / "out" / "report.html").read_text()
    png = (tmp_path / "measured" / "deviation_map.png").read_bytes()
    assert f'src="data:image/png;base64,{base64.b64encode(png).decode()}"' in html
    assert f"<tr><td>RMS deviation mm</td><td>{record['summary']['rms_deviation_mm']:.1f}</td></tr>" in html


def test_a_survey_result_that_is_not_a_survey_is_one_line_exit_2_nothing_written(tmp_path, cli):
    (tmp_path / "survey.json").write_text(json.dumps({"schema": "fabline.nesting/1"}), encoding="utf-8")
    job = tmp_path / "built.toml"
    job.write_text('name = "built"\nstages = ["report"]\n[model]\ndesign = "enneper"\n[model.options]\n'
                   'size = [1.5, 1.5]\nspacing = 0.5\n[survey]\nresult = "survey.json"\n[output]\nfolder = "out"\n',
                   encoding="utf-8")
    code, out, err = cli("run", job)
    assert code == 2
    assert err == (f"fabline run: error: built.toml: survey.result: {tmp_path / 'survey.json'}: not a fabline.survey/1 "
                   "file (schema 'fabline.nesting/1')\n")
    assert not (tmp_path / "out").exists()


# The tiny job without its survey, its machines 25 times slower, so that a Ctrl-C lands while sheets are cut.
INTERRUPTED_JOB = (JOB[:JOB.index("[survey]")] + '[output]\nfolder = "out"\n').replace(
    'name = "tiny"', 'name = "interrupted"\nstages = ["unroll", "nest", "export", "stream"]').replace(
    "time_scale = 1000.0", "time_scale = 40.0").replace("sim://pipeline-", "sim://ctrl-c-")


@pytest.mark.parametrize("stop", ["SIGINT", "SIGTERM"])
def test_ctrl_c_or_a_service_stop_stops_every_machine_safely_and_resume_cuts_each_line_exactly_once(tmp_path, stop):
    """A Ctrl-C in the terminal (SIGINT) or a service stop (SIGTERM) reaches fabline and every link process; the
    run stops with a one-line hint and exit 130, and `--resume` finishes the job: each program line executed
    once, in order, on one machine."""
    import os
    import signal
    import subprocess
    import sys
    import time

    log = tmp_path / "out" / "executed.log"
    job = tmp_path / "job.toml"
    job.write_text(INTERRUPTED_JOB.format(log=log), encoding="utf-8")
    command = [sys.executable, "-m", "fabline", "run", str(job)]
    first = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                             preexec_fn=lambda: (os.setpgrp(), signal.signal(signal.SIGINT, signal.SIG_DFL)))
    journals = tmp_path / "out" / "gcode"
    deadline = time.monotonic() + 120
    while first.poll() is None and time.monotonic() < deadline and sum(j.stat().st_size for j in journals.glob("*.journal")) < 20_000:
        time.sleep(0.05)
    os.killpg(first.pid, getattr(signal, stop))  # what a terminal's Ctrl-C or systemd's stop does: the whole group
    out, err = first.communicate(timeout=60)
    assert first.returncode == 130, err
    assert "Traceback" not in err and err.strip().endswith(f"fabline run {job} --resume continues where they stopped")
    again = subprocess.run(command, capture_output=True, text=True, timeout=60)  # a new run must not cut over it
    assert again.returncode == 2 and "an earlier run stopped before finishing" in again.stderr, again.stderr
    assert " aborted in " in out
    done = sum(len(executed_program_lines(Path(f"{log}{k}"))) for k in (1, 2))

    second = subprocess.run(command + ["--resume"], capture_output=True, text=True, timeout=300)
    if second.returncode == 2 and "could not tell the line" in second.stderr:
        # The stop landed where the path passes twice and the resume rightly refused, naming both lines; the operator
        # looks at the part (here: the simulator's log of what ran) and names the first line not yet cut.
        sheet = re.search(r"sheet (\S+) on ", second.stderr)[1]
        candidates = [int(n) for n in re.search(r"one of ([\d, ]+)\)", second.stderr)[1].split(", ")]
        cut = set(executed_program_lines(Path(f"{log}1")) + executed_program_lines(Path(f"{log}2")))
        program = load_program(next(journals.glob(f"*_{sheet}.gcode")))
        first_uncut = next(line.file_line for line in program.lines if line.wire.decode().strip() not in cut)
        assert first_uncut in candidates, (first_uncut, candidates)
        second = subprocess.run(command + ["--resume", "--from-line", str(first_uncut)], capture_output=True,
                                text=True, timeout=300)
    assert second.returncode == 0, second.stderr
    programs = sorted(journals.glob("*.gcode"))
    wires = {p.name: [line.wire.decode().strip() for line in load_program(p).lines] for p in programs}
    executed = executed_program_lines(Path(f"{log}1")) + executed_program_lines(Path(f"{log}2"))
    assert 0 < done < len(executed)  # the interrupted run cut part of the job, the resumed one the rest
    assert sorted(executed) == sorted(line for lines in wires.values() for line in lines)  # none twice, none skipped



def test_a_second_run_stopped_midway_resumes_every_sheet_it_had_not_cut_though_the_first_run_cut_them(tmp_path):
    """A job run to its end, then run again (a second set of parts) and stopped in its first sheet: `--resume`
    cuts the rest of that sheet and every later sheet, each line once more in all; the first run's finished
    journals of those sheets are not taken as this run's (they were: every later sheet was reported finished and
    never cut)."""
    import os
    import signal
    import subprocess
    import sys
    import time

    log = tmp_path / "out" / "executed.log"
    job = tmp_path / "job.toml"
    one_machine = INTERRUPTED_JOB.replace(f', "sim://ctrl-c-2?log={{log}}2"', "")
    assert one_machine != INTERRUPTED_JOB
    job.write_text(one_machine.replace("time_scale = 40.0", "time_scale = 1000.0").format(log=log), encoding="utf-8")
    command = [sys.executable, "-m", "fabline", "run", str(job)]
    first = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert first.returncode == 0, first.stderr
    programs = sorted((tmp_path / "out" / "gcode").glob("*.gcode"))
    wires = sorted(line.wire.decode().strip() for p in programs for line in load_program(p).lines)
    assert len(programs) >= 2 and sorted(executed_program_lines(Path(f"{log}1"))) == wires
    job.write_text(one_machine.format(log=log), encoding="utf-8")  # the second run slower, to stop it midway
    second = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                              preexec_fn=os.setpgrp)
    deadline = time.monotonic() + 120
    while second.poll() is None and time.monotonic() < deadline and \
            len(executed_program_lines(Path(f"{log}1"))) < len(wires) + 20:
        time.sleep(0.05)
    os.killpg(second.pid, signal.SIGINT)
    second.communicate(timeout=60)
    assert second.returncode == 130
    cut = len(executed_program_lines(Path(f"{log}1"))) - len(wires)
    assert 0 < cut < len(load_program(programs[0]).lines), "stopped in the first sheet"
    resumed = subprocess.run(command + ["--resume"], capture_output=True, text=True, timeout=300)
    assert resumed.returncode == 0, resumed.stderr
    assert "finished in an earlier run" not in resumed.stdout
    assert sorted(executed_program_lines(Path(f"{log}1"))) == sorted(wires * 2)  # the second set whole, once

def test_run_summary_and_report_give_planned_machine_time_and_the_time_remaining(run):
    """Each sheet's line and the stream summary of `fabline run` give the machine time the controller's clock took
    against the planner's time (the streamer's, from the G-code, agreeing with the export's estimate), and the job's
    elapsed and remaining time; the report's streaming table has machine time and planned time per sheet and
    machine, and a job row with the stage's one wall time (the two machines cut in parallel)."""
    from fabline.jobs.report_shop import machine_seconds
    from fabline.units import duration

    data = json.loads((run["dir"] / "report.json").read_text())
    sheets = data["stream"]["sheets"]
    exported = {s["id"]: s["time_s"] for s in data["nesting"]["sheets"]}
    for k, sheet in enumerate(sheets):
        assert sheet["planned_s"] == pytest.approx(exported[sheet["sheet"]], rel=1e-3, abs=0.2)
        assert sheet["planned_done_s"] == sheet["planned_s"]
        assert sheet["planned_s"] <= sheet["machine_s"] + 0.2  # a host that lags only ever adds stops to the plan
        line = next(text for text in run["out"].splitlines() if text.startswith(f"stream: sheet {k + 1} of "))
        assert re.search(r"finished in \d+:\d\d:\d\d machine time \(planned \d+:\d\d:\d\d\), \d+\.\d s wall; "
                         r"job: elapsed \d+:\d\d:\d\d, remaining \d+:\d\d:\d\d$", line), line
    planned, taken = sum(s["planned_s"] for s in sheets), sum(machine_seconds(s) for s in sheets)
    assert (f"machine time (summed over the machines) planned {duration(planned)}, taken {duration(taken)}"
            in run["out"])
    html = (run["dir"] / "report.html").read_text()
    stream = html[html.index("<table id=stream>"):html.index("</table>", html.index("<table id=stream>"))]
    assert "<th>machine time</th><th>planned</th><th>left (planned)</th><th>wall s</th>" in stream
    job = re.search(r"<tr class=total><th>job</th>(.*?)</tr>", stream)[1]
    assert f"<td>{duration(planned)}</td>" in job and f"<td>{duration(taken)}</td>" in job
    assert job.endswith(f"<td>{data['stream']['wall_s']:.1f}</td>")
    assert data["stream"]["wall_s"] < sum(s["seconds"] for s in sheets)  # two machines at once


def test_report_links_its_large_pictures_and_stays_small(run):
    """The page holds the model and the sheet pictures (its parts labelled, at most 1.5 kB a part), tables and text,
    but no copy of the cut-order previews or the deviation map (which alone were 0.48 MB of this job's 0.59 MB page;
    the pavilion's page was 18.9 MB, 15.7 MB of it previews)."""
    html = (run["dir"] / "report.html").read_bytes()
    parts = load_parts(run["dir"] / "parts.json").parts
    pictures = re.findall(rb"<svg.*?</svg>", html, re.S)
    model, sheets = len(pictures[0]), sum(len(p) for p in pictures[1:])
    assert sheets <= 1500 * len(parts), (sheets, len(parts))
    assert len(html) - model - sheets < 40_000, "tables and text"
    linked = sum(p.stat().st_size for p in (run["dir"] / "gcode").glob("*.order.svg"))
    assert linked + (run["dir"] / "survey" / "deviation_map.png").stat().st_size > len(html)
    assert len(html) < 150_000


def test_run_and_report_give_the_size_asked_and_the_size_built(run):
    """The design was asked for 1.5 x 1.5 m; its nodes, a whole number of spacings apart, span less: the run's model
    line, the report's summary and report.json give the network's bounding box in plan (worked out here from
    network.json)."""
    network = load_network(run["dir"] / "network.json")
    xy = np.vstack([np.array([n.xyz for n in network.nodes.values()])[:, :2]]
                   + [lam.curve[:, :2] for lam in network.lamellas])
    dx, dy = np.ptp(xy, axis=0) * {"m": 1.0, "mm": 1e-3}[network.units]
    assert dx < 1.5 - 0.2 and dy < 1.5 - 0.2
    line = f"asked 1.5 x 1.5 m, built {dx:.1f} x {dy:.1f} m"
    assert f"{len(network.nodes)} nodes, {line}\n" in run["out"]
    html = (run["dir"] / "report.html").read_text()
    summary = html[html.index("<table id=summary"):html.index("</table>", html.index("<table id=summary"))]
    assert f"<td>size in plan</td><td>{line}</td>" in summary
    extent = json.loads((run["dir"] / "report.json").read_text())["model"]["extent"]
    assert extent["plan_m"] == pytest.approx([dx, dy], abs=1e-3) and extent["asked_m"] == [1.5, 1.5]


@pytest.mark.parametrize("width", [1280, 390])
def test_report_fits_the_page_width_in_a_browser(run, width):
    """Headless Chromium lays the page out at a desktop's and a phone's width: nothing sticks out sideways (the page
    does not scroll; wide tables and a zoomed picture scroll inside their own box)."""
    with headless_chromium() as (_, browser):
        page = browser.new_page(viewport={"width": width, "height": 900})
        page.goto((run["dir"] / "report.html").as_uri(), wait_until="load")
        scroll = page.evaluate("document.documentElement.scrollWidth")
        wide = page.evaluate("""() => [...document.querySelectorAll('body *')].filter(e =>
            e.getBoundingClientRect().right > innerWidth + 1 && !e.parentElement.closest('table, .zoom'))
            .map(e => e.tagName + (e.id ? '#' + e.id : ''))""")
    assert scroll <= width and not wide, (scroll, wide[:10])

