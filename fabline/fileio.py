"""Safe file output and vetted file input, shared by every stage."""

from __future__ import annotations

import json
import math
import os
import re
import secrets
import signal
import stat
import tempfile
import threading
import time
from contextlib import contextmanager
from contextvars import ContextVar
from pathlib import Path
from typing import Any, BinaryIO, Iterable, Iterator, TextIO

import orjson

try:
    import tomllib
except ImportError:  # Python 3.10
    import tomli as tomllib

from fabline.errors import FablineError


TEMP_PATTERN = re.compile(r"^\.(?P<name>.+)\.fabline(?P<pid>\d+)-[A-Za-z0-9_]+\.tmp$")
"""Temp files of `atomic_output` (and the backups an `OutputSet` keeps): `.<name>.fabline<pid>-<random>.tmp`."""
_STARTED = time.time()  # temp files older than this process whose writer is gone are orphans of a killed run
_SWEPT: set[str] = set()  # folders already cleaned of orphans in this process
_CURRENT: ContextVar["OutputSet | None"] = ContextVar("fabline_outputs", default=None)


def output_target(path: str | os.PathLike, inputs: Iterable[str | os.PathLike] = ()) -> Path:
    """Where writing `path` goes, checked: the path itself, or the regular file a symlink points to (written
    through: the target is replaced, the link stays). A folder, a name ending in '/', anything but a regular file
    (a device, FIFO or socket) and any of `inputs` (the same path or the same file by inode) are refused."""
    text = os.fspath(path)
    if text.endswith(("/", os.sep)):
        raise FablineError(f"{text}: ends in '/', so it names a folder; give a file name")
    path = Path(text)
    target = Path(os.path.realpath(path)) if path.is_symlink() else path
    try:
        status = os.stat(target)
    except (FileNotFoundError, NotADirectoryError):  # a new file (or a folder that is a file: check_outputs says)
        status = None
    except OSError as exc:
        raise FablineError(f"{path}: cannot write: {exc.strerror}") from None
    if status is not None and stat.S_ISDIR(status.st_mode):
        raise FablineError(f"{path}: is a folder, expected a file name")
    if status is not None and not stat.S_ISREG(status.st_mode):
        raise FablineError(f"{path}: is not a regular file (a device, FIFO or socket); fabline writes only regular "
                           f"files: give a file name")
    for source in inputs:
        if _same_file(target, status, Path(source)):
            raise FablineError(f"{path}: is also an input of this command ({source}); writing it would destroy the "
                               f"input: give another output name")
    return target


def _same_file(target: Path, status: os.stat_result | None, source: Path) -> bool:
    """Whether an output (its status, None when it does not exist yet) is the input `source`: same path or inode."""
    if os.path.realpath(target) == os.path.realpath(source):
        return True
    try:
        return status is not None and os.path.samestat(status, os.stat(source))
    except OSError:
        return False


