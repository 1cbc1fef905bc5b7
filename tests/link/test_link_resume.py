"""Safe and truthful at a stock Grbl 1.1h (no `Ln:`): controller compatibility before the first move, resume on
retraced paths and away from work zero, M0 pauses, run identity, journal integrity, locks and signals."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
import uuid
from pathlib import Path

import pytest
import serial

from fabline.errors import FablineError
from fabline.link import SimulatorServer, Streamer, StreamInterrupted, executed_file_lines, read_journal
from fabline.link.protocol_sim import close_simulator, get_simulator
from fabline.machine import load_program

REPO = Path(__file__).resolve().parents[2]
HEAD = ["G21", "G90", "G17", "G94", "M4 S800", "F600"]


@pytest.fixture
def sim(tmp_path):
    """sim(**options) -> URL of a uniquely named stock-build simulator in laser mode; `.log` is its executed log."""
    names = []

    def url(name: str | None = None, **options) -> str:
        if name is None:
            name = f"r{uuid.uuid4().hex[:8]}"
            names.append(name)
        query = {"time_scale": 50, "log": tmp_path / f"{name}.log", "settings": "32:1", **options}
        return f"sim://{name}?" + "&".join(f"{key}={value}" for key, value in query.items())

    yield url
    for name in names:
        close_simulator(name)


def log_of(url: str) -> Path:
    return Path(url.split("log=")[1].split("&")[0])


def simulator_of(url: str):
    return get_simulator(url[len("sim://"):].split("?")[0])


def write(path: Path, body: list[str], tail: tuple[str, ...] = ("M5", "M2")) -> Path:
    path.write_text("\n".join(HEAD + body + list(tail)) + "\n", encoding="ascii")
    return path


def sawtooth(count: int) -> list[str]:
    """Cuts that never pass a point twice (x always grows), so a halt anywhere is placed without ambiguity."""
    return [f"G1 X{i} Y{i % 2 * 3}" for i in range(1, count + 1)]


def expected(program: Path) -> list[int]:
    return [line.file_line for line in load_program(program).lines]


def exactly_once(program: Path, url: str) -> bool:
    return executed_file_lines(log_of(url)) == expected(program)


def abort_when(streamer: Streamer, condition):
    def on_progress(progress):
        if condition(progress):
            streamer.abort()
    return on_progress


# ----- resume on every program shape --------------------------------------------------------------------
def test_a_halt_on_a_retraced_pass_resumes_there_not_on_the_first_pass(tmp_path, sim):
    """Out and back over the same 40 mm: halted on the way back, the stopped position also lies on the way out,
    but that line left the planner long ago; the first matching segment in the file re-cut the whole return."""
    out = [f"G1 X{x}" for x in range(1, 41)]
    back = [f"G1 X{x}" for x in range(39, -1, -1)]
    program = write(tmp_path / "retrace.gcode", ["G0 X0 Y10"] + out + back)
    url = sim(time_scale=2)  # 50 ms a line: the halt lands long before the end even on a loaded machine
    streamer = Streamer(url, status_interval=0.02)
    turn = len(HEAD) + 1 + 40 + 25  # acknowledged well into the return: the planner holds at most 15 lines of it
    result = streamer.run(program, on_progress=abort_when(streamer, lambda p: p.acked >= turn))
    assert result.reason == "aborted" and result.executed > len(HEAD) + 41
    simulator_of(url).time_scale = 200
    assert Streamer(url, status_interval=0.02).run(program, resume=True).completed
    assert exactly_once(program, url)


def test_a_halt_on_a_zigzag_while_lines_wait_for_planner_room_is_placed_by_the_planners_fill(tmp_path, sim):
    """Back and forth over 3 mm 12 times: a halt's position lies on several passes of the window, but with the next
    move waiting for planner room the planner is full, so the held line is the oldest of its 15 blocks."""
    zigzag = [f"G1 X{x}" for _ in range(12) for x in (1, 2, 3, 2, 1, 0)]
    program = write(tmp_path / "zigzag.gcode", ["G0 X0 Y10"] + zigzag)
    url = sim(time_scale=2)
    streamer = Streamer(url, status_interval=0.02)
    result = streamer.run(program, on_progress=abort_when(streamer, lambda p: p.acked >= 40))
    assert result.reason == "aborted"
    executed = executed_file_lines(log_of(url))
    assert result.executed == len(executed) and executed == expected(program)[: len(executed)]
    simulator_of(url).time_scale = 200
    assert Streamer(url, status_interval=0.02).run(program, resume=True).completed
    assert exactly_once(program, url)


def test_a_position_several_window_lines_pass_is_refused_naming_them_then_from_line_resumes(tmp_path, sim):
    """The whole zigzag answered (nothing waits for planner room: M5 waits for an empty planner, its fill says
    nothing) and no status report while it ran (polled every 10 s) to tell which pass the machine was on: halted on
    its way, the position fits several passes, so the candidates are named for the operator's --from-line."""
    zigzag = [f"G1 X{x}" for _ in range(2) for x in (1, 2, 3, 2, 1, 0)]
    program = write(tmp_path / "zigzag.gcode", ["G0 X0 Y10"] + zigzag)
    url = sim(time_scale=2)  # the travel to X0 Y10 takes 0.8 s, the zigzag 2.2 s more
    streamer = Streamer(url, status_interval=10)
    with pytest.raises(StreamInterrupted) as stopped:
        streamer.run(program, on_progress=abort_when(streamer, lambda p: p.elapsed > 1.5))
    assert stopped.value.reason == "undecided" and "where the path passes more than once" in str(stopped.value)
    candidates = [int(n) for n in str(stopped.value).split("(one of ")[1].rstrip(")").split(", ")]
    assert len(candidates) >= 2
    executed = executed_file_lines(log_of(url))
    assert executed == expected(program)[: len(executed)]
    with pytest.raises(StreamInterrupted, match=r"could not tell the line"):
        Streamer(url).run(program, resume=True)
    first_not_cut = expected(program)[len(executed)]
    assert first_not_cut in candidates
    simulator_of(url).time_scale = 200
    assert Streamer(url, status_interval=0.02).run(program, resume=True, start_line=first_not_cut).completed
    assert exactly_once(program, url)


