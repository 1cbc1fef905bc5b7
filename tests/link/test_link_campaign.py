"""The fault campaign: 200 random cases on a stock Grbl 1.1h simulator (no `Ln:` in status reports).

Programs with retraced paths, repeated segments, arcs, dwells and spindle changes, jobs starting away from work
zero; each interrupted once at a random point by a feed hold (abort), SIGKILL of a host process, a disconnect,
a soft reset or an alarm; then the documented recovery (`--resume`, `--unlock` after an alarm or a reset; when
fabline refuses because the stopped position fits several lines, the operator's `--from-line`, chosen here from
the simulator's truth and required to be one of the lines fabline named). Every case must end with every
program line executed exactly once, in order. The cases are generated from a fixed seed.
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
from collections import Counter
from pathlib import Path

import serial

from fabline.errors import FablineError
from fabline.link import SimulatorServer, Streamer, StreamInterrupted, executed_file_lines, read_journal
from fabline.link.protocol_sim import close_simulator, get_simulator
from fabline.machine import load_program

REPO = Path(__file__).resolve().parents[2]
CASES = 200
FAULTS = ("hold",) * 3 + ("alarm",) * 2 + ("reset",) * 2 + ("disconnect", "reconnect", "kill")
"""Weights: a killed host costs a process start (about 1 s on a loaded machine), so it is one case in ten."""
SETTINGS = "32:1,110:20000,111:20000,130:2000,131:2000"
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


def recover(url: str, program: Path, executed, outcome: list[str]) -> None:
    """The documented recovery: --resume --unlock; on a refusal that names lines, the operator's --from-line."""
    start_line = None
    for _ in range(6):
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
                outcome.append("refused, named the line range; resumed --from-line")
                if truth is None:
                    return  # the operator sees the sheet is fully cut: nothing to resume
                start_line = truth
            elif start_line is None:  # a journal that says the last run stopped undecided: the line it named before
                start_line = first_not_cut(program, executed())
                if start_line is None:
                    outcome.append("refused, named the line range; resumed --from-line")
                    return
    raise AssertionError("no recovery after six attempts")


def run_case(number: int, rng: random.Random, tmp: Path, server: SimulatorServer, server_log: Path) -> list[str]:
    fault = rng.choice(FAULTS)
    start = (0.0, 0.0) if rng.random() < 0.3 else (round(rng.uniform(100, 900), 3), round(rng.uniform(100, 900), 3))
    program = tmp / f"case{number}.gcode"
    program.write_text("\n".join(random_program(rng, start)) + "\n", encoding="ascii")
    lines = load_program(program).lines
    motion = [line.file_line for line in lines if re.match(r"G[0-3](?!\d)", line.command) and "X" in line.command]
    outcome = [fault]
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
            outcome.append("finished before the fault")
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
                    recover(url, program, executed, outcome)
            except StreamInterrupted as exc:
                if exc.reason == "undecided":
                    truth = first_not_cut(program, executed())
                    assert truth in named_lines(str(exc)), (str(exc), truth)
                recover(url, program, executed, outcome)
        finally:
            close_simulator(name)
    assert executed() == [line.file_line for line in lines], f"case {number} ({fault}): not every line exactly once"
    return outcome


def test_fault_campaign_on_a_stock_build_every_line_exactly_once_or_an_ambiguity_named(tmp_path, capsys):
    rng = random.Random(1515)
    outcomes: Counter = Counter()
    server_log = tmp_path / "server.log"
    started = time.monotonic()
    with SimulatorServer(log=server_log, time_scale=50, faults={"settings": SETTINGS}) as server:
        for number in range(CASES):
            outcome = run_case(number, random.Random(rng.random()), tmp_path, server, server_log)
            if "refused, named the line range; resumed --from-line" in outcome:
                outcomes[f"{outcome[0]}: refused (ambiguous line, named), then --from-line"] += 1
            elif "finished before the fault" in outcome:
                outcomes[f"{outcome[0]}: finished before the fault"] += 1
            else:
                outcomes[f"{outcome[0]}: resumed exactly"] += 1
    with capsys.disabled():
        print(f"\nfault campaign: {CASES} cases in {time.monotonic() - started:.0f} s, every line exactly once")
        for key in sorted(outcomes):
            print(f"  {key:<62} {outcomes[key]:>4}")
    assert sum(outcomes.values()) == CASES


# ----- journals that lost records -----------------------------------------------------------------------------
LOSS_KILLS = 6
"""Killed streams whose journal then loses records: even cases keep only a first part (cut at every k-th record
boundary in turn, first just after the send of the line one 255-line tag cycle before the last one parsed: the
tag fits it, only the position tells), odd cases lose a block from the middle. The first case's second cut is the
probe's half journal, which a tag looked up in the 255 lines past the last `ok` resumed a tag cycle early."""


