"""The prompt to load a sheet (issue 20) names the sheet, its size, material, thickness and part count and shows
its picture: in `fabline run` at a real machine (a socket:// controller fabline cannot see into) and in the
runner page's "load sheet" card, checked against the nesting and the job file."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path
from urllib.parse import unquote, urlsplit

import pytest

from fabline.jobs.queue import JobQueue, describe_load
from fabline.jobs.runner import MachineConfig, Runner
from fabline.link import SimulatorServer
from runner_support import TOKEN, headless_chromium, page_server, square_program
from .test_jobs_run_safety import write_job


def test_run_at_a_real_machine_names_each_sheet_to_load_with_its_size_material_thickness_parts_and_picture(tmp_path):
    with SimulatorServer(log=tmp_path / "executed.log", time_scale=1000.0, machine="grbl-laser") as simulator:
        job = write_job(tmp_path, simulator.url)
        run = subprocess.run([sys.executable, "-m", "fabline", "run", job, "--quiet"], input="\n" * 20,
                             capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    nesting = json.loads((tmp_path / "out" / "nesting.json").read_text())
    # each prompt line follows the previous question ("load sheet S001 on the machine, then press Enter ")
    prompts = re.findall(r"load sheet (\d+) of (\d+): (\S+) \((.*)\)\n  picture: (\S+)\n", run.stdout)
    assert len(prompts) == len(nesting["sheets"]) > 0
    for k, (number, count, name, facts, uri) in enumerate(prompts):
        sheet = nesting["sheets"][k]
        assert (int(number), int(count), name) == (k + 1, len(nesting["sheets"]), sheet["id"])
        # the job file: a 1200x500 sheet, the default lamella (stainless, 100 x 1.5 mm)
        assert facts == f"1200 x 500 mm, stainless 1.5 mm thick, {len(sheet['placements'])} parts"
        picture = Path(unquote(urlsplit(uri).path))
        assert uri.startswith("file://") and picture.parent == (tmp_path / "out" / "sheets").resolve()
        assert picture.read_text().lstrip().startswith("<svg") and sheet["id"] in picture.stem


def test_the_load_line_says_only_what_is_known():
    assert describe_load("S03", 2, 17, {"width_mm": 4000.0, "height_mm": 2000.0, "material": "stainless",
                                        "thickness_mm": 1.5, "parts": 98}) == \
        "sheet 3 of 17: S03 (4000 x 2000 mm, stainless 1.5 mm thick, 98 parts)"
    assert describe_load("plate", 0, 1, {}) == "sheet 1 of 1: plate"  # programs submitted alone: only the name


@pytest.fixture
def waiting(tmp_path):
    """A one-sheet job with its load facts, waiting for the operator on a simulated machine; the page served."""
    db = tmp_path / "runner.sqlite"
    queue = JobQueue(db)
    program = square_program(tmp_path / "S01.gcode", 30, 30, squares=4)
    facts = {"width_mm": 1200.0, "height_mm": 500.0, "material": "stainless", "thickness_mm": 1.5, "parts": 4,
             "picture": ""}
    job_id = queue.submit("load-job", programs=[("S01", str(program), "", facts)])
    runner = Runner(db, [MachineConfig("m1", "sim://load-m1?time_scale=50&settings=32:1")], poll=0.05, prepare=False)
    runner.start()
    with page_server(db) as url:
        yield {"url": url, "queue": queue, "job": job_id}
    runner.stop()


def test_the_runner_page_shows_a_load_card_with_the_facts_the_picture_and_the_confirm_button(waiting):
    job, queue = waiting["job"], waiting["queue"]
    with headless_chromium() as (sync_api, browser):
        page = browser.new_page(viewport={"width": 390, "height": 844})  # a phone at the machine
        page.goto(f"{waiting['url']}/?token={TOKEN}")
        card = page.locator(".machine .load-card")
        sync_api.expect(card).to_be_visible(timeout=20000)
        sync_api.expect(card).to_contain_text("Load sheet S01 for job")
        sync_api.expect(card.locator(".load-facts")).to_have_text(
            "sheet 1 of 1: S01 (1200 x 500 mm, stainless 1.5 mm thick, 4 parts)")
        page.wait_for_function("() => { const i = document.querySelector('.machine .load-card img');"
                               " return i && i.complete && i.naturalWidth > 0; }", timeout=20000)
        assert page.locator(".machine .picture-slot").is_hidden(), "the picture is shown once, in the card"
        confirm = page.locator(f".machine button.confirm[data-job='{job}']")
        sync_api.expect(confirm).to_be_visible()
        assert page.evaluate("() => { const c = document.querySelector('.machine .load-card').getBoundingClientRect();"
                             " const b = document.querySelector('.machine button.confirm').getBoundingClientRect();"
                             " return b.top >= c.bottom - 1 && b.top - c.bottom < 40; }"), "the button right below the card"
        confirm.click()
        sync_api.expect(card).to_be_hidden(timeout=20000)
        sync_api.expect(page.locator(f"#queue tr[data-job='{job}']")).to_have_attribute("data-state", "done",
                                                                                       timeout=60000)
    assert queue.job(job).state == "done"