def test_a_job_starting_away_from_work_zero_resumes_and_from_line_always_works(tmp_path, sim):
    """Machine at (500, 300): motion is planned from there, so a halt in the first move is placed; and the operator's
    --from-line works even where nothing could be inferred."""
    program = write(tmp_path / "away.gcode", [f"G1 X{530 + 5 * i} Y300" for i in range(29)])  # first move: 3 s
    url = sim(time_scale=1)
    port = serial.serial_for_url(url, timeout=0.05)
    simulator_of(url).time_scale = 1000
    port.write(b"G0X500Y300\n")
    port.close()
    deadline = time.monotonic() + 10
    while simulator_of(url).state != "Idle" or simulator_of(url).position[:2] != (500.0, 300.0):
        assert time.monotonic() < deadline
        time.sleep(0.01)
    simulator_of(url).time_scale = 1
    streamer = Streamer(url, status_interval=0.02)
    result = streamer.run(program, on_progress=abort_when(streamer, lambda p: p.state == "Run"))
    assert result.reason == "aborted" and result.executed == len(HEAD)  # stopped in the first move, file line 7
    assert read_journal(f"{program}.journal").origin == (500.0, 300.0, 0.0)
    executed = executed_file_lines(log_of(url))
    simulator_of(url).time_scale = 20
    streamer = Streamer(url, status_interval=0.02)
    result = streamer.run(program, resume=True, start_line=7,
                          on_progress=abort_when(streamer, lambda p: p.acked > 20))
    assert not result.completed
    assert Streamer(url, status_interval=0.02).run(program, resume=True).completed
    assert executed == expected(program)[:6] and exactly_once(program, url)


