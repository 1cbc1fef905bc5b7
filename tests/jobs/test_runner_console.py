"""The runner page's machine console (issue 24): a controller that conflicts with a job is set up from the page
(`$N=V` only after a confirmation, `$X`, `$H`, `$J=` jogs, a work origin), every command and the controller's
answer in the runner's log; while a sheet streams only Grbl's real-time overrides go out. Job files are uploaded to
the queue; a cancelled job keeps on the page what was cut."""

from __future__ import annotations

import time
import uuid

import httpx
import pytest

from fabline.jobs.queue import JobQueue
from fabline.jobs.runner import MachineConfig, Runner
from fabline.jobs.web import TOKEN_HEADER
from fabline.link.protocol_sim import close_simulator, get_simulator
from runner_support import TOKEN, executed_program_lines, page_server, square_program, wire_lines

TINY = """
name = "tiny"
[model]
design = "enneper"
[model.options]
size = [1.5, 1.5]
spacing = 0.5
[output]
folder = "../out/tiny"
"""


def wait_for(condition, timeout: float = 60) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.05)


@pytest.fixture
def shop(tmp_path):
    """A runner on one simulated stock Grbl 1.1h (laser mode off, 500 mm/min, as a real controller may come), its page."""
    name = f"console-{uuid.uuid4().hex[:8]}"
    db = tmp_path / "jobs" / "runner.sqlite"
    log = tmp_path / "executed.log"
    runner = Runner(db, [MachineConfig("m1", f"sim://{name}?time_scale=20&log={log}")], poll=0.05, prepare=False)
    runner.start()
    with page_server(db) as url, httpx.Client(base_url=url, timeout=60, headers={TOKEN_HEADER: TOKEN}) as client:
        yield {"client": client, "queue": JobQueue(db), "sim": name, "log": log, "tmp": tmp_path, "jobs": db.parent}
    runner.stop()
    close_simulator(name)


def laser_program(path, squares: int = 1, size: float = 5.0):
    """A grbl-laser program (its header names the profile: $32=1 and $110/$111 >= 6000 required)."""
    square_program(path, 20, 20, squares=squares, size=size)
    path.write_text("; machine grbl-laser (Grbl 1.1), mode laser\n" + path.read_text(encoding="ascii"), encoding="ascii")
    return path


def console(client, body):
    return client.post("/api/machines/m1/console", json=body)


def test_a_conflicting_controller_is_set_up_from_the_console_and_the_job_resumed(shop):
    client, queue = shop["client"], shop["queue"]
    program = laser_program(shop["tmp"] / "plate.gcode")
    job = queue.submit("plate", programs=[("plate", str(program), "")])
    wait_for(lambda: queue.job(job).machine == "m1")
    queue.act(job, "confirm")
    wait_for(lambda: queue.job(job).state == "attention")
    assert "needs $32=1" in queue.job(job).checkpoint()["reason"]

    refused = console(client, {"line": "$32=1"})
    assert refused.status_code == 409 and "confirm it" in refused.json()["error"]
    assert get_simulator(shop["sim"]).settings[32] == 0, "nothing is sent before the confirmation"
    for setting in ("$32=1", "$110=12000", "$111=12000"):
        answer = console(client, {"line": setting, "confirm": True})
        assert (answer.status_code, answer.json()["answer"]) == (200, ["ok"]), answer.text
    assert {k: get_simulator(shop["sim"]).settings[k] for k in (32, 110, 111)} == {32: 1, 110: 12000, 111: 12000}
    messages = [e["message"] for e in queue.events(limit=1000)]
    assert "console on m1: $32=1 -> ok" in messages

    home = console(client, {"line": "$H"})  # the stock build has homing off ($22=0): the controller's own answer
    assert home.status_code == 200 and home.json()["answer"] == ["error:5 (homing cycle is not enabled via settings)"]
    assert console(client, {"line": "$X"}).json()["answer"] == ["ok"]
    assert console(client, {"line": "$J=G91 X10 Y5 F30"}).json()["answer"] == ["ok"]  # 1.1 s at the time scale
    assert get_simulator(shop["sim"]).state == "Jog"
    assert console(client, {"line": "g10 l20 p1 x0 y0"}).json()["answer"] == ["ok"], "sent once the jog ended"
    assert [round(v, 3) for v in get_simulator(shop["sim"]).position[:2]] == [10.0, 5.0]
    for bad, status in (({"line": "G1 X100 F500"}, 409), ({"line": "M4 S1000"}, 409), ({"line": "$X\n$H"}, 409),
                        ({"override": "feed +50%"}, 409), ({"nothing": 1}, 400), ({"line": "$X", "override": "feed 100%"}, 400)):
        answer = console(client, bad)
        assert answer.status_code == status, (bad, answer.text)
    assert client.post("/api/machines/m9/console", json={"line": "$X"}).status_code == 404
    assert httpx.post(str(client.base_url.join("/api/machines/m1/console")), json={"line": "$X"}).status_code == 403

    queue.act(job, "resume")  # "resume here" now streams: the controller is the laser the program is for
    wait_for(lambda: queue.job(job).state == "done")
    assert executed_program_lines(shop["log"]) == wire_lines(program)


