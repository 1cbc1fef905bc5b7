"""The runner never lets a journal of another job, run or program decide where cutting starts, and never resumes
by itself: a sheet cut off by a restart waits for the operator ("needs attention"), whose choice (resume here,
restart the sheet, skip it, cancel) is carried out exactly; in the queue, and in headless Chromium on the page."""

from __future__ import annotations

import re
import time

import pytest

from fabline.errors import FablineError
from fabline.jobs.queue import JobQueue
from fabline.jobs.runner import MachineConfig, Runner
from fabline.link import Streamer
from runner_support import TOKEN, executed_program_lines, headless_chromium, page_server, square_program, wire_lines


def wait(condition, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.02)


def start(db, port: str, **options) -> Runner:
    runner = Runner(db, [MachineConfig("m1", port)], poll=0.05, prepare=False, **options)
    runner.start()
    return runner


def interrupt(runner: Runner, queue: JobQueue, job_id: int, k: int, port: str, auto_confirm: bool = True) -> Runner:
    """Stop the runner while sheet k is being cut (a restart of the runner: feed hold, reset), start a new one."""
    wait(lambda: queue.job(job_id).sheet == k and queue.sheets(job_id)[k].done_lines >= 4)
    runner.stop()
    return start(queue.path, port, auto_confirm=auto_confirm)


def squares_job(tmp_path, name: str, sheets: int):
    """A job of `sheets` sheets of ten squares each, queued ready, and a simulated laser's port logging to
    m1.log: (queue, job id, programs, log, port)."""
    programs = [square_program(tmp_path / f"{name}{k + 1}.gcode", 10, 10 + 20 * k, squares=10, closed=False)
                for k in range(sheets)]  # open squares: a runner stopped anywhere knows which line the machine was in
    queue = JobQueue(tmp_path / "runner.sqlite")
    job_id = queue.submit(name, programs=[(p.stem, str(p), "") for p in programs])
    log = tmp_path / "m1.log"
    return queue, job_id, programs, log, f"sim://{name}?settings=32:1&time_scale=4&log={log}"


def test_a_program_finished_elsewhere_is_cut_again_in_full_by_a_new_job(tmp_path):
    program = square_program(tmp_path / "sheet.gcode", 10, 10, squares=3)
    before = tmp_path / "before.log"
    Streamer(f"sim://elsewhere?settings=32:1&time_scale=50&log={before}").run(program)  # `fabline stream`: journal beside it, finished
    assert (tmp_path / "sheet.gcode.journal").is_file()
    db = tmp_path / "q.sqlite"
    queue = JobQueue(db)
    job_id = queue.submit("again", programs=[("S1", str(program), "")])
    log = tmp_path / "runner.log"
    runner = start(db, f"sim://again?settings=32:1&time_scale=50&log={log}", auto_confirm=True)
    try:
        runner.run_until_idle(60)
    finally:
        runner.stop()
    assert queue.job(job_id).state == "done"
    assert executed_program_lines(log) == wire_lines(program), "every line cut, none taken as done from the old journal"


def test_a_cancelled_job_resubmitted_starts_at_its_first_line(tmp_path):
    program = square_program(tmp_path / "sheet.gcode", 10, 10, squares=8)
    db = tmp_path / "q.sqlite"
    queue = JobQueue(db)
    log = tmp_path / "m1.log"
    runner = start(db, f"sim://resubmit?settings=32:1&time_scale=4&log={log}", auto_confirm=True)
    try:
        first = queue.submit("first", programs=[("S1", str(program), "")])
        wait(lambda: queue.sheets(first)[0].done_lines >= 6)
        queue.request(first, "cancel")
        wait(lambda: queue.job(first).state == "cancelled")
        cut = len(executed_program_lines(log))
        second = queue.submit("second", programs=[("S1", str(program), "")])
        wait(lambda: queue.job(second).state == "done")
    finally:
        runner.stop()
    lines = wire_lines(program)
    assert 0 < cut < len(lines)
    assert executed_program_lines(log) == lines[:cut] + lines, "the new job cut its sheet from the first line"
    assert queue.sheets(first)[0].journal != queue.sheets(second)[0].journal