# ----- controller compatibility ---------------------------------------------------------------------------
def test_a_laser_program_on_a_controller_without_laser_mode_is_refused_before_anything_is_sent(cli, tmp_path, sim):
    program = write(tmp_path / "sheet.gcode", ["G0 X10 Y10", "G1 X20"])
    url = sim(settings="32:0")
    code, _, err = cli("stream", program, "--port", url)
    assert code == 2 and err.count("\n") == 1
    assert "sheet.gcode:5: 'M4 S800' switches a laser on, but the controller has $32=0" in err and "send $32=1" in err
    assert not log_of(url).exists() or executed_file_lines(log_of(url)) == []
    assert not Path(f"{program}.journal").exists()
    exchange = Path(f"{program}.link.log").read_text()
    assert ">>> N" not in exchange  # no program line went out
    code, out, err = cli("stream", program, "--port", url, "--force")
    assert code == 0, err
    assert exactly_once(program, url)
    journal = [json.loads(row) for row in Path(f"{program}.journal").read_text().splitlines()]
    assert journal[1]["event"] == "forced" and "$32=0" in journal[1]["problems"][0]
    assert "--force: streaming despite" in Path(f"{program}.link.log").read_text()


def test_the_profile_named_in_the_header_sets_what_the_controller_must_have(cli, tmp_path, sim):
    program = tmp_path / "sheet.gcode"
    program.write_text("; fabline export: job j, sheet S1 (1 of 1), 100 x 100 mm\n"
                       "; machine grbl-laser (Grbl 1.1), mode laser, kerf 0.200 mm\n"
                       + "\n".join(HEAD + ["G1 X10", "M5"]) + "\n", encoding="ascii")
    assert load_program(program).machine == "grbl-laser"
    code, _, err = cli("stream", program, "--port", sim())  # $32=1 but Grbl's default max rates, 500 mm/min
    assert code == 2 and "machine grbl-laser needs $110>=6000, but the controller has $110=500" in err
    assert "(and 1 more conflict)" in err
    code, _, err = cli("stream", program, "--port", sim(), "--machine", "grbl-plotter")
    assert code == 2 and "machine grbl-plotter needs $32=0" in err and "send $32=0" in err
    code, _, err = cli("stream", program, "--port", sim(settings="32:1,110:12000,111:12000"))
    assert code == 0, err
    program.write_text(program.read_text().replace("grbl-laser", "shop-laser"), encoding="ascii")
    code, _, err = cli("stream", program, "--port", sim())
    assert code == 2 and err.count("\n") == 1
    assert f"{program}: made for machine shop-laser, which is not known here" in err and "give --machine" in err


@pytest.mark.parametrize("body, options, message", [
    (["G1 X150", "G1 X-100"], {}, "spans 250.000 mm in X (-100.000 to 150.000) but the controller's X travel $130 is 200"),
    (["G1 X10 Y10"], {"settings": "32:1,20:1"}, "soft limits are on ($20=1) and the program reaches machine X 0.000 to 10.000"),
    (["M7", "G1 X10"], {}, "M7 (mist coolant) is not in this controller's build ([OPT:V,...] has no M"),
])
def test_travel_soft_limits_and_build_options_are_checked(tmp_path, sim, body, options, message):
    program = write(tmp_path / "sheet.gcode", body)
    url = sim(**options)
    with pytest.raises(FablineError) as refused:
        Streamer(url).run(program)
    assert message in str(refused.value) and "nothing was sent" in str(refused.value)
    assert not log_of(url).exists() or executed_file_lines(log_of(url)) == []