class OutputSet:
    """The files one command (or one pipeline stage) writes, as a unit: `atomic_output` inside `with OutputSet():`
    records each file it renames into place (keeping a hard link to the file it replaced) and the folders it made.
    A failure or Ctrl-C inside the block removes them again and puts the replaced files back; leaving the block
    normally keeps them. Nested sets hand their files to the enclosing one. Inputs registered with
    `check_outputs` are refused as outputs of every later write in the set."""

    def __init__(self) -> None:
        self.inputs: list[str] = []
        self.written: dict[Path, Path | None] = {}  # file -> hard link to the file it replaced (None: new file)
        self.folders: list[Path] = []                # folders made, in order
        self.committed = False
        self._parent: OutputSet | None = None
        self._children: list[OutputSet] = []        # nested sets: rolled back with this one, even if interrupted
        self._token = None

    def __enter__(self) -> "OutputSet":
        self._parent = _CURRENT.get()
        if self._parent is not None:
            self.inputs = list(self._parent.inputs)
            self._parent._children.append(self)
        self._token = _CURRENT.set(self)
        return self

    def __exit__(self, kind, value, traceback) -> None:
        # A signal is held off throughout: a rollback or hand-over cut short would leave replaced files behind.
        # One that comes before this line runs is caught by the caller's `rollback` (the CLI's), as nothing
        # was committed or handed over yet.
        with _signals_deferred(swallow=kind is not None or self._parent is None):
            _CURRENT.reset(self._token)
            if kind is not None:
                self.rollback()
            elif self._parent is not None:
                for path, backup in self.written.items():
                    if path in self._parent.written and backup is not None:
                        _unlink(backup)  # the enclosing set keeps the file as it was before both
                    self._parent.written.setdefault(path, backup)
                self._parent.folders += self.folders
                self.written, self.folders = {}, []
                self._parent._children.remove(self)
            else:
                self.commit()  # the outputs are complete: a signal now interrupts nothing

    def record(self, target: Path) -> Path | None:
        """Before `target` is replaced: keep a hard link to its present file (the first time only)."""
        if target in self.written or not target.exists():
            self.written.setdefault(target, None)
            return None
        backup = target.parent / f".{target.name}.fabline{os.getpid()}-{secrets.token_hex(4)}.tmp"
        try:
            os.link(target, backup)
        except OSError:
            backup = None  # no hard links here: the replaced file cannot come back
        self.written[target] = backup
        return backup

    def commit(self) -> None:
        """Keep the outputs: drop the replaced files' links."""
        for backup in self.written.values():
            if backup is not None:
                _unlink(backup)
        self.written.clear()
        self.committed = True

    def rollback(self) -> None:
        """Remove the files written (putting back the ones they replaced) and the folders made, if empty, also by
        nested sets not yet handed over; a second call does nothing."""
        with _signals_deferred(swallow=True):  # a second Ctrl-C must not cut the putting back short
            for child in reversed(self._children):
                child.rollback()
            self._children.clear()
            for path, backup in reversed(list(self.written.items())):
                if backup is not None:
                    try:
                        os.replace(backup, path)  # does nothing when `path` is still the same file (its write failed)
                        _unlink(backup)
                        continue
                    except OSError:
                        _unlink(backup)
                _unlink(path)
            self.written.clear()
            for folder in reversed(self.folders):
                try:
                    folder.rmdir()
                except OSError:
                    pass
            self.folders.clear()


def _unlink(path: Path) -> None:
    try:
        os.unlink(path)
    except OSError:
        pass


DEFERRED_SIGNALS = (signal.SIGINT, signal.SIGTERM)


@contextmanager
def _signals_deferred(swallow: bool = False) -> Iterator[None]:
    """Hold off Ctrl-C and SIGTERM (in the main thread) while outputs are renamed into place or put back;
    afterwards a signal that came meanwhile is raised by its handler, or with `swallow` dropped (it came when the
    work was done, or while an interrupt was already being handled). A default SIGTERM still ends the process."""
    pending: list[tuple[int, Any, Any]] = []  # (signal, frame, the handler it would have reached)
    if threading.current_thread() is not threading.main_thread():
        yield pending
        return
    previous = {number: signal.signal(number, lambda number, frame: pending.append((number, frame, previous[number])))
                for number in DEFERRED_SIGNALS}
    try:
        yield pending
    finally:
        for number, handler in previous.items():
            signal.signal(number, signal.SIG_DFL if handler is None else handler)
    _deliver(pending, swallow)


def _deliver(pending: list[tuple[int, Any, Any]], swallow: bool = False) -> None:
    """Raise the first signal `_signals_deferred` held off, by its handler (unless `swallow`); a default SIGTERM
    ends the process even so."""
    if pending:
        number, frame, handler = pending[0]
        if callable(handler) and not swallow:
            handler(number, frame)
        elif handler == signal.SIG_DFL and number != signal.SIGINT:
            signal.raise_signal(number)


