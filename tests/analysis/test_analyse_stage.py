"""The job's `analyse` stage on a small design: analysis.json as `fabline analyse` writes it, the report's section with
its table, both plan pictures (parsed as SVG) and the reactions table."""

from __future__ import annotations

import json
import re
import xml.etree.ElementTree as ET

import pytest

from fabline.jobs.pipeline import prepare_job
from jobfiles import GOOD, write

JOB = GOOD.replace('name = "small"', 'name = "small"\nstages = ["unroll", "analyse", "report"]') + """
[analysis]
snow = "900 N/m2"
person = "1.2 kN"
stations = 1
supports = "fixed"   # the small design has two support nodes: pinned, it would turn about the line through them
buckling = false
"""
SVG = "{http://www.w3.org/2000/svg}"


@pytest.fixture(scope="module")
def analysed(tmp_path_factory):
    folder = tmp_path_factory.mktemp("stage")
    lines: list[str] = []
    result = prepare_job(write(folder, JOB), say=lines.append)
    return folder / "out", result, lines


def test_the_stage_writes_the_record_and_says_each_case(analysed):
    out, result, lines = analysed
    record = json.loads((out / "analysis.json").read_text())
    assert record["schema"] == "fabline.analysis/1" and "buckling" not in record
    assert record["loads"]["snow"] == pytest.approx(0.9) and record["loads"]["person"] == pytest.approx(1200.0)
    assert record["model"]["stations"] == 1
    assert record["parts_file"] == str(out / "parts.json")
    for name, case in record["cases"].items():
        line = next(line for line in lines if line.startswith(f"analyse: {name} "))
        assert f"{case['max_deflection_mm']:.2f} mm" in line and f"{case['max_reaction_kN']:.3f} kN" in line
        # every beam's strip is in the per-strip utilisation, whose largest is the case's
        assert max(case["utilisation_by_strip"].values()) == pytest.approx(case["max_utilisation"])
        assert case["max_utilisation_at"].split(" beam ")[0] in case["utilisation_by_strip"]
    assert len(record["cases"]) == 7 and "analyse" in result.timings


def _figure_svg(page: str, figure: str) -> ET.Element:
    found = re.search(rf"<figure id={figure}>(<svg.*?</svg>)", page, re.S)
    assert found, figure
    return ET.fromstring(found.group(1))


def test_the_report_shows_the_cases_both_pictures_and_the_reactions(analysed):
    out, result, _ = analysed
    record = result.analysis
    page = (out / "report.html").read_text()
    table = re.search(r"<table id=analysis-cases>(.*?)</table>", page, re.S).group(1)
    assert table.count("<tr") == 1 + len(record["cases"])
    cases = record["cases"]
    pool = [n for n, c in cases.items() if c["converged"]] or list(cases)
    moved = max(pool, key=lambda n: cases[n]["max_deflection_mm"])
    used = max(pool, key=lambda n: cases[n]["max_utilisation"])
    deflection = _figure_svg(page, "analysis-deflection")
    dots = {c.get("data-node"): float(c.get("data-value")) for c in deflection.iter(f"{SVG}circle")}
    assert dots == pytest.approx(cases[moved]["deflections_mm"], abs=1e-6)
    assert float(deflection.get("data-max")) == pytest.approx(cases[moved]["max_deflection_mm"])
    assert deflection.find(f"{SVG}rect[@class='scale']") is not None
    utilisation = _figure_svg(page, "analysis-utilisation")
    assert float(utilisation.get("data-max")) == pytest.approx(100 * cases[used]["max_utilisation"])
    coloured = [p for p in utilisation.iter(f"{SVG}polyline") if p.get("stroke") != "#bbb"]
    assert len(coloured) == len(result.network.lamellas)  # every lamella's strips were analysed
    reactions = re.search(r"<table id=analysis-reactions>(.*?)</table>", page, re.S).group(1)
    assert reactions.count("<tr") == 1 + record["model"]["supports"] + 1  # head, each support, the sum
    report = json.loads((out / "report.json").read_text())
    assert report["analysis"]["cases"][moved]["max_deflection_mm"] == cases[moved]["max_deflection_mm"]
