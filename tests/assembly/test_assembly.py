"""The assembly plan against truths of its own: the network's geometry, graph connectivity (scipy), the parts."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from fabline.assembly import plan_assembly
from fabline.assembly.pdf import PDF
from fabline.assembly.sheets import OVERVIEW, page_name, write_pages
from fabline.errors import FablineError
from fabline.jobs.jobfile import load_job_file
from fabline.model import save_network
from fabline.model.designs import enneper_network
from fabline.unroll import UnrollOptions, save_parts, unroll_network
from jobfiles import write

SVG = "{http://www.w3.org/2000/svg}"


@pytest.fixture(scope="module")
def small():
    """A 3 x 4 m Enneper patch, paired lamellas with seams (1.2 m sheets), unrolled."""
    network = enneper_network(size=(3.0, 4.0), spacing=0.35)
    parts = unroll_network(network, UnrollOptions(sheet_length=1200.0))
    return network, parts


def components(nodes: list[str], network) -> int:
    """Connected components of the nodes with the lamella intervals between them (scipy, not the plan's networkx)."""
    index = {n: k for k, n in enumerate(nodes)}
    rows, cols = [], []
    for lam in network.lamellas:
        for a, b in zip(lam.nodes[:-1], lam.nodes[1:]):
            if a in index and b in index:
                rows.append(index[a])
                cols.append(index[b])
    matrix = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(len(nodes), len(nodes)))
    return connected_components(matrix, directed=False)[0]


@pytest.mark.parametrize("asked", [{"count": 1}, {"count": 4}, {"count": 9}, {"max_size_mm": 1500.0}])
def test_segments_cover_every_node_once_and_each_is_connected(small, asked):
    network, parts = small
    plan = plan_assembly(network, parts, **asked)
    every = [n for seg in plan.segments for n in seg]
    assert sorted(every) == sorted(network.nodes) and len(every) == len(set(every))
    assert all(components(seg, network) == 1 for seg in plan.segments)
    if "count" in asked:
        assert len(plan.segments) == asked["count"]
    else:
        mm = network.mm_per_unit
        for seg in plan.segments:
            xyz = np.array([network.nodes[n].xyz for n in seg]) * mm
            assert np.ptp(xyz, axis=0).max() <= 1500.0
    again = plan_assembly(network, parts, **asked)
    assert again.segments == plan.segments  # deterministic


def test_site_joints_are_where_pieces_of_two_segments_meet(small):
    network, parts = small
    plan = plan_assembly(network, parts, count=4)
    home = {p.id: p.home for p in plan.pieces}
    through: dict[str, set[int]] = {}
    for part in parts.parts:
        if part.kind == "strip":
            for slot in part.slots:
                through.setdefault(slot.node, set()).add(home[part.id])
    on_site = {c["node"] for c in plan.crossings}
    assert plan.seams and any(p.seams for p in plan.pieces)
    assert on_site == {n for n, homes in through.items() if len(homes) > 1} and on_site
    for seam in plan.seams:
        assert home[seam["pieces"][0]] != home[seam["pieces"][1]]
    assert plan_assembly(network, parts, count=1).crossings == []


def test_every_piece_goes_in_once_and_the_first_family_before_the_second(small):
    network, parts = small
    plan = plan_assembly(network, parts, count=4)
    listed = [piece for steps in plan.steps.values() for step in steps for piece in step["pieces"]]
    assert sorted(listed) == sorted(p.id for p in plan.pieces) and len(listed) == len(set(listed))
    first = plan.families[0]
    edges = {p.family: p.slot_edge for p in plan.pieces}
    assert edges[first] == "top"  # the family whose slots open upward is laid first
    for steps in plan.steps.values():
        families = [step["family"] for step in steps]
        assert families == sorted(families, key=plan.families.index)
        assert [step["step"] for step in steps] == list(range(1, len(steps) + 1))


