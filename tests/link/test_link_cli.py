"""`fabline stream` and `fabline grbl-sim` from the command line: a job, check mode, and every bad input."""

from __future__ import annotations

import os
import pty
import subprocess
import sys
import termios
import time
import uuid
from pathlib import Path

import pytest
import serial

from conftest import without_usage
from fabline.cli import main
from fabline.link import executed_file_lines
from fabline.link.protocol_sim import close_simulator
from fabline.machine import load_program

PROGRAM = "G21\nG90\nM4 S600\n" + "".join(f"G1 X{i % 7} Y{i % 5} F3000\n" for i in range(1, 60)) + "M5\nG0 X0 Y0\n"


@pytest.fixture
def gcode(tmp_path):
    path = tmp_path / "sheet-03.gcode"
    path.write_text(PROGRAM, encoding="ascii")
    return path


@pytest.fixture
def simulator(tmp_path):
    name = f"cli{uuid.uuid4().hex[:8]}"
    log = tmp_path / "executed.log"
    yield (lambda extra="": f"sim://{name}?time_scale=500&settings=32:1&log={log}{extra}"), log  # a laser controller
    close_simulator(name)


def written(tmp_path) -> set[str]:
    return {path.name for path in tmp_path.iterdir()}


def test_stream_runs_a_job_and_logs_the_exchange(cli, gcode, simulator):
    url, log = simulator
    code, out, err = cli("stream", gcode, "--port", url(), "--check")
    assert code == 0, err
    assert "64 lines streamed" in out
    assert executed_file_lines(log) == list(range(1, 65))
    exchange = (gcode.parent / "sheet-03.gcode.link.log").read_text()
    assert ">>> N4G1X1Y1F3000T4" in exchange and "<<< ok" in exchange and "<<< [MSG:Enabled]" in exchange
    code, _, err = cli("stream", gcode, "--port", url(), "--resume")
    assert code == 2 and "already finished" in err


def test_check_mode_error_stops_before_anything_moves(cli, gcode, simulator, tmp_path):
    url, log = simulator
    code, out, err = cli("stream", gcode, "--port", url("&error_line=30&error_code=33"), "--check")
    assert code == 2
    assert err.startswith("fabline stream: error: ") and err.count("\n") == 1
    assert f"{gcode}:30: check mode: error:33 (the motion command has an invalid target" in err
    assert not log.exists() or executed_file_lines(log) == []
    assert "sheet-03.gcode.journal" not in written(tmp_path)


def test_port_that_does_not_exist(cli, gcode, tmp_path):
    code, _, err = cli("stream", gcode, "--port", "/dev/ttyFABLINE9")
    assert code == 2 and "port /dev/ttyFABLINE9: cannot open" in err and err.count("\n") == 1
    assert written(tmp_path) == {"sheet-03.gcode"}


def test_port_that_is_busy(cli, gcode, tmp_path):
    master, slave = pty.openpty()
    path = os.ttyname(slave)
    holder = serial.Serial(path, exclusive=True)
    try:
        code, _, err = cli("stream", gcode, "--port", path)
    finally:
        holder.close()
        os.close(master)
        os.close(slave)
    assert code == 2 and f"port {path}: cannot open" in err and "lock" in err
    assert written(tmp_path) == {"sheet-03.gcode"}


def test_device_that_is_not_grbl(cli, gcode, tmp_path):
    code, _, err = cli("stream", gcode, "--port", "loop://", "--connect-timeout", "0.5")
    assert code == 2 and "no GRBL answer within 0.5 s" in err
    assert written(tmp_path) == {"sheet-03.gcode"}


@pytest.mark.parametrize("content, message", [
    (b"G21\nG1 X" + b"9" * 90 + b" F100\n", "sheet-03.gcode:2: line too long for the controller"),
    (b"G21\nG1 X1 F100 (\xc2\xb0)\n", "sheet-03.gcode:2:13: non-ASCII byte 0xc2"),
])
def test_bad_file_is_refused_before_the_port_is_touched(cli, gcode, simulator, tmp_path, content, message):
    url, log = simulator
    gcode.write_bytes(content)
    code, _, err = cli("stream", gcode, "--port", url())
    assert code == 2 and message in err and err.count("\n") == 1
    assert written(tmp_path) == {"sheet-03.gcode"}


