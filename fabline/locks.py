"""Exclusive locks between fabline processes: one job output folder, one serial port, one holder at a time.

A lock is an advisory `flock` on a small file that also holds the holder's pid, so a refusal can name it; the
pid is wiped when the lock is released, so a pid found in a free lock names a holder that died holding it.
The kernel drops the lock when its holder dies (even by SIGKILL) and every process it forked with the file
open has ended: a stale lock file never blocks anyone.
"""

from __future__ import annotations

import errno
import fcntl
import os
import stat
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator

from fabline.errors import FablineError
from fabline.fileio import process_alive
from fabline.naming import file_stem


@contextmanager
def exclusive_lock(lock_path: str | os.PathLike, what: str,
                   taken_over: Callable[[int], None] | None = None) -> Iterator[Path]:
    """Hold the lock at `lock_path` for the block, or refuse at once with a one-line error naming `what` and
    the pid holding it. The lock file stays (deleting it would race a waiting process); only its pid changes.
    `taken_over(pid)` is told when the lock was left by a process that died holding it."""
    path = Path(lock_path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW, 0o644)
    except OSError as exc:
        raise FablineError(f"{path}: cannot create the lock for {what}: {exc.strerror}") from None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN):
                raise FablineError(f"{path}: cannot lock {what}: {exc.strerror}") from None
            holder = _holder(fd)
            raise FablineError(f"{what} is in use by {holder} (lock {path}); wait for it to finish or stop it") from None
        left = _pid(fd)
        if left is not None and left != os.getpid() and taken_over is not None and not process_alive(left):
            taken_over(left)
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode("ascii"), 0)
        try:
            yield path
        finally:
            os.ftruncate(fd, 0)  # released: no pid left in the file
    finally:
        os.close(fd)  # closing releases the flock


def lock_holder(lock_path: str | os.PathLike) -> int | None:
    """The pid that holds the lock at `lock_path` (as it wrote it), or None when no process holds it (or there is
    no such lock file); nothing is created, and a symbolic link or anything but a regular file holds nothing."""
    try:
        fd = os.open(lock_path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
    except OSError:
        return None
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            return None
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except OSError as exc:
            if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN):
                return None
            text = os.pread(fd, 32, 0).decode("ascii", "replace").strip()
            return int(text) if text.isdigit() else 0  # held, by a process that has not written its pid yet
        return None
    finally:
        os.close(fd)


def _pid(fd: int) -> int | None:
    """The pid written in the lock file, if any."""
    try:
        text = os.pread(fd, 32, 0).decode("ascii").strip()
    except (OSError, UnicodeDecodeError):
        return None
    return int(text) if text.isdigit() else None


def _sharers(fd: int) -> list[int]:
    """The processes that have the lock file open (on Linux, from /proc), this one aside."""
    mine = os.fstat(fd)
    found = []
    for entry in os.scandir("/proc") if os.path.isdir("/proc") else ():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            for name in os.listdir(f"/proc/{entry.name}/fd"):
                st = os.stat(f"/proc/{entry.name}/fd/{name}")
                if (st.st_dev, st.st_ino) == (mine.st_dev, mine.st_ino):
                    found.append(int(entry.name))
                    break
        except OSError:
            continue
    return found


def _holder(fd: int) -> str:
    """'process 1234' as written by the holder, or 'another process' when it has not written its pid yet; when
    that process has ended, the processes it left holding the lock (forked with the file open)."""
    pid = _pid(fd)
    if pid is None:
        return "another process"
    if process_alive(pid):
        return f"process {pid}"
    left = _sharers(fd)
    if not left:
        return f"a process left by process {pid}, which has ended"
    return (f"process{'es' if len(left) > 1 else ''} {', '.join(map(str, left))}, left by process {pid}, "
            f"which has ended (`kill {' '.join(map(str, left))}` ends {'it' if len(left) == 1 else 'them'})")


def lock_path(resource: str | os.PathLike) -> Path:
    """The machine-wide lock file of a resource: a job's output folder, a serial port or a port URL. One lock per
    resource whatever path names it (a symlink such as /dev/serial/by-id/... and /dev/ttyUSB0 share one), kept
    in the temp folder so that taking it writes nothing into the user's folders."""
    name = str(resource) if "://" in str(resource) else os.path.realpath(resource)
    return Path(tempfile.gettempdir()) / "fabline-locks" / f"{file_stem(name)}.lock"