def test_one_page_per_lamella_and_each_slot_names_the_lamella_that_crosses_there(small, tmp_path):
    """The crossing lamellas are found from the geometry: the lamellas whose centreline passes within 1 mm of the
    slot's node, not the plan's node bookkeeping."""
    network, parts = small
    plan = plan_assembly(network, parts, count=4)
    paths = write_pages(plan, tmp_path / "pages")
    assert {p.name for p in paths} == {OVERVIEW} | {page_name(lam.id) for lam in network.lamellas}
    assert len(paths) == len(network.lamellas) + 1
    mm = network.mm_per_unit
    curves = {lam.id: np.asarray(lam.curve) * mm for lam in network.lamellas}

    def near(point: np.ndarray) -> set[str]:
        found = set()
        for lam, curve in curves.items():
            a, b = curve[:-1], curve[1:]
            t = np.clip(np.einsum("ij,ij->i", point - a, b - a) / np.einsum("ij,ij->i", b - a, b - a), 0, 1)
            if np.min(np.linalg.norm(a + t[:, None] * (b - a) - point, axis=1)) < 1.0:
                found.add(lam)
        return found

    slots_in_parts = {(p.id, s.node) for p in parts.parts if p.kind == "strip" for s in p.slots}
    seen = set()
    for lam in network.lamellas:
        root = ET.parse(tmp_path / "pages" / page_name(lam.id)).getroot()
        assert root.get("width") == "420mm" and root.get("height") == "297mm"
        for group in root.iter(f"{SVG}g"):
            if group.get("class") != "slot":
                continue
            node, crossing = group.get("data-node"), set(group.get("data-crossing").split())
            assert crossing and crossing == near(np.asarray(network.nodes[node].xyz) * mm) - {lam.id}, (lam.id, node)
            text = "".join(group.itertext())
            assert all(other in text for other in crossing) and node in text
            seen.add((group.get("data-piece"), node))
        pieces = {g.get("data-piece"): float(g.get("data-length")) for g in root.iter(f"{SVG}g")
                  if g.get("class") == "piece"}
        strips = {p.id: p for p in parts.parts if p.kind == "strip" and p.lamella == lam.id}
        assert set(pieces) == set(strips)
        for pid, length in pieces.items():
            assert length == pytest.approx(np.ptp(strips[pid].outline[:, 0]), abs=0.06)
    assert seen == slots_in_parts


def test_the_pdf_holds_every_page_on_a3_with_the_labels_its_svg_page_holds(small, tmp_path):
    """Read back with pypdf (not the writer): a page per lamella and the overview, each 420 x 297 mm, and each
    lamella page's text names the lamella and every crossing lamella and node its SVG page labels at a slot."""
    pypdf = pytest.importorskip("pypdf", reason="pypdf (the test extra) reads the PDF back")
    network, parts = small
    plan = plan_assembly(network, parts, count=4)
    paths = write_pages(plan, tmp_path)
    reader = pypdf.PdfReader(tmp_path / PDF)
    assert len(reader.pages) == len(network.lamellas) + 1 == len(paths)
    points_per_mm = 72.0 / 25.4
    for page in reader.pages:
        assert (float(page.mediabox.width), float(page.mediabox.height)) == pytest.approx(
            (420.0 * points_per_mm, 297.0 * points_per_mm), abs=0.5)
    assert f"assembly in {len(plan.segments)} segments" in reader.pages[0].extract_text()
    checked = 0
    for path, page in zip(paths[1:], reader.pages[1:]):
        text = page.extract_text()
        root = ET.parse(path).getroot()
        lamella = path.stem.removeprefix("lamella-")
        assert f"Lamella {lamella}" in text
        for group in root.iter(f"{SVG}g"):
            if group.get("class") == "slot":
                words = set(group.get("data-crossing").split()) | {group.get("data-node")}
                assert all(word in text for word in words), (lamella, words)
                checked += 1
    assert checked == len({(p.id, s.node) for p in parts.parts if p.kind == "strip" for s in p.slots})


def test_a_name_outside_latin_1_prints_as_question_marks_not_a_crash(tmp_path):
    pypdf = pytest.importorskip("pypdf", reason="pypdf (the test extra) reads the PDF back")
    from fabline.assembly.pdf import write_pdf

    svg = ('<svg xmlns="http://www.w3.org/2000/svg" width="420mm" height="297mm" viewBox="0 0 420 297">'
           '<text x="10" y="20" font-size="6">Pavillon \u2013 Z\u00fcrich \u6771</text></svg>')
    write_pdf([svg], tmp_path / PDF, (420.0, 297.0))
    assert pypdf.PdfReader(tmp_path / PDF).pages[0].extract_text().strip() == "Pavillon ? Z\u00fcrich ?"


def test_overview_numbers_every_segment(small, tmp_path):
    network, parts = small
    plan = plan_assembly(network, parts, count=4)
    write_pages(plan, tmp_path)
    root = ET.parse(tmp_path / OVERVIEW).getroot()
    numbers = [g.get("data-segment") for g in root.iter(f"{SVG}g") if g.get("class") == "segment"]
    assert numbers == ["1", "2", "3", "4"]