def test_while_a_sheet_streams_only_overrides_go_out(shop, monkeypatch):
    client, queue = shop["client"], shop["queue"]
    assert console(client, {"line": "$32=1", "confirm": True}).status_code == 200
    for setting in ("$110=12000", "$111=12000", "$130=4100", "$131=2100"):
        assert console(client, {"line": setting, "confirm": True}).json()["answer"] == ["ok"]
    simulator, received = get_simulator(shop["sim"]), []
    real = simulator._realtime
    monkeypatch.setattr(simulator, "_realtime", lambda byte: (received.append(byte), real(byte))[1])
    program = laser_program(shop["tmp"] / "long.gcode", squares=20, size=50)  # 4 s at the time scale
    job = queue.submit("long", programs=[("long", str(program), "")])
    wait_for(lambda: queue.job(job).machine == "m1")
    queue.act(job, "confirm")
    wait_for(lambda: queue.job(job).state != "ready" and (queue.job(job).state != "cutting"
                                                          or queue.sheets(job)[0].done_lines > 3))
    assert queue.job(job).state == "cutting", queue.job(job).describe()
    refused = console(client, {"line": "$X"})
    assert refused.status_code == 409 and "only feed, rapid and power overrides" in refused.json()["error"]
    for name, byte in (("feed +10%", 0x91), ("power -10%", 0x9B), ("rapid 50%", 0x96)):  # Grbl 1.1's bytes
        answer = console(client, {"override": name})
        assert (answer.status_code, answer.json()["answer"]) == (200, ["sent"])
        wait_for(lambda: byte in received, 10)
    assert queue.job(job).state == "cutting"

    queue.act(job, "cancel")  # a cancelled job keeps on the page what was cut
    wait_for(lambda: queue.job(job).state == "cancelled")
    cut = next(j for j in client.get("/api/state").json()["jobs"] if j["id"] == job)["cut"]
    stopped = cut["stopped"]
    executed = len(executed_program_lines(shop["log"]))
    assert (cut["sheets_finished"], cut["sheets"], stopped["sheet"]) == ([], 1, "long")
    assert stopped["done"] <= stopped["acked"] and stopped["done"] <= executed <= stopped["acked"]
    lines = [line.file_line for line in __import__("fabline.machine", fromlist=["x"]).load_program(program).lines]
    assert stopped["file_line"] == lines[stopped["done"] - 1] and stopped["acked_file_line"] == lines[stopped["acked"] - 1]


def test_a_job_file_uploaded_from_the_page_is_queued_once(shop, tmp_path):
    client, queue, jobs = shop["client"], shop["queue"], shop["jobs"]
    runner = Runner(jobs / "runner.sqlite", [], poll=0.05, prepare=False)
    runner.watch_folder(jobs, every=0.05)  # the folder watcher sees the uploaded file too: still one job
    runner.start()
    try:
        assert httpx.post(str(client.base_url.join("/api/jobs/upload")),
                          json={"name": "tiny.toml", "text": TINY}).status_code == 403
        assert not (jobs / "tiny.toml").exists()
        answer = client.post("/api/jobs/upload", json={"name": "tiny.toml", "text": TINY})
        assert answer.status_code == 200, answer.text
        first = answer.json()
        assert (first["file"], first["new"]) == (str(jobs / "tiny.toml"), True)
        assert (jobs / "tiny.toml").read_text(encoding="utf-8") == TINY
        again = client.post("/api/jobs/upload", json={"name": "tiny.toml", "text": TINY}).json()
        assert (again["id"], again["new"]) == (first["id"], False)
        edited = client.post("/api/jobs/upload", json={"name": "tiny.toml", "text": TINY.replace("0.5", "0.45")}).json()
        assert edited["new"] and edited["file"].startswith(str(jobs / "tiny-")), "the queued job's file is kept"
        time.sleep(0.5)
        assert sorted(j.job_file for j in queue.jobs()) == sorted([first["file"], edited["file"]])
    finally:
        runner.stop()
    for body, said in (({"name": "../x.toml", "text": TINY}, "a job file's name"),
                       ({"name": "bad.toml", "text": "name = "}, "bad.toml: malformed TOML"),
                       ({"name": "bad.toml", "text": TINY + "colour = 1\n"}, "bad.toml: output.colour: unknown key"),
                       ({"name": "big.toml", "text": "#" * (1 << 21)}, "a job file has at most"),
                       ({"name": "deep.toml", "text": "a = " + "[" * 5000 + "]" * 5000}, "deep.toml: nested deeper"),
                       ({"name": "deep.toml", "text": "a = " + "{a=" * 5000 + "1" + "}" * 5000},
                        "deep.toml: nested deeper than 32 levels")):
        answer = client.post("/api/jobs/upload", json=body)
        assert answer.status_code == 400 and said in answer.json()["error"], answer.text
    assert not (jobs / "bad.toml").exists() and not (tmp_path / "x.toml").exists()


