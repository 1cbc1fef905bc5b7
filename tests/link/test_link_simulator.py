"""The simulator answers like the real Grbl 1.1h in tests/data/grbl-1.1h-transcript.txt, replayed host line by host line."""

from __future__ import annotations

import re
import time
from contextlib import contextmanager
from pathlib import Path

import pytest

from fabline.link.protocol import LineSplitter, classify
from fabline.link.simulator import GrblSimulator

TRANSCRIPT = Path(__file__).parents[1] / "data" / "grbl-1.1h-transcript.txt"
REALTIME = {"ctrl-x": b"\x18", "?": b"?", "!": b"!", "~": b"~"}


def exchanges() -> list[tuple[bytes, list[str]]]:
    """(bytes the host sent, answer lines the firmware gave after it) for every '>>>' in the transcript."""
    steps: list[tuple[bytes, list[str]]] = []
    for raw in TRANSCRIPT.read_text(encoding="ascii").splitlines():
        if raw.startswith(">>> "):
            command = raw[4:].split("    #")[0]
            if command.startswith("realtime "):
                steps.append((REALTIME[command.split()[1]], []))
            else:
                steps.append((command.encode("ascii") + b"\n", []))
        elif raw.startswith("<<< "):
            steps[-1][1].append(raw[4:])
    return steps


def status_shape(line: str) -> tuple:
    """What must match in a status report: state and field names in order, buffer and override values."""
    fields = line[1:-1].split("|")
    exact = tuple(f for f in fields[1:] if f.startswith(("Bf:", "Ov:", "A:", "WCO:")))
    return fields[0], tuple(f.split(":")[0] for f in fields[1:]), exact


class Host:
    """Talks to a simulator like the capture script did: send, then read the answers."""

    def __init__(self, simulator: GrblSimulator):
        self.simulator = simulator
        self.splitter = LineSplitter()
        self.lines: list[str] = []

    def read(self, count: int, quiet: float = 0.15, timeout: float = 5.0) -> list[str]:
        """Read until `count` lines arrived, then a little more to catch extra ones."""
        deadline = time.monotonic() + timeout
        while len(self.lines) < count and time.monotonic() < deadline:
            self.lines += self.splitter.feed(self.simulator.read(4096, 0.02))
        end = time.monotonic() + quiet
        while time.monotonic() < end:
            self.lines += self.splitter.feed(self.simulator.read(4096, 0.02))
        lines, self.lines = self.lines, []
        return lines

    def status(self) -> str:
        self.simulator.receive(b"?")
        return self.read(1, quiet=0)[0]


@pytest.fixture
def host():
    simulator = GrblSimulator(time_scale=1.0)
    simulator.attach()
    yield Host(simulator)
    simulator.close()


def test_transcript_is_present_and_complete():
    steps = exchanges()
    assert len(steps) == 44 and sum(len(answers) for _, answers in steps) == 98
    assert steps[0] == (b"\x18", ["Grbl 1.1h ['$' for help]"])


def test_simulator_replays_the_real_firmware_transcript(host):
    pending = 0  # answers of the real firmware that arrived only after later sends (the late ok for M5)
    for sent, expected in exchanges():
        if sent == b"~":
            while not host.status().startswith("<Hold:0"):  # the capture waited long enough for the hold to end
                time.sleep(0.05)
        host.simulator.receive(sent)
        if sent == b"M5\n":
            pending = 1
            time.sleep(0.1)
            continue
        wanted = len(expected)
        got = host.read(wanted, quiet=0.05 if wanted else 0.1)
        if pending and sent == b"?":
            got = [line for line in got if line != "ok"]
        if pending and expected and expected[0] == "ok":
            pending = 0
            got = ["ok"] + got if got[:1] != ["ok"] else got
        assert len(got) == len(expected), (sent, got, expected)
        for answer, truth in zip(got, expected):
            if truth.startswith("<"):
                assert status_shape(answer) == status_shape(truth), (sent, answer, truth)
            else:
                assert answer == truth, (sent, answer, truth)


def test_status_report_values_follow_the_motion(host):
    for line in (b"$10=3\n", b"$32=1\n", b"$120=1000\n", b"$121=1000\n", b"M4S500\n", b"G1X10Y10F3000\n"):
        host.simulator.receive(line)  # 1000 mm/s^2: at full speed after 6 ms, the status shows the nominal feed
    assert host.read(6) == ["ok"] * 6
    time.sleep(0.3)
    report = classify(host.status()).status
    assert report.state == "Run"
    assert report.feed == pytest.approx(707, abs=1)  # 500 mm/min per axis on a 45 degree move
    assert report.speed == pytest.approx(118, abs=1)  # laser M4: power scales with speed, S500 * 707/3000
    assert report.mpos[0] == pytest.approx(report.mpos[1]) and 0 < report.mpos[0] < 10


