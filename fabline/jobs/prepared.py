"""Prepared sheets reused: a job whose file and inputs are unchanged is not unrolled, nested and exported again.

The runner prepares every job into a folder of its own (`runs/job-N/`) and records there, in `prepared.json`, the
key of what it prepared: a SHA-256 over the job file's bytes, the bytes of every file it reads (model, materials,
stock, machine profile, survey result) and fabline's own code (the package's sources, so a changed stage never
hands out stale programs). A job with the same key (a re-queued job, the same file submitted again) gets a copy
of that folder instead of a new preparation (minutes for the example job), and a job whose own preparation had
finished when the runner stopped keeps it; one whose programs were changed on disk since (their SHA-256 is
recorded too) is prepared afresh.
"""

from __future__ import annotations

import functools
import hashlib
import os
import shutil
from pathlib import Path
from typing import Any

from fabline.errors import FablineError
from fabline.fileio import read_bytes, read_json, write_json
from fabline.jobs.jobfile import JobSpec

RECORD = "prepared.json"
FORMAT = "fabline.prepared/1"


def input_files(spec: JobSpec) -> list[Path]:
    """The files a job's preparation reads besides its job file: model or mesh, materials, stock, profile, survey result."""
    named = [spec.model.get("file"), spec.model.get("mesh"), spec.lamella.get("materials_file"), spec.stock.get("file"),
             spec.survey.get("result"), spec.machine["profile"] if str(spec.machine["profile"]).endswith(".toml") else None]
    return [Path(path) for path in named if path]


@functools.lru_cache(maxsize=1)
def code_digest() -> str:
    """SHA-256 over fabline's package sources (every .py and .toml, by relative path): the code that prepares."""
    root = Path(__file__).resolve().parents[1]
    digest = hashlib.sha256()
    for path in sorted(p for p in root.rglob("*") if p.suffix in (".py", ".toml") and p.is_file()):
        digest.update(str(path.relative_to(root)).encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()


def job_key(spec: JobSpec) -> str:
    """The key of a job's prepared output: its file, its inputs and fabline's code, hashed together."""
    digest = hashlib.sha256(f"{FORMAT}\0{code_digest()}\0".encode())
    for path, kind in ((spec.path, "config"), *((path, "model") for path in input_files(spec))):
        try:  # vetted as every input is (a FIFO named as the model must not hang the runner's preparer)
            data = read_bytes(path, kind)
        except FablineError as exc:
            raise FablineError(f"{spec.path.name}: {exc}") from None
        digest.update(str(path).encode() + b"\0" + data + b"\0")
    return digest.hexdigest()


def _sha256(path: str | os.PathLike) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _relative(value: Any, folder: Path) -> Any:
    """`value` with every path string inside `folder` made relative to it (marked by a leading `./`)."""
    if isinstance(value, str) and Path(value).is_absolute() and Path(value).is_relative_to(folder):
        return "./" + str(Path(value).relative_to(folder))
    if isinstance(value, (list, tuple)):
        return [_relative(v, folder) for v in value]
    if isinstance(value, dict):
        return {k: _relative(v, folder) for k, v in value.items()}
    return value


def _absolute(value: Any, folder: Path) -> Any:
    """The inverse of `_relative` for another folder."""
    if isinstance(value, str) and value.startswith("./"):
        return str(folder / value[2:])
    if isinstance(value, list):
        return [_absolute(v, folder) for v in value]
    if isinstance(value, dict):
        return {k: _absolute(v, folder) for k, v in value.items()}
    return value


def record(folder: str | os.PathLike, key: str, programs: list[tuple], report: str | None) -> list[int]:
    """Write `prepared.json` into a job folder just prepared: the key, the sheet programs (paths relative to the
    folder) with each G-code file's SHA-256 and command lines (counted once here: that parses every line, 40 s
    for the example job's 430,000 on a busy machine), and the report; returns the line counts."""
    from fabline.machine import load_program

    folder = Path(folder).resolve()
    lines = [len(load_program(p[1]).lines) for p in programs]
    write_json(folder / RECORD, {"format": FORMAT, "key": key, "report": _relative(report, folder),
                                 "programs": [_relative(list(p), folder) for p in programs],
                                 "sha256": [_sha256(p[1]) for p in programs], "lines": lines})
    return lines


def _intact(folder: Path, entry: dict) -> bool:
    try:
        return all(_sha256(_absolute(p[1], folder)) == sha for p, sha in zip(entry["programs"], entry["sha256"]))
    except (OSError, KeyError, TypeError, IndexError):
        return False


def find(runs: str | os.PathLike, key: str, prefer: str | os.PathLike) -> Path | None:
    """The job folder under `runs` prepared with `key` whose programs are unchanged: `prefer` (the job's own
    folder, prepared before the runner stopped) if it is one, else the newest; None if there is none."""
    prefer = Path(prefer).resolve()
    candidates = []
    for path in Path(runs).glob(f"*/{RECORD}"):
        folder = path.parent.resolve()
        try:
            entry = read_json(path)
        except FablineError:
            continue
        if (isinstance(entry, dict) and entry.get("format") == FORMAT and entry.get("key") == key
                and len(entry.get("lines", ())) == len(entry.get("programs", ())) and _intact(folder, entry)):
            candidates.append((folder == prefer, path.stat().st_mtime, folder))
    return max(candidates)[2] if candidates else None


def reuse(source: str | os.PathLike, folder: str | os.PathLike) -> tuple[list[tuple], str | None, list[int]]:
    """Copy a prepared job folder into `folder` (emptied first; hard links where the file system allows, the
    files are never written in place) and return its programs and report with paths into `folder`, and the
    programs' command lines."""
    source, folder = Path(source).resolve(), Path(folder).resolve()
    entry = read_json(source / RECORD)
    programs = [tuple(_absolute(p, folder)) for p in entry["programs"]]
    if source == folder:  # the job's own preparation, finished before the runner stopped
        return programs, _absolute(entry["report"], folder), entry["lines"]
    if folder.exists():
        shutil.rmtree(folder)

    def link(src: str, dst: str) -> None:
        try:
            os.link(src, dst)
        except OSError:
            shutil.copy2(src, dst)

    shutil.copytree(source, folder, copy_function=link)
    return programs, _absolute(entry["report"], folder), entry["lines"]
