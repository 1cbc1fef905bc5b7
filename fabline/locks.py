"""Exclusive locks between fabline processes: one job output folder, one serial port, one holder at a time.

A lock is an advisory `flock` on a small file that also holds the holder's pid, so a refusal can name it.
The kernel drops the lock when its holder dies (even by SIGKILL): a stale lock file never blocks anyone.
"""

from __future__ import annotations

import errno
import fcntl
import os
import stat
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from fabline.errors import FablineError
from fabline.naming import file_stem


@contextmanager
def exclusive_lock(lock_path: str | os.PathLike, what: str) -> Iterator[Path]:
    """Hold the lock at `lock_path` for the block, or refuse at once with a one-line error naming `what` and
    the pid holding it. The lock file stays (deleting it would race a waiting process); only its pid changes."""
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
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode("ascii"), 0)
        yield path
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


def _holder(fd: int) -> str:
    """'process 1234' as written by the holder, or 'another process' when it has not written its pid yet."""
    try:
        text = os.pread(fd, 32, 0).decode("ascii").strip()
    except (OSError, UnicodeDecodeError):
        text = ""
    return f"process {text}" if text.isdigit() else "another process"


def lock_path(resource: str | os.PathLike) -> Path:
    """The machine-wide lock file of a resource: a job's output folder, a serial port or a port URL. One lock per
    resource whatever path names it (a symlink such as /dev/serial/by-id/... and /dev/ttyUSB0 share one), kept
    in the temp folder so that taking it writes nothing into the user's folders."""
    name = str(resource) if "://" in str(resource) else os.path.realpath(resource)
    return Path(tempfile.gettempdir()) / "fabline-locks" / f"{file_stem(name)}.lock"