def test_receive_buffer_holds_128_bytes_and_overflow_is_counted():
    simulator = GrblSimulator(time_scale=1.0)
    try:
        simulator.attach()
        simulator.receive(b"G4P100\n")  # a dwell keeps the parser waiting
        time.sleep(0.05)
        simulator.receive(b"X" * 130)
        assert simulator.overflowed == 2
        report = classify(Host(simulator).status()).status
        assert report.state == "Idle"
    finally:
        simulator.close()


@contextmanager
def logged(tmp_path, time_scale: float, lines: bytes):
    """A simulator with an executed-line log, sent `lines` and every one acknowledged; yields (host, log)."""
    log = tmp_path / "executed.log"
    simulator = GrblSimulator(time_scale=time_scale, executed_log=log)
    try:
        simulator.attach()
        host = Host(simulator)
        simulator.receive(lines)
        assert host.read(lines.count(b"\n"), timeout=10) == ["ok"] * lines.count(b"\n")
        yield host, log
    finally:
        simulator.close()


def test_executed_log_records_lines_in_order(tmp_path):
    with logged(tmp_path, 100.0, b"N1G21\nN2G1X5F600\nN3G1Y5\nN4M5\n") as (host, log):
        assert re.match(r"<Idle\|MPos:5\.000,5\.000,0\.000", wait_for(host, "<Idle"))
        assert log.read_text().splitlines() == ["N1G21", "N2G1X5F600", "N3G1Y5", "N4M5"]


def test_jog_cancel_stops_a_jog_and_keeps_the_position(host):
    from fabline.link.protocol import JOG_CANCEL

    host.simulator.receive(b"$J=G91X50F600\n")
    assert host.read(1) == ["ok"]
    time.sleep(0.3)
    assert host.status().startswith("<Jog|")
    host.simulator.receive(JOG_CANCEL)
    report = classify(host.status()).status
    assert report.state == "Idle" and 0 < report.mpos[0] < 50


def test_settings_configure_the_simulated_machine_like_its_profile():
    from fabline.machine import load_machine

    settings = load_machine("grbl-laser").controller_settings()
    simulator = GrblSimulator(time_scale=1.0, settings=settings)
    try:
        simulator.attach()
        host = Host(simulator)
        simulator.receive(b"$$\n")
        reported = dict(line[1:].split("=") for line in host.read(len(simulator.settings) + 1) if line.startswith("$"))
        assert float(reported["110"]) == 12000 and float(reported["120"]) == 800 and reported["32"] == "1"
        simulator.receive(b"G1X100Y100F6000\n")
        assert host.read(1) == ["ok"]
        time.sleep(0.2)
        assert classify(host.status()).status.feed == pytest.approx(6000, abs=1)  # not Grbl's default 500 mm/min
    finally:
        simulator.close()


def test_unknown_settings_are_refused_by_name():
    from serial import SerialException, serial_for_url

    with pytest.raises(ValueError, match=r"\$999"):
        GrblSimulator(settings={999: 1.0})
    with pytest.raises(SerialException, match=r"\$999"):
        serial_for_url("sim://bad-settings?settings=110:12000,999:1")


def test_line_time_delays_each_answer_but_not_realtime_commands():
    """The firmware's parse-and-plan time: each line's ok comes line_time after its newline, one line at a
    time, while a status request is still answered at once (real-time bytes bypass the line parser)."""
    simulator = GrblSimulator(time_scale=100.0, line_time=0.2)
    try:
        simulator.attach()
        host = Host(simulator)
        start = time.monotonic()
        simulator.receive(b"G21\nG90\n")
        assert classify(host.status()).status.state == "Idle"  # answered while the first line is parsed
        assert time.monotonic() - start < 0.15
        assert host.read(1, quiet=0) == ["ok"]
        first = time.monotonic() - start
        assert host.read(1, quiet=0) == ["ok"]
        second = time.monotonic() - start
        assert 0.18 <= first < 0.35 and 0.38 <= second < 0.6
    finally:
        simulator.close()


def test_a_non_motion_line_is_executed_when_it_is_acknowledged(tmp_path):
    """With nothing in the planner, Grbl executes a non-motion line (M2, G21, ...) in the parser, before its ok:
    a reset right after the ok must not lose it (a resume would skip it: it was acknowledged on an idle machine)."""
    log = tmp_path / "executed.log"
    simulator = GrblSimulator(time_scale=100.0, executed_log=log, tick=0.5)  # a slow main loop widens the window
    try:
        simulator.attach()
        host = Host(simulator)
        simulator.receive(b"N1G21\n")
        assert host.read(1, quiet=0) == ["ok"]
        simulator.receive(b"\x18")
        assert log.read_text().splitlines() == ["N1G21"]
    finally:
        simulator.close()