def _make_folder(folder: Path) -> None:
    """Create `folder` and its missing parents, recording the ones made in the current output set."""
    missing = []
    while not folder.exists() and folder != folder.parent:
        missing.append(folder)
        folder = folder.parent
    for made in reversed(missing):
        made.mkdir(exist_ok=True)
        outputs = _CURRENT.get()
        if outputs is not None:
            outputs.folders.append(made)


def sweep_orphans(folder: str | os.PathLike) -> int:
    """Remove temp files that a killed fabline process left in `folder` (our own temp-name pattern, written by a
    process that is gone, before this one started); once per folder and process. Returns how many."""
    key = os.path.realpath(folder)
    if key in _SWEPT:
        return 0
    _SWEPT.add(key)
    removed = 0
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return 0
    for entry in entries:
        match = TEMP_PATTERN.match(entry.name)
        if match is None or int(match["pid"]) == os.getpid() or process_alive(int(match["pid"])):
            continue
        try:
            if entry.is_file(follow_symlinks=False) and entry.stat(follow_symlinks=False).st_mtime < _STARTED:
                os.unlink(entry.path)
                removed += 1
        except OSError:
            pass
    return removed


def process_alive(pid: int) -> bool:
    """Whether process `pid` exists (one of another user's, or a pid too large to be one, counts as alive)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError):
        return True
    return True


@contextmanager
def atomic_output(path: str | os.PathLike, mode: str = "w") -> Iterator[Any]:
    """Open a temp file beside `path`; on success fsync and rename it over `path`, on failure remove it.

    Readers never see a half-written file, and a failed run leaves no output behind. The target is checked by
    `output_target` (a symlink is written through; devices, FIFOs, sockets and the command's inputs are refused);
    inside an `OutputSet` the file is recorded so that a later failure of the command removes it again.
    """
    outputs = _CURRENT.get()
    target = output_target(path, outputs.inputs if outputs is not None else ())
    try:
        _make_folder(target.parent)
        sweep_orphans(target.parent)
    except OSError as exc:
        raise FablineError(f"{path}: cannot write: {exc.strerror}") from None
    tmp = None  # set with the temp file, before any signal can be raised: whatever stops us then removes it
    try:
        with _signals_deferred(swallow=True) as pending:
            fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.fabline{os.getpid()}-", suffix=".tmp",
                                       dir=target.parent)
        with os.fdopen(fd, mode, **({} if "b" in mode else {"encoding": "utf-8", "newline": "\n"})) as handle:
            _deliver(pending)  # a signal that came as the temp file was made: raised here, where it is removed
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(tmp, 0o666 & ~umask)
            yield handle
            handle.flush()
            os.fsync(handle.fileno())
        with _signals_deferred():
            if outputs is not None:
                outputs.record(target)
            os.replace(tmp, target)
    except OSError as exc:
        if tmp is not None:
            _unlink(Path(tmp))
        raise FablineError(f"{path}: cannot write: {exc.strerror}") from None
    except BaseException:
        if tmp is not None:
            _unlink(Path(tmp))
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


MAX_MM = 1e7
"""The largest coordinate or size in millimetres (10 km) any reader takes: beyond it is a mistake in the file,
and squares of such numbers overflow."""


def finite_number(value: Any, limit: float = math.inf) -> bool:
    """Whether a value read from JSON is a finite number (an int or a float; not a bool, NaN or infinity), at
    most `limit` in size."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value) and abs(value) <= limit


INPUT_LIMITS = {"json": 1 << 30, "model": 1 << 30, "gcode": 1 << 28, "photo": 1 << 28, "config": 1 << 20}
"""The largest input of each kind fabline reads, in bytes: JSON networks, parts, nestings and records (1 GiB);
models (OBJ, DXF, 3dm, STL, meshes, 1 GiB); G-code (256 MiB); photos (256 MiB); TOML job files, machine
profiles and materials (1 MiB). A larger file is a mistake (or /dev/zero renamed) that would exhaust memory."""
_INPUT_NAMES = {"json": "JSON file", "model": "model file", "gcode": "G-code file", "photo": "photo",
                "config": "TOML file"}
_NOT_REGULAR = ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISSOCK, "a socket"),
                (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"))


def open_input(path: str | os.PathLike, kind: str) -> BinaryIO:
    """Open an input file of `kind` (a key of INPUT_LIMITS) for reading in binary, vetted: a path holding a NUL
    byte, a missing file, anything but a regular file (a folder, FIFO, socket or device: found by stat, before it
    is opened, and again on the open descriptor, opened non-blocking so that a FIFO swapped in meanwhile cannot
    hang) and a file larger than the kind's limit are each refused with a one-line FablineError naming the path.
    Every reader of a user's file comes through here (`read_bytes`, `read_text`, `read_json`, `vet_input`)."""
    text = _no_nul(path)
    try:
        _vet_status(text, os.stat(text), kind)
        fd = os.open(text, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except (FileNotFoundError, NotADirectoryError):
        raise FablineError(f"{text}: file not found") from None
    except OSError as exc:
        raise FablineError(f"{text}: cannot read: {exc.strerror}") from None
    try:
        _vet_status(text, os.fstat(fd), kind)
        os.set_blocking(fd, True)
    except BaseException:
        os.close(fd)
        raise
    return os.fdopen(fd, "rb")


def _no_nul(path: str | os.PathLike) -> str:
    """A path as text; one holding a NUL byte (which no file name can, and which os calls refuse with a ValueError)
    is refused in one line."""
    text = os.fsdecode(path)
    if "\0" in text:
        raise FablineError(f"{text!r}: the path holds a NUL byte, which no file name can: give the file's name")
    return text


def _vet_status(path: str, info: os.stat_result, kind: str) -> None:
    """Refuse an input that is not a regular file, or larger than its kind's limit (INPUT_LIMITS)."""
    for test, what in _NOT_REGULAR:
        if test(info.st_mode):
            raise FablineError(f"{path}: is {what}, not a regular file: give the {_INPUT_NAMES[kind]} itself")
    if not stat.S_ISREG(info.st_mode):
        raise FablineError(f"{path}: is not a regular file: give the {_INPUT_NAMES[kind]} itself")
    if info.st_size > INPUT_LIMITS[kind]:
        raise FablineError(f"{path}: {info.st_size} bytes, more than the {INPUT_LIMITS[kind]} bytes "
                           f"({INPUT_LIMITS[kind] / (1 << 20):g} MiB) a {_INPUT_NAMES[kind]} may have: not read")


def vet_input(path: str | os.PathLike, kind: str) -> Path:
    """Check an input that a library opens by name (rhino3dm, trimesh, ezdxf, OpenCV, Pillow) as `open_input`
    does; returns the path."""
    open_input(path, kind).close()
    return Path(os.fsdecode(path))


def read_bytes(path: str | os.PathLike, kind: str = "json") -> bytes:
    """An input file's bytes, vetted by `open_input` (at most its kind's limit, even if it grows meanwhile)."""
    with open_input(path, kind) as handle:
        try:
            data = handle.read(INPUT_LIMITS[kind] + 1)
        except OSError as exc:
            raise FablineError(f"{os.fsdecode(path)}: cannot read: {exc.strerror}") from None
    if len(data) > INPUT_LIMITS[kind]:
        raise FablineError(f"{os.fsdecode(path)}: grew past the {INPUT_LIMITS[kind]} bytes a {_INPUT_NAMES[kind]} "
                           f"may have while it was read: not read")
    return data


def read_text(path: str | os.PathLike, what: str = "", kind: str = "json") -> str:
    """A UTF-8 text input (vetted by `open_input`); bytes that are not UTF-8 are refused naming the file and the
    byte offset (`what`, e.g. " as OBJ text", says how it was being read)."""
    data = read_bytes(path, kind)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise FablineError(f"{os.fsdecode(path)}: cannot read{what}: not UTF-8 text at byte {exc.start} "
                           f"(0x{data[exc.start]:02x}: {exc.reason})") from None


def read_json(path: str | os.PathLike, kind: str = "json") -> Any:
    """Read a JSON file; a missing file or bad JSON becomes a FablineError naming file and line.

    Integers beyond 64 bits become floats (10**400: infinity, which the readers' finite-number checks name), and
    nesting deeper than orjson's 1024 levels is an error, not a RecursionError."""
    text = read_text(path, kind=kind)
    path = Path(os.fsdecode(path))
    try:
        return orjson.loads(text)  # 2x faster than json.loads on a large file
    except orjson.JSONDecodeError:
        pass  # not strict JSON: read as the standard library does (NaN literals, for the caller to name), or say why not
    try:
        return json.loads(text, parse_int=_json_integer)
    except json.JSONDecodeError as exc:
        raise FablineError(f"{path}:{exc.lineno}:{exc.colno}: malformed JSON: {exc.msg}") from None
    except RecursionError:
        raise FablineError(f"{path}: malformed JSON: nested too deeply (lists and objects within each other)") from None


TOML_DEPTH = 32
"""Levels of tables and arrays within each other a TOML input may have (a job file or a profile has 3 or 4); the
runner's JSON bodies have the same bound (fabline.jobs.web.JSON_DEPTH)."""


def read_toml(path: str | os.PathLike, what: str = "", kind: str = "config") -> dict[str, Any]:
    """A TOML input (vetted and decoded by `read_text`) parsed by `parse_toml`, errors naming the file."""
    return parse_toml(read_text(path, what, kind), os.fsdecode(path))


def parse_toml(text: str, where: str) -> dict[str, Any]:
    """TOML text as a table, or one FablineError naming `where`: malformed, or nested deeper than TOML_DEPTH
    (the one reader of TOML: tomllib recurses once per level, so a deep text would exhaust the stack)."""
    try:
        table = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise FablineError(f"{where}: malformed TOML: {exc}") from None
    except RecursionError:
        table = None
    if table is None or nesting_depth(table, TOML_DEPTH) > TOML_DEPTH:
        raise FablineError(f"{where}: nested deeper than {TOML_DEPTH} levels (tables and arrays within each other); "
                           "no fabline file needs more than a few")
    return table


def nesting_depth(value: Any, limit: int) -> int:
    """Levels of dicts and lists within each other in a parsed value (a scalar is 0), counted without recursion,
    stopping once past `limit`."""
    deepest, stack = 0, [(value, 0)]
    while stack and deepest <= limit:
        item, level = stack.pop()
        if isinstance(item, (dict, list)):
            deepest = max(deepest, level + 1)
            stack.extend((child, level + 1) for child in (item.values() if isinstance(item, dict) else item))
    return deepest


def _json_integer(text: str) -> int | float:
    """A JSON integer as Python reads it, but as a float past 64 bits (no 4300-digit conversion limit, no
    OverflowError where arrays are made of it)."""
    return int(text) if len(text) < 19 else float(text)


def check_outputs(files: tuple = (), folders: tuple = (), inputs: tuple = ()) -> None:
    """Check up front that the output files and folders can be written (a file name is a regular file or a new
    name, not a folder, a device, a FIFO or one of the command's `inputs`; a folder is not a file; the place takes
    files), so that a command fails before it computes or writes anything. Nothing is created; None entries
    (options not given) are skipped. The inputs are remembered by the current `OutputSet`, whose later writes
    refuse them too."""
    inputs = tuple(_no_nul(i) for i in inputs if i)
    for name in (*files, *folders):
        if name:
            _no_nul(name)
    outputs = _CURRENT.get()
    if outputs is not None:
        outputs.inputs += inputs
    targets: dict[str, str] = {}
    for name in [f for f in files if f]:
        target = output_target(name, inputs)
        if os.path.realpath(target) in targets:
            raise FablineError(f"{name}: named twice as an output (also as {targets[os.path.realpath(target)]})")
        targets[os.path.realpath(target)] = str(name)
        folders += (target.parent,)
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
