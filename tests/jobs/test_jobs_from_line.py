"""`fabline run`'s refusals name only options `fabline run` has (issue 25 item 7): a run killed (kill -9) where its
journal cannot tell where the sheet stopped was told to "resume with --from-line", which only `fabline stream` took.
`fabline run JOB --resume --from-line N` now continues the one interrupted sheet from file line N."""

from __future__ import annotations

import re

from fabline.link import executed_file_lines, read_journal
from fabline.link.journal import Journal
from fabline.machine import load_program

JOB = """
name = "lines"
stages = ["unroll", "nest", "export", "stream"]
[model]
design = "enneper"
[model.options]
size = [1.5, 1.5]
spacing = 0.5
[stock]
sheet = "1200x500"
[machine]
time_scale = 1000.0
port = "sim://from-line?log={log}"
[output]
folder = "out"
"""


def test_a_refusal_to_resume_names_an_option_fabline_run_has_and_it_continues_there(tmp_path, cli):
    log = tmp_path / "out" / "executed.log"
    job = tmp_path / "lines.toml"
    job.write_text(JOB.format(log=log), encoding="utf-8")
    code, _, err = cli("run", job, "-q")
    assert code == 0, err
    program = sorted((tmp_path / "out" / "gcode").glob("*.gcode"))[0]
    loaded = load_program(program)
    half = len(loaded.lines) // 2
    journal = program.with_name(f"{program.name}.journal")
    identity = read_journal(journal).identity  # the run's: {job, run}
    journal.unlink()
    with Journal(journal) as record:  # what an older fabline left when killed: no origin, so no position to go by
        record.record("start", program=str(program), sha256=loaded.sha256, lines=len(loaded.lines), mode="counting",
                      identity=identity)
        record.record("done", count=half)
    code, out, err = cli("run", job, "--resume", "-q")
    assert code == 2 and "--from-line" in err, err
    _, usage, _ = cli("run", "--help")
    for option in set(re.findall(r"--[a-z][a-z-]+", err)):
        assert re.search(rf"(^|\s){option}\b", usage), f"{option} named but not an option of fabline run"
    log.unlink()
    start = loaded.lines[half].file_line
    code, _, err = cli("run", job, "--resume", "--from-line", start, "-q")
    assert code == 0, err
    assert read_journal(journal).finished
    assert executed_file_lines(log) == [line.file_line for line in loaded.lines[half:]], "the rest, once each"


def test_from_line_needs_resume_and_one_interrupted_sheet(tmp_path, cli):
    job = tmp_path / "lines.toml"
    job.write_text(JOB.format(log=tmp_path / "out" / "executed.log"), encoding="utf-8")
    code, _, err = cli("run", job, "--from-line", "5")
    assert code == 2 and err.strip() == "fabline run: error: --from-line needs --resume (it names where the " \
        "interrupted sheet continues)", err
    code, _, err = cli("run", job, "--resume", "--from-line", "5")
    assert code == 2 and "no sheet was interrupted" in err and err.count("\n") == 1, err
