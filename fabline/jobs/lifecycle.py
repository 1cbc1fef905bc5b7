"""The runner server's own processes: what it forks dies with it and keeps none of its sockets or locks, and a stop
ends every process it started.

The export stage makes sheets in forked worker processes. A fork copies every open file: the page's listening
socket (a worker that outlives the server keeps the port bound, and connections to it hang) and the queue's
and job folders' lock files (a flock lives as long as any copy, so a new server was refused). A fork also copies
the server's Python signal handlers, which only set a flag, so SIGTERM did not end a worker. `guard_forks` makes
every child forked by the server (the export workers; subprocess children exec and close their files anyway)
close those copies, ignore the stop signals (the server stops them), and be killed by the kernel when the
server's thread that forked it ends (Linux PR_SET_PDEATHSIG), even by SIGKILL. `end_descendants` ends
whatever is left at a stop.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import signal
import sys
import time
from pathlib import Path

from fabline.link.streamer import STOP_SIGNALS

_PR_SET_PDEATHSIG = 1


def exit_code(number: int) -> int:
    """The shell's exit code for a process stopped by signal `number`: 130 for SIGINT, 143 for SIGTERM, 129 SIGHUP."""
    return 128 + number


def guard_forks(listening: list[int], locks: list[Path]) -> None:
    """From now on every process this one forks closes its copies of the `listening` socket descriptors and of any
    file under or at `locks`, ignores the stop signals (the stopping server ends it), and dies with its parent."""
    parent = os.getpid()
    prctl = _prctl()
    closing = set(listening)
    roots = [str(path) for path in locks]

    def in_child() -> None:
        if prctl is not None:
            prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
        if os.getppid() != parent:  # the parent died before the line above: nobody is left to work for
            os._exit(1)
        for number in STOP_SIGNALS:  # a terminal's or a service manager's signal to the whole group: the
            signal.signal(number, signal.SIG_IGN)  # server decides, and ends its workers itself
        for fd in _inherited(closing, roots):
            os.close(fd)

    os.register_at_fork(after_in_child=in_child)


def _prctl():
    """libc's prctl on Linux, else None (elsewhere the stop's `end_descendants` is what ends the workers)."""
    if not sys.platform.startswith("linux"):
        return None
    libc = ctypes.CDLL(ctypes.util.find_library("c") or None, use_errno=True)
    return libc.prctl


def _inherited(closing: set[int], roots: list[str]) -> list[int]:
    """The descriptors of this process that are in `closing` or name a file at or under one of `roots`."""
    found = []
    try:
        fds = [int(name) for name in os.listdir("/proc/self/fd")]
    except OSError:
        return sorted(fd for fd in closing if _is_open(fd))
    for fd in fds:
        if fd in closing:
            found.append(fd)
            continue
        try:
            target = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:
            continue
        if any(target == root or target.startswith(root + os.sep) for root in roots):
            found.append(fd)
    return found


def _is_open(fd: int) -> bool:
    try:
        os.fstat(fd)
    except OSError:
        return False
    return True


def descendants(pid: int) -> list[int]:
    """Every living process below `pid` (children, their children, ...), read from /proc; [] where there is none."""
    parents: dict[int, int] = {}
    for entry in Path("/proc").iterdir() if Path("/proc").is_dir() else ():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2:].split()  # after "pid (command) ": state, ppid, ...
        if fields[0] not in ("Z", "X"):
            parents[int(entry.name)] = int(fields[1])
    found, level = [], [pid]
    while level:
        level = [child for child, parent in parents.items() if parent in level]
        found += level
    return found


def end_descendants(grace: float = 0.5) -> int:
    """End every process below this one: SIGTERM, then SIGKILL for any still there after `grace` seconds, and reap
    the direct children; returns how many there were."""
    found = descendants(os.getpid())
    for pid in found:
        _signal(pid, signal.SIGTERM)
    deadline = time.monotonic() + grace
    while time.monotonic() < deadline and any(pid in descendants(os.getpid()) for pid in found):
        _reap()
        time.sleep(0.05)
    for pid in descendants(os.getpid()):
        _signal(pid, signal.SIGKILL)
    deadline = time.monotonic() + grace
    while time.monotonic() < deadline and descendants(os.getpid()):
        _reap()
        time.sleep(0.05)
    _reap()
    return len(found)


def _signal(pid: int, number: int) -> None:
    try:
        os.kill(pid, number)
    except (ProcessLookupError, PermissionError):
        pass


def _reap() -> None:
    """Collect the exit status of children that ended (so none stays a zombie)."""
    while True:
        try:
            pid, _ = os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:
            return
        if pid == 0:
            return