def test_a_restarted_runner_waits_for_the_operator_and_carries_out_each_choice(tmp_path):
    queue, job_id, sheets, log, port = squares_job(tmp_path, "choices", 3)
    runner = start(queue.path, port, auto_confirm=True)
    try:
        # Sheet 1: cut off by a restart, waits, then "resume here": each line once.
        runner = interrupt(runner, queue, job_id, 0, port)
        job = queue.job(job_id)
        assert job.state == "attention", job.describe()
        checkpoint = job.checkpoint()
        assert checkpoint["reason"] == "the runner stopped while the sheet was being cut"
        assert 4 <= checkpoint["done"] < checkpoint["lines"] == len(wire_lines(sheets[0]))
        assert checkpoint["file_line"] == checkpoint["done"]  # the squares program has one command per file line
        assert len(checkpoint["position"]) == 3
        held = len(executed_program_lines(log))
        time.sleep(0.6)
        assert len(executed_program_lines(log)) == held and queue.job(job_id).state == "attention", "moved by itself"
        assert held == checkpoint["done"], "the journal knows every executed line"
        assert "needs attention: sheet 1 of 3 stopped after file line" in job.describe()
        with pytest.raises(FablineError, match="choose one of: resume, restart, skip, cancel"):
            queue.request(job_id, "pause")
        queue.resolve(job_id, "resume")
        wait(lambda: queue.job(job_id).sheet == 1)
        # Sheet 2: cut off again, then "restart the sheet": a new run cuts it from its first line.
        runner = interrupt(runner, queue, job_id, 1, port)
        cut = len(executed_program_lines(log)) - len(wire_lines(sheets[0]))
        journal = queue.sheets(job_id)[1].journal
        queue.resolve(job_id, "restart")
        assert queue.sheets(job_id)[1].journal != journal, "a restart is a new run with a journal of its own"
        wait(lambda: queue.job(job_id).sheet == 2)
        # Sheet 3: cut off, then skipped: the job is done, saying so.
        runner = interrupt(runner, queue, job_id, 2, port)
        skipped_at = len(executed_program_lines(log))
        assert queue.resolve(job_id, "skip").state == "done"
        time.sleep(0.3)
        assert len(executed_program_lines(log)) == skipped_at
        assert queue.snapshot()["jobs"][0]["status"] == "done (1 sheet(s) skipped)"
    finally:
        runner.stop()
    first, second, third = (wire_lines(p) for p in sheets)
    executed = executed_program_lines(log)
    assert executed[:len(first)] == first
    assert executed[len(first):len(first) + cut + len(second)] == second[:cut] + second
    rest = executed[len(first) + cut + len(second):]
    assert 0 < len(rest) < len(third) and rest == third[:len(rest)]


def test_choices_are_only_for_a_job_that_needs_attention(tmp_path):
    queue = JobQueue(tmp_path / "q.sqlite")
    job_id = queue.submit("j", programs=[("S1", str(square_program(tmp_path / "p.gcode", 1, 1)), "")])
    for choice in ("restart", "skip"):
        with pytest.raises(FablineError, match=rf"job {job_id}: does not need attention \(ready: sheet 1 of 1"):
            queue.resolve(job_id, choice)
    with pytest.raises(FablineError, match="unknown choice 'rewind'"):
        queue.resolve(job_id, "rewind")
    with pytest.raises(FablineError, match="a start line goes with resume"):
        queue.resolve(job_id, "restart", from_line=3)


def test_the_cli_asks_before_acting_on_a_job_that_needs_attention_and_refuses_without_a_terminal(tmp_path, cli,
                                                                                                   monkeypatch):
    import io

    db = tmp_path / "q.sqlite"
    queue = JobQueue(db)
    job_id = queue.submit("j", programs=[("S1", str(square_program(tmp_path / "p.gcode", 1, 1)), "")])
    queue.claim_for_machine("m1")
    queue.confirm_sheet(job_id)
    queue.start_sheet(job_id, "m1")
    queue.need_attention(job_id, {"reason": "ALARM:1 hard limit", "done": 3, "lines": 12, "file_line": 3})
    monkeypatch.setattr("sys.stdin", io.StringIO(""))
    code, out, err = cli("runner", "skip", str(job_id), "--db", db)
    assert code == 2 and err.strip().endswith(f"job {job_id}: cannot ask for confirmation (standard input closed); add --yes")
    monkeypatch.setattr("sys.stdin", io.StringIO("n\n"))
    code, out, _ = cli("runner", "skip", str(job_id), "--db", db)
    assert code == 1 and "stopped after file line 3: ALARM:1 hard limit" in out and out.strip().endswith("nothing done")
    assert queue.job(job_id).state == "attention"
    monkeypatch.setattr("sys.stdin", io.StringIO("y\n"))
    code, out, _ = cli("runner", "resume", str(job_id), "--from-line", "2", "--db", db)
    assert code == 0 and queue.job(job_id).state == "cutting"
    assert queue.sheets(job_id)[0].resume == 1 and queue.sheets(job_id)[0].from_line == 2


@pytest.fixture
def attention_page(tmp_path):
    """A 2-sheet job whose first sheet a runner restart cut off, the new runner and the page on 127.0.0.1."""
    queue, job_id, sheets, log, port = squares_job(tmp_path, "page", 2)
    runner = interrupt(start(queue.path, port, auto_confirm=True), queue, job_id, 0, port, auto_confirm=False)
    with page_server(queue.path) as url:
        yield {"url": url, "queue": queue, "job": job_id, "sheets": sheets, "log": log}
    runner.stop()