def wait_for(host: Host, prefix: str, timeout: float = 10.0) -> str:
    """Poll status reports until one starts with `prefix`; return it."""
    deadline = time.monotonic() + timeout
    while True:
        report = host.status()
        if report.startswith(prefix) or time.monotonic() > deadline:
            return report
        time.sleep(0.01)


def test_a_stock_build_reports_no_line_numbers_and_its_options(host):
    """Grbl 1.1h as compiled from gnea/grbl: `$I` says [OPT:V,15,128] and status reports carry no `Ln:` (line
    numbers are the USE_LINE_NUMBERS compile option), as in the captured transcript, even for N-numbered lines."""
    host.simulator.receive(b"$I\n")
    assert host.read(3) == ["[VER:1.1h.20190830:]", "[OPT:V,15,128]", "ok"]
    host.simulator.receive(b"N10G1X20F600\n")
    assert host.read(1) == ["ok"]
    report = wait_for(host, "<Run")
    assert report.startswith("<Run") and "Ln:" not in report and "|Bf:" not in report


def test_a_build_with_line_numbers_and_bigger_buffers_through_the_sim_url():
    from serial import serial_for_url

    import fabline.link  # noqa: F401  (registers sim://)
    from fabline.link.protocol_sim import close_simulator, get_simulator

    port = serial_for_url("sim://build-vn?build_options=VN&planner_blocks=31&rx_buffer=256&settings=10:3", timeout=0.05)
    try:
        host = Host(get_simulator("build-vn"))
        host.simulator.receive(b"$I\n")
        assert host.read(3) == ["[VER:1.1h.20190830:]", "[OPT:VN,31,256]", "ok"]
        host.simulator.receive(b"N10G1X20F600\n")
        assert host.read(1) == ["ok"]
        report = wait_for(host, "<Run")
        assert "|Ln:10|" in report and "|Bf:30,256|" in report
    finally:
        port.close()
        close_simulator("build-vn")


def test_feed_hold_while_idle_is_a_completed_hold(host):
    """gnea/grbl protocol.c: "If IDLE, Grbl is not in motion. Simply indicate suspend state and hold is complete."
    Lines sent during the hold are planned but do not move until cycle start."""
    host.simulator.receive(b"!")
    assert host.status().startswith("<Hold:0|")
    host.simulator.receive(b"G1X5F600\n")
    assert host.read(1) == ["ok"]
    time.sleep(0.1)
    assert host.status().startswith("<Hold:0|MPos:0.000,0.000,0.000")
    host.simulator.receive(b"~")
    assert wait_for(host, "<Run").startswith("<Run")


def test_a_hold_that_outlasts_the_last_planned_block_completes():
    """Decelerating into a hold, the machine may reach the end of the last block it holds: it stands still then,
    and Grbl reports Hold:0 (a Hold:1 forever kept a halting host waiting for an hour). Machine time is stepped."""
    simulator = GrblSimulator(settings={120: 0.5}, threaded=False)  # 0.5 mm/s^2: a 2 mm move is a 4 s triangle
    try:
        simulator.attach()
        host = Host(simulator)
        simulator.receive(b"G1X2F600\n")
        simulator.step(0.0)
        assert host.read(1, quiet=0) == ["ok"]
        simulator.step(2.5)  # past the peak (1 mm/s at X1): braking already, to stop at X2
        assert host.status().startswith("<Run")
        simulator.receive(b"!")
        simulator.step(1.0)
        assert host.status().startswith("<Hold:1|MPos:1.9")  # still slowing down, 1.5 s to go
        simulator.step(1.0)
        assert host.status().startswith("<Hold:0|MPos:2.000,0.000")
        simulator.receive(b"~")
        simulator.step(0.1)
        assert host.status().startswith("<Idle")
    finally:
        simulator.close()


def test_m0_pauses_after_the_planner_empties_and_m1_is_ignored(tmp_path):
    """Grbl 1.1: M0 waits for the planner to empty, then holds (Hold:0) until cycle start; M1 (optional stop) is
    ignored, there being no optional-stop switch."""
    with logged(tmp_path, 20.0, b"N1G1X5F600\nN2M1\nN3G1X6\nN4M0\nN5G1X7\n") as (host, log):
        assert wait_for(host, "<Hold:0").startswith("<Hold:0|MPos:6.000,0.000,0.000")
        time.sleep(0.2)
        assert log.read_text().splitlines() == ["N1G1X5F600", "N2M1", "N3G1X6", "N4M0"]
        host.simulator.receive(b"~")
        assert wait_for(host, "<Idle").startswith("<Idle|MPos:7.000")
        assert log.read_text().splitlines()[-1] == "N5G1X7"