def test_a_feed_above_the_max_rates_with_the_laser_at_constant_power_is_refused_before_anything_is_sent(tmp_path,
                                                                                                        sim):
    """$110 = $111 = 5000 mm/min and F6000: Grbl caps a move so that no axis runs over its max rate
    (limit_value_by_axis_maximum): along X the cap is 5000 / 1 = 5000 < 6000, on the diagonal to (10, 10) it is
    5000 / (1/sqrt 2) = 7071 > 6000. With M3 in laser mode the power stays while the cut slows: refused, naming
    the move along X (file line 9); with M4 (power follows the speed) it streams, and the log notes the cap."""
    body = ["G1 X10 Y10", "G1 X20"]
    program = tmp_path / "fast.gcode"
    program.write_text("\n".join(["G21", "G90", "G17", "G94", "M3 S800", "F6000", "G0 X0 Y0"] + body + ["M5", "M2"])
                       + "\n", encoding="ascii")
    url = sim(settings="32:1,110:5000,111:5000")
    with pytest.raises(FablineError) as refused:
        Streamer(url).run(program)
    message = str(refused.value)
    assert message.startswith(f"{program}:9: feed 6000 mm/min is above what the controller's max rates "
                              "($110..$112) allow along this move, 5000 mm/min: Grbl caps it and with the laser at "
                              "constant power (M3) the slower cut burns more than planned")
    assert "nothing was sent" in message and (not log_of(url).exists() or executed_file_lines(log_of(url)) == [])
    program.write_text(program.read_text().replace("M3 S800", "M4 S800"), encoding="ascii")
    exchange = tmp_path / "exchange.log"
    assert Streamer(url, status_interval=0.02, exchange_log=exchange).run(program).completed
    assert f"note: {program}:9: feed 6000 mm/min is above" in exchange.read_text()
    assert "the cut runs slower than planned" in exchange.read_text()


def test_the_receive_buffer_comes_from_the_build(tmp_path, sim):
    program = write(tmp_path / "sheet.gcode", sawtooth(60))
    url = sim(rx_buffer=256, build_options="VN")
    streamer = Streamer(url, status_interval=0.02)
    assert streamer.run(program).completed and streamer.rx_buffer == 256 and streamer.build.line_numbers
    assert simulator_of(url).overflowed == 0 and exactly_once(program, url)


# ----- M0 ---------------------------------------------------------------------------------------------------
def test_m0_is_reported_with_its_file_line_and_the_stream_continues_on_resume(tmp_path, sim):
    program = write(tmp_path / "pause.gcode", ["G1 X10", "M1", "G1 X20", "M0", "G1 X30"])
    url = sim()
    streamer = Streamer(url, status_interval=0.02)
    messages = []

    def on_progress(progress):
        if progress.message and progress.message not in messages:
            messages.append(progress.message)
            streamer.resume()

    assert streamer.run(program, on_progress=on_progress).completed
    assert messages == ["program paused (M0) at file line 10: resume to continue"]
    assert exactly_once(program, url)
    assert '"event":"paused","line":10' in Path(f"{program}.journal").read_text()


def test_the_cli_shows_the_m0_pause_and_sigusr1_resumes_it(cli, tmp_path, sim):
    program = write(tmp_path / "pause.gcode", ["G1 X10", "M0", "G1 X20"])
    url = sim()

    def resume_when_held():
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:
            simulator = simulator_of(url)
            if simulator is not None and simulator.state == "Hold":
                time.sleep(0.3)
                os.kill(os.getpid(), signal.SIGUSR1)
                return
            time.sleep(0.02)

    helper = threading.Thread(target=resume_when_held)
    helper.start()
    code, out, err = cli("stream", program, "--port", url)
    helper.join()
    assert code == 0, err
    assert f"{program}: program paused (M0) at file line 8: resume to continue (send SIGUSR1 to process" in err
    assert exactly_once(program, url)


