"""Ids become file names only through `fabline.naming.file_stem`: hostile ids stay inside the output folder, and
distinct ids never share a file (issue 25: a lamella id `../../../outside/TRAV` wrote its previews outside)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from fabline.model import save_network
from fabline.naming import MAX_STEM, file_stem
from networks import network_of

HOSTILE = ["../../../outside/TRAV", "/etc/passwd", "/", "..", ".", "", "a/b", "a\\b", "a b", "a:b", "a\0b", "C:\\x",
           "..\\..\\up", "~/home", "-rf", ".hidden", "trailing.", "CON", "nul", "Com1", "LPT9.txt", "aux.svg",
           "x" * 10_000, "é" * 300, "Träger-Ω-1", "日本語", "😀", "\n", "a\tb", "a*b?c", "<>|\"", "a~b", "%2e%2e",
           "\udcff"]


@pytest.mark.parametrize("item_id", HOSTILE)
def test_a_hostile_id_becomes_one_safe_name_inside_its_folder(tmp_path, item_id):
    stem = file_stem(item_id)
    name = f"{stem}.svg"
    assert set(stem) <= set("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789._-~"), stem
    assert stem and not stem.startswith((".", "-")) and len(stem) <= MAX_STEM
    assert Path(name).name == name and os.path.dirname(os.path.join(tmp_path, name)) == str(tmp_path)
    assert stem.split(".")[0].upper() not in {"CON", "PRN", "AUX", "NUL", *(f"COM{k}" for k in range(10)),
                                              *(f"LPT{k}" for k in range(10))}
    (tmp_path / name).write_text("x")  # the file system takes it as one file in the folder
    assert [p.name for p in tmp_path.iterdir()] == [name]


def test_distinct_ids_give_distinct_names_and_safe_ids_are_kept():
    stems = [file_stem(i) for i in HOSTILE]
    assert len(set(stems)) == len(HOSTILE)
    assert file_stem("a b") != file_stem("a/b") != file_stem("a_b") == "a_b"  # alike once sanitised, apart as names
    assert file_stem("x" * 10_000) != file_stem("x" * 10_001)
    for kept in ("TRAV-L", "A-000", "S1", "sheet.2", "job_a-b"):
        assert file_stem(kept) == kept


def test_lamella_ids_that_name_other_folders_keep_the_previews_in_theirs(cli, tmp_path):
    """The probe's model: lamella ids with '..' and an absolute path; `fabline unroll --svg` writes every preview
    in the folder given and nothing anywhere else."""
    steps = np.linspace(0.0, 1.0, 41)
    outside = tmp_path / "outside"
    ids = ["../../../outside/TRAV", str(outside / "ABS"), "A/B", "A_B"]
    curves = []
    for k, lam_id in enumerate(ids):
        points = np.column_stack([steps * 1200.0, np.full_like(steps, 150.0 * k), np.zeros_like(steps)])
        curves.append((lam_id, "A", points, np.tile([0.0, 0.0, 1.0], (len(steps), 1)), [0, 20, 40]))
    for j in range(3):
        points = np.column_stack([np.full_like(steps, 600.0 * j), steps * 450.0, np.zeros_like(steps)])
        curves.append((f"B-{j}", "B", points, np.tile([0.0, 0.0, 1.0], (len(steps), 1)), [0, 13, 27, 40]))
    model = tmp_path / "work" / "deep" / "model.network.json"
    model.parent.mkdir(parents=True)
    save_network(network_of(curves, "hostile"), model)
    assert {lam["id"] for lam in json.loads(model.read_text())["lamellas"]} >= set(ids)
    previews = tmp_path / "work" / "deep" / "previews"
    code, _, stderr = cli("unroll", model, "-o", model.with_name("parts.json"), "--profile", "100x1.5",
                          "--material", "steel-s235", "--no-hardware", "--svg", previews)
    assert code == 0, stderr
    everything = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*") if p.is_file())
    assert not outside.exists() and all(p.parts[:3] == ("work", "deep", "previews") or p.parent == Path("work/deep")
                                        for p in everything), everything
    names = sorted(p.name for p in previews.iterdir())
    strips = json.loads(model.with_name("parts.json").read_text())["parts"]
    assert len(names) == len([p for p in strips if p["kind"] in ("strip", "curved-strip", "joint")]) >= len(ids) + 3
    assert sorted(f"{file_stem(p['id'])}.svg" for p in strips if p["kind"] in ("strip", "curved-strip", "joint")) == names


def test_a_job_in_the_runner_keeps_hostile_previews_in_its_own_folder(tmp_path):
    """The probe's runner case: a queued job whose model names lamellas `../../../outside/TRAV` and an absolute
    path, with unroll.previews, writes every file under `runs/job-N/`."""
    import time

    from fabline.jobs.queue import JobQueue
    from fabline.jobs.runner import MachineConfig, Runner

    outside = tmp_path / "outside"
    steps = np.linspace(0.0, 1.0, 41)
    curves = []
    for k, lam_id in enumerate(["../../../outside/TRAV", str(outside / "ABS")]):
        points = np.column_stack([steps * 1200.0, np.full_like(steps, 300.0 * k), np.zeros_like(steps)])
        curves.append((lam_id, "A", points, np.tile([0.0, 0.0, 1.0], (len(steps), 1)), [0, 20, 40]))
    for j in range(3):
        points = np.column_stack([np.full_like(steps, 600.0 * j), steps * 300.0, np.zeros_like(steps)])
        curves.append((f"B-{j}", "B", points, np.tile([0.0, 0.0, 1.0], (len(steps), 1)), [0, 40]))
    shop = tmp_path / "a" / "b" / "shop"
    shop.mkdir(parents=True)
    save_network(network_of(curves, "hostile"), shop / "hostile.network.json")
    job = shop / "hostile.toml"
    job.write_text('name = "hostile"\nstages = ["unroll", "nest", "export"]\n[model]\nfile = "hostile.network.json"\n'
                   '[unroll]\npreviews = true\n[output]\nfolder = "out"\n', encoding="utf-8")
    db = shop / "runner.sqlite"
    runner = Runner(db, [MachineConfig("m1", "sim://hostile-m1?time_scale=1000")], poll=0.05)
    queue = JobQueue(db)
    job_id = queue.submit("hostile", str(job))
    runner.start()
    try:
        deadline = time.monotonic() + 240
        while queue.job(job_id).state in ("queued", "preparing"):
            assert time.monotonic() < deadline, "timed out"
            time.sleep(0.1)
        assert queue.job(job_id).state == "ready", queue.job(job_id).describe()
    finally:
        runner.stop()
        queue.close()
    folder = shop / "runs" / f"job-{job_id}"
    previews = sorted(p.name for p in (folder / "previews").iterdir())
    assert f"{file_stem('../../../outside/TRAV-L')}.svg" in previews and len(previews) >= 5, previews
    strays = [p for p in tmp_path.rglob("*.svg") if folder not in p.parents]
    assert strays == [] and not outside.exists(), strays
