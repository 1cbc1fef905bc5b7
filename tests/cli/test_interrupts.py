"""Every interrupt is all-or-nothing (issue 25, item 8): Ctrl-C (SIGINT to the process group, as a terminal sends
it) and SIGTERM (to the command, as `kill` sends it) stop `unroll` and `export` with exit 130 / 143 and one line on
stderr, and leave the output folder byte for byte as it was: the outputs of an earlier run that were being
replaced are put back, new ones are gone. The signal is sent while the command loads and again at the moment it
is replacing the earlier run's files (when the first backup link of a replaced file appears)."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from fabline import fileio
from fabline.fileio import TEMP_PATTERN, OutputSet, atomic_output

REPO = Path(__file__).resolve().parents[2]


def _fabline(*args, cwd) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, (os.environ.get("PYTHONPATH"), str(REPO)))))
    return subprocess.Popen([sys.executable, "-m", "fabline", *map(str, args)], cwd=cwd, env=env, text=True,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True)


def _snapshot(folder: Path) -> dict:
    return {p.relative_to(folder): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def earlier(tmp_path_factory):
    """An earlier run's folder: a catenoid's network, parts with 64 strip previews, nesting and export."""
    folder = tmp_path_factory.mktemp("earlier")
    steps = (("design", "catenoid", "--count", "12", "-o", "net.json"),
             ("unroll", "net.json", "-o", "parts.json", "--svg", "svg"),
             ("nest", "parts.json", "-o", "nest.json", "--time-limit", "2"),
             ("export", "nest.json", "-o", "ex"))
    for step in steps:
        process = _fabline(*step, cwd=folder)
        assert process.wait(timeout=600) == 0, process.stderr.read()
    return folder


COMMANDS = {"unroll": (("unroll", "net.json", "-o", "parts.json", "--svg", "svg", "--no-hardware"), "svg"),
            "export": (("export", "nest.json", "-o", "ex", "--kerf", "0.25mm"), "ex")}
"""The command (with an option that changes its outputs, so a file not put back differs) and the folder whose
replaced files the `replacing` moment watches."""


def _catches(pid: int, number: int) -> bool:
    """Whether the process has its own handler for signal `number` (its SigCgt mask in /proc): fabline's main sets
    SIGTERM's first thing; before that a signal meets a program still starting (killed outright, or a
    KeyboardInterrupt in Python's imports)."""
    with open(f"/proc/{pid}/status", encoding="ascii") as status:
        caught = next(line for line in status if line.startswith("SigCgt:")).split()[1]
    return bool(int(caught, 16) >> (number - 1) & 1)


def _replacing(folder: Path, pid: int) -> bool:
    """Whether the process has begun replacing files in `folder` (a backup link of its own is there)."""
    try:
        names = os.listdir(folder)
    except OSError:
        return False
    return any((m := TEMP_PATTERN.match(n)) and int(m["pid"]) == pid for n in names)


