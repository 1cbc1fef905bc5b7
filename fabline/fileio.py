"""Safe file output and tolerant input helpers shared by every stage."""

from __future__ import annotations

import json
import math
import os
import stat
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator, TextIO

import orjson

from fabline.errors import FablineError


@contextmanager
def atomic_output(path: str | os.PathLike, mode: str = "w") -> Iterator[Any]:
    """Open a temp file beside `path`; on success fsync and rename it over `path`, on failure remove it.

    Readers never see a half-written file, and a failed run leaves no output behind.
    """
    path = Path(path)
    if path.is_dir():
        raise FablineError(f"{path}: is a folder, expected a file name")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    except OSError as exc:
        raise FablineError(f"{path}: cannot write: {exc.strerror}") from None
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)
    try:
        with os.fdopen(fd, mode, **({} if "b" in mode else {"encoding": "utf-8", "newline": "\n"})) as handle:
            yield handle
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    except OSError as exc:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise FablineError(f"{path}: cannot write: {exc.strerror}") from None
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def write_json(path: str | os.PathLike, data: Any, compact: bool = False) -> None:
    """Write `data` as JSON, atomically: indented for reading, or compact for bulk geometry.

    Compact JSON is encoded by orjson, several times faster than the standard library on a large parts file, and
    it takes numpy arrays and scalars; the same text but for exponents (1e-6, not 1e-06). It writes NaN as null,
    so callers check their bulk numbers are finite (parts do, when rounding).
    """
    if compact:
        with atomic_output(path, "wb") as handle:
            handle.write(orjson.dumps(data, option=orjson.OPT_SERIALIZE_NUMPY))
            handle.write(b"\n")
        return
    with atomic_output(path) as handle:
        json.dump(data, handle, allow_nan=False, indent=1)
        handle.write("\n")


def finite_number(value: Any) -> bool:
    """Whether a value read from JSON is a finite number (an int or a float; not a bool, NaN or infinity)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def read_bytes(path: str | os.PathLike) -> bytes:
    """A file's bytes; a missing or unreadable file becomes a FablineError naming it."""
    try:
        return Path(path).read_bytes()
    except FileNotFoundError:
        raise FablineError(f"{path}: file not found") from None
    except OSError as exc:
        raise FablineError(f"{path}: cannot read: {exc.strerror}") from None


def check_regular_file(path: str | os.PathLike, max_bytes: int) -> None:
    """Refuse, before reading it, a path that is not a regular file (a FIFO or a device would block or never
    end) or that is larger than `max_bytes`, with a one-line FablineError naming it."""
    try:
        info = os.stat(path)
    except FileNotFoundError:
        raise FablineError(f"{path}: file not found") from None
    except OSError as exc:
        raise FablineError(f"{path}: cannot read: {exc.strerror}") from None
    if not stat.S_ISREG(info.st_mode):
        raise FablineError(f"{path}: not a regular file")
    if info.st_size > max_bytes:
        raise FablineError(f"{path}: {info.st_size} bytes, more than the {max_bytes} this kind of file may have")


def read_text(path: str | os.PathLike, what: str = "") -> str:
    """A UTF-8 text file; a missing, unreadable or undecodable file becomes a FablineError naming it
    (`what`, e.g. " as OBJ text", says how it was being read)."""
    try:
        return Path(path).read_text(encoding="utf-8")
    except FileNotFoundError:
        raise FablineError(f"{path}: file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise FablineError(f"{path}: cannot read{what}: {exc}") from None


def read_json(path: str | os.PathLike) -> Any:
    """Read a JSON file; a missing file or bad JSON becomes a FablineError naming file and line."""
    path = Path(path)
    text = read_text(path)
    try:
        return orjson.loads(text)  # 2x faster than json.loads on a large file
    except orjson.JSONDecodeError:
        pass  # not strict JSON: read as the standard library does (NaN literals, for the caller to name), or say why not
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise FablineError(f"{path}:{exc.lineno}:{exc.colno}: malformed JSON: {exc.msg}") from None


def check_outputs(files: tuple = (), folders: tuple = ()) -> None:
    """Check up front that the output files and folders can be written (a file name is not a folder, a folder
    is not a file, the place takes files), so that a command fails before it computes or writes anything.
    Nothing is created; None entries (options not given) are skipped."""
    for path in [Path(f) for f in files if f]:
        if path.is_dir():
            raise FablineError(f"{path}: is a folder, expected a file name")
        folders += (path.parent,)
    for folder in [Path(f) for f in folders if f]:
        existing = folder
        while not existing.exists() and existing != existing.parent:
            existing = existing.parent
        if not existing.is_dir():
            raise FablineError(f"{folder}: cannot be an output folder: {existing} is a file")
        try:
            tempfile.TemporaryFile(dir=existing).close()  # it takes files (not read-only, not /proc)
        except OSError as exc:
            raise FablineError(f"{folder}: cannot write there: {exc.strerror}") from None


def open_append(path: str | os.PathLike, what: str, **options) -> TextIO:
    """Open an ASCII log (a journal, an exchange log) for appending, creating its folder; a place that cannot
    take it is a one-line FablineError naming the path and `what` it is."""
    path = Path(path)
    check_outputs(files=(path,))
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        return open(path, "a", encoding="ascii", **options)
    except OSError as exc:
        raise FablineError(f"{path}: cannot write the {what}: {exc.strerror}") from None