@pytest.mark.parametrize("option, value, message", [
    ("--baud", "0", "argument --baud: must be a positive whole number, got '0'"),
    ("--baud", "fast", "argument --baud: must be a positive whole number, got 'fast'"),
    ("--connect-timeout", "-1", "argument --connect-timeout: must be a positive number, got '-1'"),
    ("--connect-timeout", "inf", "argument --connect-timeout: must be a positive number, got 'inf'"),
])
def test_option_that_is_not_a_positive_number_is_refused(capsys, gcode, simulator, tmp_path, option, value, message):
    url, log = simulator
    with pytest.raises(SystemExit) as stop:
        main(["stream", str(gcode), "--port", url(), option, value])
    out, err = capsys.readouterr()
    assert stop.value.code == 2 and out == ""
    assert without_usage(err) == f"fabline stream: error: {message}\n"
    assert written(tmp_path) == {"sheet-03.gcode"}


def test_resume_without_a_journal(cli, gcode, simulator):
    url, _ = simulator
    code, _, err = cli("stream", gcode, "--port", url(), "--resume")
    assert code == 2 and "no journal to resume from" in err


def test_grbl_sim_rejects_unknown_fault(cli):
    code, _, err = cli("grbl-sim", "--fault", "explode=1")
    assert code == 2 and "unknown simulator option(s) ['explode']" in err


def test_keyboard_pauses_resumes_and_aborts_on_a_terminal(monkeypatch):
    from fabline.cli.link import _keyboard

    class Recorder:
        paused = False
        calls: list[str] = []

        def pause(self):
            self.paused = True
            self.calls.append("pause")

        def resume(self):
            self.paused = False
            self.calls.append("resume")

        def abort(self):
            self.calls.append("abort")

    master, slave = pty.openpty()
    terminal = os.fdopen(slave, "r")
    monkeypatch.setattr(sys, "stdin", terminal)
    saved = termios.tcgetattr(slave)
    recorder = Recorder()
    try:
        with _keyboard(recorder, interactive=True):
            for key, count in ((b"p", 1), (b" ", 2), (b"x", 2), (b"q", 3)):
                os.write(master, key)
                deadline = time.monotonic() + 5
                while len(recorder.calls) < count and time.monotonic() < deadline:
                    time.sleep(0.01)
            time.sleep(0.2)
        assert recorder.calls == ["pause", "resume", "abort"]
        assert termios.tcgetattr(slave) == saved  # the terminal is left as it was
    finally:
        terminal.close()
        os.close(master)


def test_controller_left_in_check_mode_is_taken_out_of_it(cli, gcode, simulator):
    from fabline.link.protocol_sim import get_simulator

    url, log = simulator
    port = serial.serial_for_url(url())  # a host that turns check mode on, then vanishes
    port.write(b"$C\n")
    port.close()
    name = url().split("?")[0][len("sim://"):]
    deadline = time.monotonic() + 5
    while get_simulator(name).state != "Check" and time.monotonic() < deadline:
        time.sleep(0.01)
    code, _, err = cli("stream", gcode, "--port", url())
    assert code == 0, err
    assert executed_file_lines(log) == list(range(1, 65))


def _grbl_sim_answers(*options: str) -> list[str]:
    """The lines a `fabline grbl-sim` process started with `options` answers to `$I` and `$$`."""
    command = [sys.executable, "-c", "import sys; from fabline.cli import main; sys.exit(main())", "grbl-sim",
               *options]
    server = subprocess.Popen(command, stdout=subprocess.PIPE, text=True,
                              env={**os.environ, "PYTHONPATH": str(Path(__file__).parents[2])})
    try:
        url = server.stdout.readline().strip()
        port = serial.serial_for_url(url, timeout=0.2)
        port.write(b"$I\n$$\n")
        answer, deadline = b"", time.monotonic() + 10
        while answer.count(b"ok") < 2 and time.monotonic() < deadline:
            answer += port.read(4096)
        port.close()
    finally:
        server.terminate()
        server.wait()
    return answer.decode().split("\r\n")