# ----- run identity and journal integrity ----------------------------------------------------------------------
def interrupted(program: Path, url: str, identity=None) -> None:
    """Stream `program` and abort it about halfway."""
    streamer = Streamer(url, status_interval=0.02)
    total = len(load_program(program).lines)
    result = streamer.run(program, identity=identity,
                          on_progress=abort_when(streamer, lambda p: p.acked >= total // 2))
    assert result.reason == "aborted"


def test_a_resume_is_refused_for_another_run_identity_and_a_new_run_of_another_job_starts_at_line_one(tmp_path, sim):
    program = write(tmp_path / "sheet.gcode", sawtooth(80))
    url = sim(time_scale=5)
    first = {"job": "pavilion", "run": "1"}
    interrupted(program, url, identity=first)
    assert read_journal(f"{program}.journal").identity == first
    with pytest.raises(FablineError, match=r"belongs to run job=pavilion, run=1, not run job=pavilion, run=2; resume"):
        Streamer(url).run(program, resume=True, identity={"job": "pavilion", "run": "2"})
    with pytest.raises(FablineError, match=r"belongs to run job=pavilion, run=1, not no named run"):
        Streamer(url).run(program, resume=True)
    simulator_of(url).time_scale = 200
    before = len(executed_file_lines(log_of(url)))
    assert Streamer(url, status_interval=0.02).run(program, identity={"job": "pavilion", "run": "2"}).completed
    assert executed_file_lines(log_of(url))[before:] == expected(program)  # a new run: every line, from the first


def test_a_controller_moved_after_its_host_died_is_not_resumed_by_its_tag_alone(tmp_path, sim):
    """The host died with its journal whole, then the machine was moved: `$G` still names the last line parsed, but
    the controller does not stand where the program is after that line, so nothing proves what ran: one line naming
    both positions and --from-line, nothing run; the operator's --from-line then completes the sheet exactly once."""
    program = write(tmp_path / "moved.gcode", sawtooth(60))
    url = sim(time_scale=100)
    streamer = Streamer(url, status_interval=0.02)

    def die(progress):
        if progress.acked > 30:
            raise KeyboardInterrupt  # the host goes away; the controller runs out what it holds

    with pytest.raises(KeyboardInterrupt):
        streamer.run(program, on_progress=die)
    controller, deadline = simulator_of(url), time.monotonic() + 10
    while controller.state != "Idle" or controller.planner:
        assert time.monotonic() < deadline
        time.sleep(0.01)
    ran = executed_file_lines(log_of(url))
    controller.receive(b"$J=G90X200Y50F20000\n")  # the operator jogs away: a jog leaves the parser's tag alone
    while controller.state != "Idle" or controller.position[:2] != (200.0, 50.0):
        assert time.monotonic() < deadline
        time.sleep(0.01)
    with pytest.raises(FablineError) as refused:
        Streamer(url, status_interval=0.02).run(program, resume=True)
    message = str(refused.value)
    x = len(ran) - len(HEAD)  # the sawtooth's cut at file line 6 + i ends at (i, i % 2 * 3)
    assert (f"fits file line {ran[-1]}, but it stands at (200.000, 50.000, 0.000), not at ({x}.000, {x % 2 * 3}.000, "
            "0.000) where the program is after that line") in message
    assert "--resume --from-line N" in message and "\n" not in message
    assert executed_file_lines(log_of(url)) == ran
    first_not_cut = expected(program)[len(ran)]
    assert Streamer(url, status_interval=0.02).run(program, resume=True, start_line=first_not_cut).completed
    assert exactly_once(program, url)


def test_a_held_controller_whose_host_died_is_checked_before_the_resume_lets_it_go_on(tmp_path, sim):
    """The host died with the machine held mid-sheet; the resume names a profile the controller conflicts with
    (grbl-plotter needs $32=0, it has $32=1): refused before the cycle start that would let it cut what it holds
    (a held Grbl answers `$$` with error:8: the run's journaled settings are checked), nothing run, still held."""
    program = write(tmp_path / "held.gcode", sawtooth(120))
    url = sim(time_scale=10)
    streamer = Streamer(url, status_interval=0.02)

    def pause_then_die(progress):
        if progress.acked > 40 and not streamer.paused:
            streamer.pause()
        elif streamer.paused and progress.state == "Hold":
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        streamer.run(program, on_progress=pause_then_die)
    controller, deadline = simulator_of(url), time.monotonic() + 10
    while controller._hold != "complete":
        assert time.monotonic() < deadline
        time.sleep(0.01)
    ran = executed_file_lines(log_of(url))
    with pytest.raises(FablineError, match=r"machine grbl-plotter needs .*nothing was sent"):
        Streamer(url, status_interval=0.02).run(program, resume=True, machine="grbl-plotter")
    time.sleep(0.2)
    assert controller.state == "Hold" and executed_file_lines(log_of(url)) == ran
    assert Streamer(url, status_interval=0.02).run(program, resume=True).completed
    assert exactly_once(program, url)


def test_a_journal_that_lost_the_start_of_a_later_run_is_refused_not_read_as_the_stopped_one(tmp_path):
    """An aborted run, then a resumed one killed mid-sheet whose start and resume records were lost: read as one run,
    the old stop's verdict (done = 3) would settle what ran, and the later run's lines would run again."""
    journal = tmp_path / "sheet.gcode.journal"
    rows = ['{"event":"start","sha256":"x","lines":9}', '{"event":"sent","n":3,"line":4}', '{"event":"ok","n":3,"line":4}',
            '{"event":"done","count":3}', '{"event":"stopped","reason":"aborted"}',
            '{"event":"sent","n":4,"line":5}', '{"event":"ok","n":4,"line":5}', '{"event":"sent","n":5,"line":6}']
    journal.write_text("\n".join(rows) + "\n")
    with pytest.raises(FablineError) as refused:
        read_journal(journal)
    assert str(refused.value).startswith(f"{journal}:6: journal record 'sent' follows the stop recorded at line 5 ")
    assert "it knew 3 lines executed" in str(refused.value) and "--resume --from-line N" in str(refused.value)
    rows[5:5] = ['{"event":"start","sha256":"x","lines":9}', '{"event":"resume","count":3}']
    journal.write_text("\n".join(rows) + "\n")
    state = read_journal(journal)  # whole: the later run, resumed after 3 lines, sent line 6
    assert (state.stopped, state.resumed_at, state.sent) == (None, 3, 6)


def test_a_torn_last_record_is_cut_off_before_a_resume_appends(tmp_path, sim):
    program = write(tmp_path / "sheet.gcode", sawtooth(80))
    url = sim(time_scale=5)
    interrupted(program, url)
    journal = Path(f"{program}.journal")
    with open(journal, "a") as handle:
        handle.write('{"event":"ok","n":4')  # the host died writing this
    simulator_of(url).time_scale = 200
    assert Streamer(url, status_interval=0.02).run(program, resume=True).completed
    assert read_journal(journal).finished and exactly_once(program, url)


@pytest.mark.parametrize("content", [b"", b'{"event":"start"\n{garbage\n{"event":"ok","n":1}\n', b"\x00" * 64])
def test_restart_never_needs_the_old_journal(tmp_path, sim, content):
    program = write(tmp_path / "sheet.gcode", ["G1 X10"])
    Path(f"{program}.journal").write_bytes(content)
    url = sim()
    if content:
        with pytest.raises(FablineError, match=r"journal.*--restart"):
            Streamer(url).run(program)
    assert Streamer(url, status_interval=0.02).run(program, restart=True).completed
    assert exactly_once(program, url) and read_journal(f"{program}.journal").finished


@pytest.mark.parametrize("record, message", [
    ('{"event":"ok"}', "journal record 'ok' has no valid 'n' (got None)"),
    ('{"event":"ok","n":"7"}', "journal record 'ok' has no valid 'n' (got '7')"),
    ('{"event":"done","count":-3}', "journal record 'done' has no valid 'count' (got -3)"),
    ('{"event":"teleport"}', "unknown journal event 'teleport'"),
    ('[1, 2]', "malformed journal record (no event)"),
    ('{"event":"start","sha256":"x","lines":3,"identity":{"job":5}}', "malformed identity"),
])
def test_malformed_journal_fields_are_one_line_errors(tmp_path, record, message):
    journal = tmp_path / "sheet.gcode.journal"
    journal.write_text('{"event":"start","sha256":"x","lines":3}\n' + record + "\n" + '{"event":"finished"}\n')
    with pytest.raises(FablineError) as error:
        read_journal(journal)
    assert f"{journal}:2: " in str(error.value) and message in str(error.value) and "\n" not in str(error.value)


# ----- locks and signals ------------------------------------------------------------------------------------
def run_in_background(program: Path, url: str, **options):
    """Start a slow stream in a thread; return (streamer, thread, outcome list), once the machine moves."""
    streamer, outcome = Streamer(url, status_interval=0.02), []

    def target():
        try:
            outcome.append(streamer.run(program, **options))
        except Exception as exc:  # reported by the test
            outcome.append(exc)

    thread = threading.Thread(target=target)
    thread.start()
    deadline = time.monotonic() + 10
    while (simulator_of(url) is None or simulator_of(url).state != "Run") and time.monotonic() < deadline:
        time.sleep(0.01)
    return streamer, thread, outcome


def test_two_streams_to_one_port_refuse_naming_the_holder(tmp_path, sim):
    first = write(tmp_path / "a.gcode", sawtooth(40))
    second = write(tmp_path / "b.gcode", ["G1 X1"])
    url = sim(time_scale=1)
    streamer, thread, outcome = run_in_background(first, url)
    try:
        with pytest.raises(FablineError) as refused:
            Streamer(url.split("?")[0] + "?time_scale=7").run(second)  # the same device, other URL options
        assert f"port sim://{url[6:].split('?')[0]}?time_scale=7 is in use by process {os.getpid()}" in str(refused.value)
        assert not Path(f"{second}.journal").exists()
    finally:
        streamer.abort()
        thread.join()
    assert outcome[0].reason == "aborted"


def test_a_refused_second_run_leaves_the_running_ones_journal_alone(tmp_path, sim):
    program = write(tmp_path / "sheet.gcode", sawtooth(40))
    url = sim(time_scale=1)
    streamer, thread, outcome = run_in_background(program, url)
    journal = Path(f"{program}.journal")
    try:
        written = journal.read_text()
        with pytest.raises(FablineError, match=rf"journal {journal} is in use by process {os.getpid()}"):
            Streamer(sim()).run(program, restart=True)  # another machine, the same program and journal
        assert journal.read_text().startswith(written)
    finally:
        streamer.abort()
        thread.join()
    assert outcome[0].reason == "aborted" and read_journal(journal).stopped == "aborted"


@pytest.mark.parametrize("signal_number", [signal.SIGTERM, signal.SIGHUP])
def test_sigterm_and_sighup_stop_like_ctrl_c_and_the_job_resumes(tmp_path, signal_number):
    program = write(tmp_path / "sheet.gcode", sawtooth(120))
    log, journal = tmp_path / "executed.log", Path(f"{program}.journal")
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    command = [sys.executable, "-c", "import sys; from fabline.cli import main; sys.exit(main())", "stream",
               str(program), "--reconnect-timeout", "0"]
    with SimulatorServer(log=log, time_scale=5, faults={"settings": "32:1"}) as server:
        process = subprocess.Popen(command + ["--port", server.url], env=env, stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + 30
        while not journal.exists() or journal.read_text().count('"event":"ok"') < 20:
            assert time.monotonic() < deadline and process.poll() is None
            time.sleep(0.02)
        process.send_signal(signal_number)
        _, err = process.communicate(timeout=30)
        assert process.returncode == 1, err
        assert "stopped (aborted)" in err and "--resume" in err
        assert read_journal(journal).stopped == "aborted"
        finished = subprocess.run(command + ["--port", server.url, "--resume"], env=env, capture_output=True,
                                  text=True, timeout=60)
        assert finished.returncode == 0, finished.stderr
    assert executed_file_lines(log) == expected(program)


def test_a_settings_query_refused_while_buffered_lines_run_is_asked_again_when_the_machine_stands_still(sim):
    """After a lost connection the controller may be idle for a moment and then run lines still in its buffer:
    a `$I` sent then is refused with error:8 (seen in the fault campaign); the streamer waits and asks again."""
    url = sim(time_scale=5)
    streamer = Streamer(url)
    streamer._open()
    try:
        streamer._write(b"G1 X8 F600\n")  # what the host sent before the connection dropped
        time.sleep(0.05)
        assert streamer._query_status().state == "Run"
        feedback = streamer._command(b"$I\n")
        assert "VER:1.1h.20190830:" in feedback and streamer._query_status().state == "Idle"
    finally:
        streamer._close()


# ----- a journal that cannot be written ---------------------------------------------------------------------
def fail_fsync_after(monkeypatch, calls: int) -> None:
    """The disk fills after `calls` fsyncs: every later fsync fails as a full disk does."""
    from fabline.link import journal as journal_module
    real, count = os.fsync, [0]

    def fsync(fd):
        count[0] += 1
        if count[0] > calls:
            raise OSError(28, "No space left on device")
        real(fd)

    monkeypatch.setattr(journal_module.os, "fsync", fsync)


def test_a_journal_that_fills_the_disk_before_the_first_line_sends_nothing(tmp_path, sim, monkeypatch):
    program = write(tmp_path / "sheet.gcode", sawtooth(20))
    url = sim(time_scale=200)
    fail_fsync_after(monkeypatch, 0)
    with pytest.raises(FablineError, match=r"sheet\.gcode\.journal: cannot write the journal: No space left on "
                                            r"device; nothing was sent"):
        Streamer(url, status_interval=0.02).run(program)
    assert executed_file_lines(log_of(url)) == []


def test_a_journal_that_fails_mid_stream_stops_the_machine_and_names_the_line_to_resume_from(tmp_path, sim,
                                                                                            monkeypatch):
    """A full disk in the middle of a sheet: the stream stops (feed hold) rather than cut lines no journal records,
    names the line to go on from (or, stopped on a corner two lines share, both of them), and --from-line then
    cuts every line exactly once."""
    program = write(tmp_path / "sheet.gcode", sawtooth(120))
    url = sim(time_scale=5)
    fail_fsync_after(monkeypatch, 4)  # the start record's commit and a few background commits succeed
    with pytest.raises(StreamInterrupted, match=r"cannot write the journal: No space left on device; the machine "
                                                r"was stopped") as stop:
        Streamer(url, status_interval=0.02).run(program)
    monkeypatch.undo()
    ran = executed_file_lines(log_of(url))
    first_not_cut = expected(program)[len(ran)]
    assert ran == expected(program)[:len(ran)] and 0 < len(ran) < 120
    named = re.search(r"after file line \d+: make room, then run again with --resume --from-line (\d+)$", str(stop.value))
    if named:
        assert stop.value.reason == "journal" and stop.value.executed == len(ran) and int(named[1]) == first_not_cut
    else:  # halted on a sawtooth corner: the two lines meeting there are named, the operator looks at the part
        lines = re.search(r"where the path passes more than once \(file lines (\d+), (\d+) can have been cutting\)",
                          str(stop.value))
        assert stop.value.reason == "undecided" and lines and first_not_cut in (int(lines[1]), int(lines[2]))
    simulator_of(url).time_scale = 200
    assert Streamer(url, status_interval=0.02).run(program, resume=True, start_line=first_not_cut).completed
    assert exactly_once(program, url)


def test_an_exchange_log_that_fails_mid_stream_stops_the_machine_and_the_journal_resumes(tmp_path, sim):
    """The exchange log's disk fills mid-sheet: the stream stops as for the journal, the journal (still sound)
    records where, and a plain --resume cuts every remaining line exactly once."""
    program = write(tmp_path / "sheet.gcode", sawtooth(120))
    url = sim(time_scale=5)
    log = tmp_path / "exchange.log"
    streamer = Streamer(url, status_interval=0.02, exchange_log=log)

    class FullDisk:
        def __init__(self, real):
            self.real = real

        def write(self, text):
            raise OSError(28, "No space left on device")

        def flush(self):
            self.real.flush()

        def close(self):
            self.real.close()

    def fill_the_disk(progress):
        if progress.acked >= 20 and not isinstance(streamer._log, (FullDisk, type(None))):
            streamer._log = FullDisk(streamer._log)

    with pytest.raises(StreamInterrupted, match=r"exchange\.log: cannot write the exchange log: No space left on "
                                                r"device; the machine was stopped after file line \d+: make room, "
                                                r"then run again with --resume$") as stop:
        streamer.run(program, on_progress=fill_the_disk)
    assert stop.value.reason == "journal" and 0 < stop.value.executed < 120
    assert read_journal(f"{program}.journal").done == stop.value.executed
    simulator_of(url).time_scale = 200
    assert Streamer(url, status_interval=0.02).run(program, resume=True).completed
    assert exactly_once(program, url)