def test_page_in_headless_chromium_shows_where_the_sheet_stopped_and_resumes_after_confirmation(attention_page):
    job, queue, log = attention_page["job"], attention_page["queue"], attention_page["log"]
    checkpoint = queue.job(job).checkpoint()
    with headless_chromium() as (sync_api, browser):
        page = browser.new_page()
        page.goto(f"{attention_page['url']}/?token={TOKEN}")
        row = page.locator(f"#queue tr[data-job='{job}']")
        sync_api.expect(row).to_have_attribute("data-state", "attention")
        box = page.locator(f".machine .attention[data-job='{job}']")
        sync_api.expect(box).to_contain_text(f"stopped after file line {checkpoint['file_line']}")
        sync_api.expect(box).to_contain_text(f"{checkpoint['done']} of {checkpoint['lines']} lines known executed")
        sync_api.expect(box).to_contain_text("machine at X ")
        assert row.locator("button[data-action='pause']").count() == 0, "no pause or plain cancel for this job"
        dialog = page.locator("#confirm")
        box.locator("button[data-choice='restart']").click()  # the operator changes their mind: nothing happens
        sync_api.expect(dialog).to_be_visible()
        sync_api.expect(dialog).to_contain_text("Restart sheet 1")
        page.locator("#confirm-no").click()
        sync_api.expect(dialog).to_be_hidden()
        time.sleep(0.5)
        assert queue.job(job).state == "attention" and len(executed_program_lines(log)) == checkpoint["done"]
        box.locator("button[data-choice='resume']").click()
        sync_api.expect(dialog).to_contain_text(f"Resume job {job} sheet 1 after file line {checkpoint['file_line']}?")
        page.locator("#confirm-yes").click()
        sync_api.expect(row).to_have_attribute("data-state", "ready", timeout=60000)  # sheet 1 done; load sheet 2
        page.locator(f".machine button.confirm[data-job='{job}']").click()
        sync_api.expect(row).to_have_attribute("data-state", "done", timeout=60000)
    expected = [line for sheet in attention_page["sheets"] for line in wire_lines(sheet)]
    assert executed_program_lines(log) == expected


def test_framing_traces_the_sheet_outline_with_the_laser_off_before_the_operator_confirms(tmp_path):
    from fabline.jobs.streaming import frame_program

    program = square_program(tmp_path / "sheet.gcode", 12, 34, squares=3)
    db = tmp_path / "q.sqlite"
    queue = JobQueue(db)
    job_id = queue.submit("framed", programs=[("S1", str(program), "")])
    with pytest.raises(FablineError, match="a sheet is framed while it waits on its machine"):
        queue.request(job_id, "frame")  # not on a machine yet
    log = tmp_path / "m1.log"
    runner = start(db, f"sim://frame?settings=32:1&time_scale=50&log={log}")
    try:
        wait(lambda: queue.job(job_id).machine == "m1")
        queue.request(job_id, "frame")
        wait(lambda: any("framed on m1" in e["message"] for e in queue.events()))
        assert queue.job(job_id).state == "ready" and queue.job(job_id).confirmed == -1, "framing confirms nothing"
    finally:
        runner.stop()
    frame = tmp_path / "frame.gcode"
    frame.write_text(frame_program(program), encoding="ascii")
    executed = executed_program_lines(log)
    assert executed == wire_lines(frame)
    corners = [re.sub(r"^N\d+|T\d+$", "", line) for line in executed[1:6]]
    assert corners == ["G0X12.000Y34.000", "G0X31.000Y34.000", "G0X31.000Y39.000", "G0X12.000Y39.000", "G0X12.000Y34.000"]
    assert not any(word in line for line in executed for word in ("M3", "M4", "S")), "the laser stays off"


def test_a_program_pause_m0_waits_for_the_operator_with_a_message_and_resumes(tmp_path):
    program = square_program(tmp_path / "sheet.gcode", 10, 10, squares=3)
    lines = program.read_text(encoding="ascii").splitlines()
    lines.insert(9, "M0")  # after the first square: the operator turns the sheet over, say
    program.write_text("\n".join(lines) + "\n", encoding="ascii")
    db = tmp_path / "q.sqlite"
    queue = JobQueue(db)
    job_id = queue.submit("m0", programs=[("S1", str(program), "")])
    log = tmp_path / "m1.log"
    runner = start(db, f"sim://m0?settings=32:1&time_scale=20&log={log}", auto_confirm=True)
    try:
        wait(lambda: queue.job(job_id).state == "paused")
        machine = queue.machines()[0]
        assert machine["state"] == "program paused (M0) at file line 10: resume to continue"
        held = len(executed_program_lines(log))
        time.sleep(0.5)
        assert len(executed_program_lines(log)) == held and queue.job(job_id).state == "paused"
        assert any("program paused (M0) at file line 10" in e["message"] for e in queue.events())
        queue.request(job_id, "resume")
        wait(lambda: queue.job(job_id).state == "done")
    finally:
        runner.stop()
    assert executed_program_lines(log) == wire_lines(program)