def test_the_page_console_sends_a_setting_after_its_dialog_uploads_a_job_and_shows_what_a_cancelled_job_cut(shop):
    from runner_support import headless_chromium

    client, queue = shop["client"], shop["queue"]
    program = laser_program(shop["tmp"] / "plate.gcode")
    job = queue.submit("plate", programs=[("plate", str(program), "")])
    job_file = shop["tmp"] / "tiny.toml"
    job_file.write_text(TINY, encoding="utf-8")
    with headless_chromium() as (sync_api, browser):
        page = browser.new_page()
        page.goto(f"{client.base_url}?token={TOKEN}")
        machine = page.locator(".machine[data-machine='m1']")
        machine.locator(".console summary").click()
        machine.locator(".console input.line").fill("$32=1")
        machine.locator(".console button.send").click()
        dialog = page.locator("#confirm")
        sync_api.expect(dialog).to_contain_text("Send $32=1 to m1?")
        simulator = get_simulator(shop["sim"])  # none yet: nothing was ever sent to the machine
        assert simulator is None or simulator.settings[32] == 0, "not before the dialog's yes"
        page.locator("#confirm-yes").click()
        sync_api.expect(machine.locator(".console .answer")).to_have_text("$32=1: ok", timeout=20000)
        assert get_simulator(shop["sim"]).settings[32] == 1
        machine.locator(".console button.jog-Xplus").click()
        sync_api.expect(machine.locator(".console .answer")).to_have_text("$J=G91 G21 X10 F3000: ok", timeout=20000)
        machine.locator(".console input.line").fill("G1 X5")
        machine.locator(".console input.line").press("Enter")
        sync_api.expect(machine.locator(".console .answer")).to_contain_text("G1 X5: refused: console: 'G1 X5' is not sent")

        page.locator("#upload").set_input_files(str(job_file))
        uploaded = page.locator("#queue tr", has_text="tiny")
        sync_api.expect(uploaded).to_have_count(1, timeout=20000)
        assert (shop["jobs"] / "tiny.toml").read_text(encoding="utf-8") == TINY

        queue.act(job, "cancel")
        row = page.locator(f"#queue tr[data-job='{job}']")
        sync_api.expect(row).to_have_attribute("data-state", "cancelled", timeout=20000)
        sync_api.expect(row.locator(".state")).to_contain_text("cut: 0 of 1 sheets finished")


@pytest.mark.parametrize("text, sent, kind", [
    ("$32=1", "$32=1", "setting"), (" $x ", "$X", "unlock"), ("$H", "$H", "home"), ("$$", "$$", "report"),
    ("$j=g91 g21 x-5.5 y2 f600", "$J=G91 G21 X-5.5 Y2 F600", "jog"), ("$J=G53 F100 X0", "$J=G53 F100 X0", "jog"),
    ("G10 L20 P1 X0 Y0", "G10 L20 P1 X0 Y0", "origin"), ("G92 X0 Y0", "G92 X0 Y0", "origin")])
def test_the_console_sends_settings_unlock_home_jogs_and_origins(text, sent, kind):
    from fabline.jobs.console import check_line

    assert check_line(text) == (sent, kind)


@pytest.mark.parametrize("text", ["G1 X10 F100", "M4 S1000", "$J=G91 X10", "$J=G91 F100", "$J=G91 X10 F100 M3",
                                  "$RST=*", "$SLP", "$C", "$32=1\n$X", "G10 L2 P1 X0", "$N0=G1 X1", "\x18"])
def test_the_console_refuses_programs_and_anything_else(text):
    from fabline.errors import FablineError
    from fabline.jobs.console import check_line

    with pytest.raises(FablineError, match="console: "):
        check_line(text)
