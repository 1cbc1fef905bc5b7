"""The simulator as its own process over a real pseudo-terminal: pacing like a 115200-baud line, exact execution."""

from __future__ import annotations

import pytest

from fabline.link import SimulatorServer, Streamer, executed_file_lines
from fabline.link.server import _Wire
from fabline.machine import load_program


def test_pty_link_is_paced_like_115200_baud_and_runs_the_program_exactly(tmp_path):
    program = tmp_path / "job.gcode"
    program.write_text("G21\nG90\nM4 S500\n" + "".join(f"G1 X{i % 9}.125 Y{i % 4}.5 F6000\n" for i in range(300))
                       + "M5\n", encoding="ascii")
    log = tmp_path / "executed.log"
    with SimulatorServer(log=log, time_scale=1e4, transport="pty", baud=115200, faults={"settings": "32:1"}) as server:
        assert server.url.startswith("/dev/")
        result = Streamer(server.url).run(program)
    assert result.completed
    assert executed_file_lines(log) == [line.file_line for line in load_program(program).lines]
    assert result.bytes_sent / result.elapsed <= 11520 * 1.05  # never faster than the serial line


def test_wire_never_exceeds_the_byte_rate():
    import time

    wire = _Wire(115200)
    start, crossed = time.monotonic(), 0
    while crossed < 5000:
        crossed += wire.take(64)
    assert crossed / (time.monotonic() - start) <= 11520 * 1.01


def test_server_reports_a_bad_option():
    with pytest.raises(Exception, match="unknown simulator option"):
        SimulatorServer(faults={"explode": 1}).start()


def test_dropped_tcp_connection_is_reconnected_and_the_job_finishes(tmp_path):
    program = tmp_path / "job.gcode"
    program.write_text("G21\nG90\nM4 S500\n" + "".join(f"G1 X{i % 9}.25 Y{i % 4}.5 F3000\n" for i in range(200))
                       + "M5\n", encoding="ascii")
    log = tmp_path / "executed.log"
    with SimulatorServer(log=log, time_scale=200, faults={"drop_at": "1500,4000", "settings": "32:1"}) as server:
        result = Streamer(server.url, status_interval=0.05, reconnect_timeout=10).run(program)
    assert result.completed
    assert executed_file_lines(log) == [line.file_line for line in load_program(program).lines]
    journal = (tmp_path / "job.gcode.journal").read_text()
    assert journal.count('"event":"resume"') == 2 and journal.count("connection lost") == 2
