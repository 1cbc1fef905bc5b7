"""The fault campaign: 200 random cases on a stock Grbl 1.1h simulator (no `Ln:` in status reports).

Programs with retraced paths, repeated segments, arcs, dwells and spindle changes, jobs starting away from work
zero; each interrupted once at a random point by a feed hold (abort), SIGKILL of a host process, a disconnect,
a soft reset or an alarm; then the documented recovery (`--resume`, `--unlock` after an alarm or a reset; when
fabline refuses because the stopped position fits several lines, the operator's `--from-line`, chosen here from
the simulator's truth and required to be one of the lines fabline named). Every case must end with every
program line executed exactly once, in order (a line a resume re-sent from within 0.01 mm of its end, which moved
microns, counts once: `campaign_cases.cut_once`). The cases are generated from a fixed seed
(tests/link/campaign_cases.py, shared with benchmarks/resume_bench.py).
"""

from __future__ import annotations

import os
import random
import re
import signal
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import serial

from fabline.errors import FablineError
from fabline.link import SimulatorServer, Streamer, executed_file_lines
from fabline.machine import load_program

from .campaign_cases import (CASES, FINISHED, HOST, MICRONS, REFUSED, REPO, SETTINGS, cases, first_not_cut, move_to,
                             run_case)


def test_fault_campaign_on_a_stock_build_every_line_exactly_once_or_an_ambiguity_named(tmp_path, capsys):
    outcomes: Counter = Counter()
    server_log = tmp_path / "server.log"
    started = time.monotonic()
    with SimulatorServer(log=server_log, time_scale=50, faults={"settings": SETTINGS}) as server:
        for number, rng in cases():
            outcome = run_case(number, rng, tmp_path, server, server_log)
            if REFUSED in outcome:
                outcomes[f"{outcome[0]}: refused (ambiguous line, named), then --from-line"] += 1
            elif MICRONS in outcome:
                outcomes[f"{outcome[0]}: resumed, a line re-sent from its end (microns)"] += 1
            elif FINISHED in outcome:
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