def long_program(start: tuple[float, float], count: int = 700) -> list[str]:
    """A sawtooth far longer than the 255 tags `$G` can tell apart; no point is passed twice."""
    x, y = start
    cuts = [f"G1 X{x + 0.3 * i:.3f} Y{y + 2 * (i % 2):.3f}" for i in range(1, count + 1)]
    return ["G21", "G90", "G17", "G94", f"G0 X{x:.3f} Y{y:.3f}", "M4 S800", "F3000"] + cuts + ["M5", "M2"]


def wait_idle(url: str) -> None:
    """Wait until the controller has finished the lines a killed host left in its buffers."""
    port = serial.serial_for_url(url, timeout=0.02)
    try:
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            port.write(b"?")
            time.sleep(0.05)
            if b"<Idle" in port.read(4096):
                return
        raise AssertionError("the controller did not come to rest")
    finally:
        port.close()


def resume_lost(url: str, program: Path, executed, refusal: str = "") -> str:
    """One --resume over a journal that lost records: 'refused' (one line naming a line to continue from by hand,
    and nothing run; with `refusal`, for that reason) or 'completed' (every line exactly once)."""
    before = executed()
    try:
        result = Streamer(url, status_interval=0.02, connect_timeout=3).run(program, resume=True)
    except FablineError as exc:
        message = str(exc)
        assert "\n" not in message and "--resume --from-line N" in message and re.search(r"file line \d+|no line",
                                                                                        message), message
        assert executed() == before, f"refused, but ran lines: {message}"
        assert refusal in message, message
        return "refused"
    assert not refusal, f"resumed where it must refuse ({refusal!r})"
    assert result.completed and executed() == [line.file_line for line in load_program(program).lines], \
        "a resume over a journal that lost records ran lines twice or skipped some"
    return "completed"


def test_a_journal_that_lost_its_end_or_a_middle_refuses_naming_a_line_or_resumes_exactly_once(tmp_path, capsys):
    rng = random.Random(2525)
    server_log = tmp_path / "server.log"
    outcomes: Counter = Counter()
    with SimulatorServer(log=server_log, time_scale=50, faults={"settings": SETTINGS}) as server:
        for case in range(LOSS_KILLS):
            start = (round(rng.uniform(100, 500), 3), round(rng.uniform(100, 500), 3))
            program = tmp_path / f"loss{case}.gcode"
            program.write_text("\n".join(long_program(start)) + "\n", encoding="ascii")
            lines = load_program(program).lines
            already = len(executed_file_lines(server_log))
            executed = lambda: executed_file_lines(server_log)[already:]  # noqa: E731
            move_to(server.url, start)
            journal = Path(f"{program}.journal")
            host = subprocess.Popen([sys.executable, "-c", HOST, server.url, str(program)], stderr=subprocess.PIPE,
                                    env={**os.environ, "PYTHONPATH": str(REPO)})
            target, deadline = rng.randrange(450, 650), time.monotonic() + 60
            while host.poll() is None and time.monotonic() < deadline and (
                    not journal.exists() or journal.read_text().count('"event":"ok"') < target):
                time.sleep(0.005)
            assert host.poll() is None, host.communicate()[1]
            host.send_signal(signal.SIGKILL)
            host.wait()
            wait_idle(server.url)  # the controller finishes what it holds: what ran before any resume is known
            whole = journal.read_text().splitlines(keepends=True)
            records = [row for row in whole if row.endswith("\n")]  # a torn last one is not a boundary
            if case % 2 == 0:
                step = len(records) // rng.randrange(5, 8)
                keeps = [records[:cut] for cut in range(step if case else len(records) // 2, len(records), step)]
                keeps.append(records[:-1])
                # a cut just after the line one tag cycle before the last one parsed was sent: the tag fits that
                # line, but the controller does not stand where the program is after it
                early = f'{{"event":"sent","n":{len(executed()) - 1 - 255},'
                collision = next(number for number, row in enumerate(records) if row.startswith(early))
                keeps.insert(0, records[:collision + 1])
                kind = "lost end"
            else:
                first = rng.randrange(2, len(records) - 60)
                keeps = [records[:first] + records[first + rng.randrange(1, len(records) - first - 20):]]
                kind = "lost middle"
            verdict = None
            for number, kept in enumerate(keeps):
                journal.write_text("".join(kept), encoding="ascii")
                verdict = resume_lost(server.url, program, executed,
                                      "where the program is after" if kind == "lost end" and number == 0 else "")
                outcomes[f"{kind}: {verdict}"] += 1
                if verdict == "completed":
                    break
            if case == 0:
                assert outcomes["lost end: refused"] >= 1  # the probe's half journal is refused, not resumed
            if verdict != "completed":  # the operator's --from-line from the part (here: the simulator's truth)
                truth = first_not_cut(program, executed())
                if truth is not None:
                    assert Streamer(server.url, status_interval=0.02).run(program, resume=True,
                                                                          start_line=truth).completed
            assert executed() == [line.file_line for line in lines], f"case {case}: not every line exactly once"
    with capsys.disabled():
        print(f"\njournal loss: {LOSS_KILLS} killed streams, {sum(outcomes.values())} resumes")
        for key in sorted(outcomes):
            print(f"  {key:<40} {outcomes[key]:>4}")
