"""The fault campaign's cases, shared by tests/link/test_link_campaign.py and benchmarks/resume_bench.py: random laser
programs on a stock Grbl 1.1h simulator, each interrupted once by a feed hold, an alarm, a soft reset, a disconnect
or a killed host, then recovered as documented (`--resume --unlock`; the operator's `--from-line` where fabline
refuses, naming candidate lines: chosen from the simulator's truth and required to be one of those named).
"""

from __future__ import annotations

import math
import os
import random
import re
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import serial

import fabline
from fabline.errors import FablineError
from fabline.link import SimulatorServer, Streamer, StreamInterrupted, executed_file_lines, read_journal
from fabline.link.protocol_sim import close_simulator, get_simulator
from fabline.machine import load_program

REPO = Path(fabline.__file__).resolve().parents[1]
"""The fabline the caller runs: a killed host process runs it too."""
CASES = 200
FAULTS = ("hold",) * 3 + ("alarm",) * 2 + ("reset",) * 2 + ("disconnect", "reconnect", "kill")
"""Weights: a killed host costs a process start (about 1 s on a loaded machine), so it is one case in ten."""
SETTINGS = "32:1,110:20000,111:20000,130:2000,131:2000"
REFUSED = "refused, named the line range; resumed --from-line"
FINISHED = "finished before the fault"
MICRONS = "a line re-sent from within the tolerance of its end"
TOLERANCE = 0.01
"""mm: a line re-run by a resume that found the machine this close to its end moved no more than this."""
HOST = ("import sys; from fabline.link import Streamer; "
        "Streamer(sys.argv[1], status_interval=0.02).run(sys.argv[2])")


def random_program(rng: random.Random, start: tuple[float, float]) -> list[str]:
    """A laser program near `start`: straight cuts, paths cut out and back, one segment cut back and forth, arcs,
    dwells and power changes, every coordinate absolute and to 0.001 mm."""
    x, y = start
    lines = ["G21", "G90", "G17", "G94", f"G0 X{x:.3f} Y{y:.3f}", "M4 S800", f"F{rng.choice((600, 1200, 2400))}"]

    def to(nx: float, ny: float, word: str = "G1") -> None:
        nonlocal x, y
        x, y = round(nx, 3), round(ny, 3)
        lines.append(f"{word} X{x:.3f} Y{y:.3f}")

    def near() -> tuple[float, float]:
        return start[0] + rng.uniform(-10, 10), start[1] + rng.uniform(-10, 10)

    while len(lines) < rng.randrange(16, 40):
        shape = rng.choice(("cut", "cut", "retrace", "repeat", "arc", "travel", "dwell", "power"))
        if shape == "cut":
            to(*near())
        elif shape == "travel":
            to(*near(), word="G0")
        elif shape == "retrace":
            path = [(x, y)] + [near() for _ in range(rng.randrange(2, 8))]
            for point in path[1:] + path[-2::-1]:
                to(*point)
        elif shape == "repeat":
            a, b = (x, y), near()
            for _ in range(rng.randrange(1, 4)):
                to(*b)
                to(*a)
        elif shape == "arc":
            radius, angle = rng.uniform(2, 10), rng.uniform(0, 2 * math.pi)
            cx, cy = x - radius * math.cos(angle), y - radius * math.sin(angle)
            end = angle + rng.choice((-1, 1)) * rng.uniform(0.5, 5.5)
            ex, ey = round(cx + radius * math.cos(end), 3), round(cy + radius * math.sin(end), 3)
            lines.append(f"{rng.choice(('G2', 'G3'))} X{ex:.3f} Y{ey:.3f} I{cx - x:.3f} J{cy - y:.3f}")
            x, y = ex, ey
        elif shape == "dwell":
            lines.append("G4 P0.05")
        else:
            lines += ["M5", f"M4 S{rng.randrange(200, 1000)}"]
    return lines + ["M5", f"G0 X{start[0]:.3f} Y{start[1]:.3f}", "M2"]


def move_to(url: str, start: tuple[float, float]) -> None:
    """Put the machine at `start` (work coordinates) before the job, as an operator jogging to the sheet would."""
    port = serial.serial_for_url(url, timeout=0.02)
    try:
        port.write(b"\x18")
        time.sleep(0.05)
        port.write(f"$X\nG90G0X{start[0]:.3f}Y{start[1]:.3f}Z0\n".encode("ascii"))
        deadline, buffer = time.monotonic() + 10, b""
        while time.monotonic() < deadline:
            port.write(b"?")
            buffer += port.read(4096)
            if re.search(rb"<Idle\|MPos:" + f"{start[0]:.3f},{start[1]:.3f}".encode("ascii"), buffer):
                return
            buffer = buffer[-200:]
        raise AssertionError(f"the machine did not reach {start}")
    finally:
        port.close()


def first_not_cut(program: Path, executed: list[int]) -> int | None:
    """The file line to restart from, by the simulator's truth; None when every line ran."""
    lines = [line.file_line for line in load_program(program).lines]
    assert executed == lines[: len(executed)], "executed out of order or twice before the recovery"
    return lines[len(executed)] if len(executed) < len(lines) else None


def named_lines(message: str) -> list[int | None]:
    """The file lines a refusal names: 'one of 12, 15, the end' (None: all done) or a range 'file lines 12..40'."""
    if "(one of " in message:
        return [None if n == "the end" else int(n) for n in message.split("(one of ")[1].split(")")[0].split(", ")]
    match = re.search(r"file lines (\d+)\.\.(\d+)", message)
    return list(range(int(match.group(1)), int(match.group(2)) + 1)) if match else []