def test_grbl_sim_options_make_another_build_and_settings():
    """`fabline grbl-sim` is a stock build unless its options say otherwise: --build-options, --rx-buffer,
    --planner-blocks and --setting reach the controller (the other path than a sim:// URL's query)."""
    lines = _grbl_sim_answers("--build-options", "VN", "--rx-buffer", "256", "--planner-blocks", "31",
                              "--setting", "32=1")
    assert "[OPT:VN,31,256]" in lines and "$32=1" in lines and "$10=1" in lines


def test_grbl_sim_firmware_option_answers_as_a_stock_grblhal():
    """`--firmware grblhal` is grblHAL's stock build (grblHAL/core report.c: `[FIRMWARE:grblHAL]`, blocks and RX
    bytes in `[OPT:...]`), and an option still overrides one figure of it."""
    lines = _grbl_sim_answers("--firmware", "grblhal", "--rx-buffer", "512")
    assert "[FIRMWARE:grblHAL]" in lines
    assert any(line.startswith("[OPT:") and line.split(",")[1:3] == ["100", "512"] for line in lines), lines


def test_check_mode_parses_arcs_from_the_previous_target(cli, simulator, tmp_path):
    """Grbl's check mode moves nothing but parses each line from the last one's target: an arc after a move is
    checked against that move's end (the simulator used to check it from the start point and answer error:33)."""
    program = tmp_path / "arc.gcode"
    program.write_text("G21\nG90\nG0 X100.000 Y100.000\nG3 X103.150 Y96.850 I3.150 J0.000 F600\n"
                       "G3 X106.300 Y100.000 I0.000 J3.150\nM5\n", encoding="ascii")
    url, _ = simulator
    code, out, err = cli("stream", program, "--port", url(), "--check")
    assert code == 0, err


def test_a_stopped_stream_prints_a_resume_command_quoted_for_any_shell(cli, gcode, simulator):
    """A sim:// URL's ? and & would make a shell glob or background the pasted command: the hint quotes them."""
    import shlex
    import signal
    import threading

    url, log = simulator
    slow = url().replace("time_scale=500", "time_scale=1")

    def interrupt() -> None:
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline and not (log.is_file() and log.read_text().strip()):
            time.sleep(0.02)
        os.kill(os.getpid(), signal.SIGINT)  # the stream's handler stops the machine safely

    thread = threading.Thread(target=interrupt)
    thread.start()
    code, _, err = cli("stream", gcode, "--port", slow)
    thread.join()
    assert code == 1, err
    hint = err.split("continue with: ", 1)[1].strip()
    assert shlex.quote(slow) in hint and shlex.split(hint) == ["fabline", "stream", str(gcode), "--port", slow, "--resume"]


def test_grbl_sim_machine_option_makes_the_profiles_machine_so_its_programs_stream(cli, tmp_path):
    """docs/streaming.md's `fabline grbl-sim --transport tcp --machine grbl-laser` is the example job's laser: a grbl-laser
    program that a stock Grbl refuses ($32=0, 200 mm travel) streams to it over TCP."""
    program = tmp_path / "laser.gcode"
    program.write_text("; machine grbl-laser (Grbl 1.1), mode laser\nG21 G90 G17 G94\nM4 S0\nG0 X3000 Y1500\n"
                       "G1 X3010 Y1500 S800 F3000\nG0 X0 Y0\nM5\nM2\n", encoding="ascii")
    log = tmp_path / "executed.log"
    command = [sys.executable, "-c", "import sys; from fabline.cli import main; sys.exit(main())", "grbl-sim",
               "--transport", "tcp", "--machine", "grbl-laser", "--log", str(log), "--time-scale", "1000"]
    server = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                              env={**os.environ, "PYTHONPATH": str(Path(__file__).parents[2])})
    try:
        url = server.stdout.readline().strip()
        assert url.startswith("socket://127.0.0.1:"), server.stderr.read()
        code, out, err = cli("stream", program, "--port", url)
    finally:
        server.terminate()
        server.wait()
        server.stdout.close()
        server.stderr.close()
    assert code == 0, err
    assert executed_file_lines(log) == [line.file_line for line in load_program(program).lines]