@pytest.mark.parametrize("table, message", [
    ("segments = 0", "assembly.segments: must be 1 to 1000, got 0"),
    ('max_segment = "-2 m"', "assembly.max_segment: must be a positive length"),
    ('segments = 3\nmax_segment = "4 m"', "assembly: give assembly.segments (how many) or assembly.max_segment"),
    ("segment = 3", "assembly.segment: unknown key (allowed: segments, max_segment)"),
    ('max_segment = "4 parsecs"', "assembly.max_segment: unknown unit 'parsecs'"),
    ('segments = "nine"', "assembly.segments: expected an integer, got string 'nine'"),
])
def test_bad_assembly_keys_are_one_line_naming_file_and_key(tmp_path, table, message):
    job = write(tmp_path, 'stages = ["unroll", "assembly"]\n' + GOOD_JOB + f"[assembly]\n{table}\n")
    with pytest.raises(FablineError) as error:
        load_job_file(job)
    text = str(error.value)
    assert text.startswith("job.toml: ") and message in text and "\n" not in text


def test_assembly_keys_need_the_stage_and_the_stage_needs_unroll(tmp_path):
    with pytest.raises(FablineError, match="assembly.segments: only with 'assembly' in stages"):
        load_job_file(write(tmp_path, GOOD_JOB + "[assembly]\nsegments = 2\n"))
    with pytest.raises(FablineError, match="'assembly' needs 'unroll'"):
        load_job_file(write(tmp_path, 'stages = ["assembly"]\n' + GOOD_JOB))
    spec = load_job_file(write(tmp_path, 'stages = ["unroll", "assembly"]\n' + GOOD_JOB))
    assert spec.assembly == {"segments": None, "max_segment": 5000.0}
    spec = load_job_file(write(tmp_path, 'stages = ["unroll", "assembly"]\n' + GOOD_JOB + '[assembly]\nmax_segment = "2.5 m"\n'))
    assert spec.assembly == {"segments": None, "max_segment": 2500.0}


GOOD_JOB = """name = "small"
[model]
design = "enneper"
[model.options]
size = [2.0, 2.5]
spacing = 0.35
[output]
folder = "out"
"""


def test_a_small_job_writes_the_pages_and_the_report_section(tmp_path, cli):
    job = write(tmp_path, 'stages = ["unroll", "assembly", "report"]\n' + GOOD_JOB + "[assembly]\nsegments = 3\n")
    code, out, err = cli("run", job)
    assert code == 0, err
    assert "assembly: 3 segments" in out
    network = json.loads((tmp_path / "out" / "network.json").read_text())
    lamellas = [lam["id"] for lam in network["lamellas"]]
    pages = sorted(p.name for p in (tmp_path / "out" / "assembly").iterdir())
    assert pages == sorted([OVERVIEW, PDF] + [page_name(lam) for lam in lamellas])
    page = (tmp_path / "out" / "report.html").read_text()
    section = page[page.index("<h2 id=assembly>"):]
    assert section.count("<tr><td>") == 3
    for lam in lamellas:
        assert f'href="assembly/{page_name(lam)}"' in section
    assert f'href="assembly/{PDF}"' in section
    data = json.loads((tmp_path / "out" / "report.json").read_text())
    assert len(data["assembly"]["segments"]) == 3
    assert sum(row["nodes"] for row in data["assembly"]["segments"]) == len(network["nodes"])


def test_the_command_writes_pages_and_refuses_mistakes_in_one_line(small, tmp_path, cli):
    network, parts = small
    model, parts_file = tmp_path / "small.network.json", tmp_path / "parts.json"
    save_network(network, model)
    save_parts(parts, parts_file)
    code, out, err = cli("assembly", parts_file, "-o", tmp_path / "plan", "--model", model, "--segments", "2")
    assert code == 0, err
    written = json.loads((tmp_path / "plan" / "assembly.json").read_text())
    assert written["schema"] == "fabline.assembly/1" and len(written["segments"]) == 2
    assert len(written["pages"]) == len(network.lamellas) + 1 and "2 segments" in out
    code, out, err = cli("assembly", parts_file, "-o", tmp_path / "plan2", "--model", model, "--max-segment", "1.5m")
    assert code == 0, err
    sizes = [row["extent_mm"] for row in json.loads((tmp_path / "plan2" / "assembly.json").read_text())["segments"]]
    assert max(sizes) <= 1500.0
    for args, message in ((("--segments", "0"), "--segments: must be a positive whole number"),
                          (("--max-segment", "4 parsecs"), "--max-segment"),
                          (("--segments", "100000"), "--segments")):
        code, _, err = cli("assembly", parts_file, "-o", tmp_path / "bad", "--model", model, *args)
        assert code == 2 and message in err and len(err.strip().splitlines()) == 1 and not (tmp_path / "bad").exists()
    code, _, err = cli("assembly", parts_file, "-o", tmp_path / "bad", "--segments", "2")  # the parts name no file
    assert code == 2 and "give --model" in err and len(err.strip().splitlines()) == 1
    code, _, err = cli("assembly", parts_file, "-o", tmp_path / "bad", "--model", model, "--segments", "999")
    assert code == 2 and f"999 segments for {len(network.nodes)} nodes" in err