def recover(url: str, program: Path, executed, outcome: list[str], resumes: list | None = None,
            simulator=None) -> None:
    """The documented recovery: --resume --unlock; on a refusal that names lines, the operator's --from-line. Before
    each attempt, (lines executed, the `simulator`'s exact position) goes to `resumes`."""
    start_line = None
    for _ in range(6):
        if simulator is not None:
            resumes.append((len(executed()), simulator.position))
        try:
            result = Streamer(url, status_interval=0.02, connect_timeout=3).run(
                program, resume=True, unlock=True, start_line=start_line)
            assert result.completed
            return
        except (StreamInterrupted, FablineError) as exc:
            message = str(exc)
            if "cannot tell" not in message and "could not tell" not in message and "passes more than once" not in message:
                raise
            candidates = named_lines(message)
            if start_line is None and candidates:
                truth = first_not_cut(program, executed())
                assert truth in candidates, (message, truth)
                outcome.append(REFUSED)
                if truth is None:
                    return  # the operator sees the sheet is fully cut: nothing to resume
                start_line = truth
            elif start_line is None:  # a journal that says the last run stopped undecided: the line it named before
                start_line = first_not_cut(program, executed())
                if start_line is None:
                    outcome.append(REFUSED)
                    return
    raise AssertionError("no recovery after six attempts")


def cut_once(program: Path, executed: list[int], resumes: list, outcome: list[str]) -> list[int]:
    """The executed file lines, a line run again first thing by a resume dropped where the machine stood within
    TOLERANCE of its end when the resume began (the simulator's own position, exact): a stop at a line's end or
    microns short of it cannot be told apart from three-decimal positions, so fabline re-sends the line, which then
    moves microns, as the brief for a resume wants; such a case is marked MICRONS in `outcome`."""
    ends = {}
    for line in load_program(program).lines:
        words = dict(re.findall(r"([XY])(-?[0-9.]+)", line.source))
        if "X" in words and "Y" in words:
            ends[line.file_line] = (float(words["X"]), float(words["Y"]))
    repeats = {count for count, position in resumes
               if 0 < count < len(executed) and executed[count] == executed[count - 1] and executed[count] in ends
               and math.dist(position[:2], ends[executed[count]]) <= TOLERANCE}
    if repeats:
        outcome.append(MICRONS)
    return [line for number, line in enumerate(executed) if number not in repeats]


def run_case(number: int, rng: random.Random, tmp: Path, server: SimulatorServer, server_log: Path) -> list[str]:
    fault = rng.choice(FAULTS)
    start = (0.0, 0.0) if rng.random() < 0.3 else (round(rng.uniform(100, 900), 3), round(rng.uniform(100, 900), 3))
    program = tmp / f"case{number}.gcode"
    program.write_text("\n".join(random_program(rng, start)) + "\n", encoding="ascii")
    lines = load_program(program).lines
    motion = [line.file_line for line in lines if re.match(r"G[0-3](?!\d)", line.command) and "X" in line.command]
    outcome, resumes = [fault], []
    if fault == "kill":
        url, already = server.url, len(executed_file_lines(server_log))
        executed = lambda: executed_file_lines(server_log)[already:]  # noqa: E731
        move_to(url, start)
        journal = Path(f"{program}.journal")
        host = subprocess.Popen([sys.executable, "-c", HOST, url, str(program)], stderr=subprocess.PIPE,
                                env={**os.environ, "PYTHONPATH": str(REPO)})
        target, deadline = rng.randrange(1, len(lines) - 5), time.monotonic() + 30
        while host.poll() is None and time.monotonic() < deadline and (
                not journal.exists() or journal.read_text().count('"event":"ok"') < target):
            time.sleep(0.005)
        host.send_signal(signal.SIGKILL)
        host.wait()
        if read_journal(journal).finished:
            outcome.append(FINISHED)
        else:
            recover(url, program, executed, outcome)
    else:
        name = f"c{number}-{uuid.uuid4().hex[:6]}"
        log = tmp / f"{name}.log"
        options = {"time_scale": rng.choice((200, 400, 800)), "log": log, "settings": SETTINGS}
        if fault == "alarm":
            options["alarm_line"] = rng.choice(motion)
        if fault in ("disconnect", "reconnect"):
            options["drop_at"] = rng.randrange(60, sum(len(line.wire) for line in lines) - 20)
        url = f"sim://{name}?" + "&".join(f"{key}={value}" for key, value in options.items())
        executed = lambda: executed_file_lines(log) if log.exists() else []  # noqa: E731
        try:
            move_to(url, start)
            streamer = Streamer(url, status_interval=0.02, connect_timeout=3,
                                reconnect_timeout=3 if fault == "reconnect" else 0)
            stop_at = rng.randrange(2, len(lines) - 2)

            def on_progress(progress) -> None:
                if progress.acked >= stop_at and fault == "hold":
                    streamer.abort()
                elif progress.acked >= stop_at and fault == "reset" and not outcome[1:]:
                    outcome.append("reset sent")
                    get_simulator(name).receive(b"\x18")

            try:
                result = streamer.run(program, on_progress=on_progress)
                if not result.completed:
                    recover(url, program, executed, outcome, resumes, get_simulator(name))
            except StreamInterrupted as exc:
                if exc.reason == "undecided":
                    truth = first_not_cut(program, executed())
                    assert truth in named_lines(str(exc)), (str(exc), truth)
                recover(url, program, executed, outcome, resumes, get_simulator(name))
        finally:
            close_simulator(name)
    assert cut_once(program, executed(), resumes, outcome) == [line.file_line for line in lines], \
        f"case {number} ({fault}): not every line exactly once"
    return outcome


def cases(count: int = CASES, seed: int = 1515):
    """(number, that case's own random generator) for the campaign's `count` cases from `seed`."""
    rng = random.Random(seed)
    for number in range(count):
        yield number, random.Random(rng.random())