@pytest.mark.parametrize("moment", ["loading", "replacing"])
@pytest.mark.parametrize("number", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_an_interrupt_leaves_the_outputs_as_they_were(command, number, moment, earlier, tmp_path):
    folder = tmp_path / "run"
    shutil.copytree(earlier, folder)
    before = _snapshot(folder)
    argv, watched = COMMANDS[command]
    process = _fabline(*argv, cwd=folder)
    if moment == "loading":  # as soon as fabline's main handles signals (on a loaded machine that can take > 0.3 s)
        deadline = time.monotonic() + 120
        while not _catches(process.pid, signal.SIGTERM):
            assert process.poll() is None, f"finished before it handled the signal: {process.stderr.read()}"
            assert time.monotonic() < deadline
            time.sleep(0.002)
    else:
        deadline = time.monotonic() + 300
        while not _replacing(folder / watched, process.pid):
            assert process.poll() is None, f"finished before it replaced a file: {process.stderr.read()}"
            assert time.monotonic() < deadline
            time.sleep(0.002)
    if number == signal.SIGINT:
        os.killpg(process.pid, number)  # Ctrl-C: the terminal signals the whole process group
    else:
        process.send_signal(number)
    code, err = process.wait(timeout=300), process.stderr.read()
    if code == 0 and moment == "replacing":  # the signal came as the outputs were committed: all are new, and kept
        assert "interrupted" not in err and "terminated" not in err, err
        pytest.fail("the command finished between the first replaced file and the signal; run again")
    word = "interrupted" if number == signal.SIGINT else "terminated"
    assert code == 128 + number and err == f"fabline {command}: {word}; nothing was written\n", (code, err)
    assert _snapshot(folder) == before


def test_a_rollback_after_interrupted_exits_puts_back_what_a_nested_set_replaced(tmp_path):
    """A signal that lands as the sets' exits begin (before they can hold signals off) leaves the nested set's file
    neither handed over nor put back: the caller's rollback (the command line's) puts it back; twice is harmless."""
    old = tmp_path / "a.txt"
    old.write_text("old")
    outputs = OutputSet()
    outputs.__enter__()
    try:
        OutputSet().__enter__()
        with atomic_output(old) as handle:
            handle.write("new")
        outputs.rollback()
        outputs.rollback()
    finally:
        fileio._CURRENT.reset(outputs._token)
    assert old.read_text() == "old" and os.listdir(tmp_path) == ["a.txt"]


def test_a_run_refused_at_a_later_stage_leaves_its_output_folder_as_it_was(cli, tmp_path):
    """The export stage refuses the 4.5 m sheets (the laser's bed is 4.1 m) after model, unroll and nest wrote their
    files: all of them go again, and the earlier run's network.json is put back."""
    (tmp_path / "job.toml").write_text('name = "refused"\nstages = ["unroll", "nest", "export"]\n[model]\n'
                                       'design = "catenoid"\n[model.options]\ncount = 8\nwaist = 1.0\nheight = 1.5\n'
                                       '[stock]\nsheet = "4500x2000"\n[output]\nfolder = "out"\n')
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "network.json").write_text("an earlier run's network\n")
    before = _snapshot(tmp_path)
    code, _, err = cli("run", tmp_path / "job.toml")
    assert code == 2 and err.count("\n") == 1 and "is larger than the bed of machine grbl-laser" in err, err
    assert _snapshot(tmp_path) == before and os.listdir(tmp_path / "out") == ["network.json"]


def test_a_ctrl_c_as_the_temp_file_is_made_leaves_no_temp_file(tmp_path, monkeypatch):
    """The window the process test found: a signal landing right after mkstemp made the temp file (before the
    code that removes it on failure began) left an empty `.name.fabline<pid>-*.tmp` behind."""
    import tempfile

    made = tempfile.mkstemp

    def mkstemp(*args, **kwargs):
        fd, name = made(*args, **kwargs)
        signal.raise_signal(signal.SIGINT)
        return fd, name

    monkeypatch.setattr(tempfile, "mkstemp", mkstemp)
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)  # Ctrl-C as in a fresh process, whatever
    try:                                                                 # an earlier test left in this worker
        with pytest.raises(KeyboardInterrupt):
            with atomic_output(tmp_path / "a.txt") as handle:
                handle.write("never")
    finally:
        signal.signal(signal.SIGINT, previous)
    assert os.listdir(tmp_path) == []


SWALLOWED_STOP = """
import os, signal, sys, weakref
from fabline.cli import main
from fabline.model import designs

class Held:
    pass

def catenoid(**options):
    network = DESIGN(**options)
    held = Held()
    ref = weakref.ref(held, lambda ref: os.kill(os.getpid(), signal.{name}))  # the handler runs inside the callback
    del held
    return network

DESIGN = designs.DESIGNS["catenoid"]
designs.DESIGNS["catenoid"] = catenoid
sys.exit(main(["design", "catenoid", "--count", "12", "-o", "net.json"]))
"""


@pytest.mark.parametrize("number", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_stop_python_swallows_in_a_callback_still_stops_the_command(number, tmp_path):
    """A signal whose handler runs inside a weakref callback (as SIGTERM did in importlib's module-lock callback on
    a loaded CI machine) is swallowed by Python as "Exception ignored"; the command still stops before it writes,
    says so in its one line and exits 130 / 143, with no note of the swallowed exception."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, (os.environ.get("PYTHONPATH"), str(REPO)))))
    script = SWALLOWED_STOP.replace("{name}", signal.Signals(number).name)
    done = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, env=env, text=True, capture_output=True,
                          timeout=300)
    word = "interrupted" if number == signal.SIGINT else "terminated"
    assert (done.returncode, done.stderr) == (128 + number, f"fabline design: {word}; nothing was written\n")
    assert os.listdir(tmp_path) == []
