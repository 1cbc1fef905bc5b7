"""Inputs are vetted as outputs are (issue 25, item 9): every command that reads a file refuses at once, in one line
naming the path, a FIFO (which would block the reader until killed), a device (/dev/zero: MemoryError after half a
minute), a folder, a file over its kind's size limit and a path holding a NUL byte; undecodable text names the
byte offset. The FIFO cases run the real command line in a process of its own, so that a hang fails the test."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fabline.errors import FablineError
from fabline.fileio import INPUT_LIMITS, open_input, read_text

from .test_cli_outputs import chain  # noqa: F401 (the fixture: a small catenoid's model, parts and nesting)

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
REPO = EXAMPLES.parent

# reader -> (argv, with {x} for the vetted input, {network} {parts} {nesting} {photo} {out} for good files; the
# input's suffix; its kind in INPUT_LIMITS)
READERS = {
    "inspect": (["inspect", "{x}"], ".json", "json"),
    "import obj": (["import", "{x}", "-o", "{out}/n.json"], ".obj", "model"),
    "import dxf": (["import", "{x}", "-o", "{out}/n.json"], ".dxf", "model"),
    "import 3dm": (["import", "{x}", "-o", "{out}/n.json"], ".3dm", "model"),
    "import json": (["import", "{x}", "-o", "{out}/n.json"], ".json", "json"),
    "import --surface": (["import", str(EXAMPLES / "curves.obj"), "--surface", "{x}", "-o", "{out}/n.json"], ".stl",
                         "model"),
    "design asymptotic --surface": (["design", "asymptotic", "--surface", "{x}", "--spacing", "0.5", "-o",
                                     "{out}/n.json"], ".obj", "model"),
    "design minimal --boundary": (["design", "minimal", "--boundary", "{x}", "--mesh-size", "0.5", "-o",
                                   "{out}/s.obj"], ".dxf", "model"),
    "unroll": (["unroll", "{x}", "-o", "{out}/p.json"], ".json", "json"),
    "unroll --materials": (["unroll", "{network}", "--materials", "{x}", "-o", "{out}/p.json"], ".toml", "config"),
    "nest": (["nest", "{x}", "-o", "{out}/n.json"], ".json", "json"),
    "nest --stock": (["nest", "{parts}", "--stock", "{x}", "-o", "{out}/n.json"], ".json", "json"),
    "nest --check": (["nest", "--check", "{x}"], ".json", "json"),
    "export": (["export", "{x}", "-o", "{out}/e"], ".json", "json"),
    "export --machine": (["export", "{nesting}", "--machine", "{x}", "-o", "{out}/e"], ".toml", "config"),
    "gcode-check": (["gcode-check", "{x}"], ".gcode", "gcode"),
    "stream": (["stream", "{x}", "--port", "sim://vet?time_scale=500", "--journal", "{out}/j"], ".gcode", "gcode"),
    "survey detect": (["survey", "detect", "{x}"], ".png", "photo"),
    "survey detect --camera": (["survey", "detect", "{photo}", "--camera", "{x}", "--tag-size", "50"], ".json", "json"),
    "survey tags --model": (["survey", "tags", "--model", "{x}", "-o", "{out}/t"], ".json", "json"),
    "run": (["run", "{x}"], ".toml", "config"),
}


@pytest.fixture(scope="module")
def goods(chain, tmp_path_factory):  # noqa: F811
    """The good files the readers' other arguments name: the chain's, and a small photo."""
    import cv2

    folder = tmp_path_factory.mktemp("goods")
    photo = folder / "photo.png"
    cv2.imwrite(str(photo), np.full((64, 64), 200, np.uint8))
    return {"network": chain["network"], "parts": chain["parts"], "nesting": chain["nesting"], "photo": photo}


def _argv(reader: str, x, goods, out) -> list[str]:
    argv, _, _ = READERS[reader]
    return [a.format(x=x, out=out, **goods) for a in argv]


def _fabline(argv: list[str], cwd) -> subprocess.CompletedProcess:
    """Run the command line in its own process; a reader that blocks is killed after 60 s and fails the test."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, (os.environ.get("PYTHONPATH"), str(REPO)))))
    try:
        return subprocess.run([sys.executable, "-m", "fabline", *argv], cwd=cwd, env=env, capture_output=True,
                              text=True, timeout=60)
    except subprocess.TimeoutExpired:
        pytest.fail(f"fabline {' '.join(argv)}: still reading after 60 s")


def _one_line(code: int, err: str, *words: str) -> None:
    assert code == 2 and err.count("\n") == 1 and "Traceback" not in err, err
    for word in words:
        assert word in err, err


@pytest.mark.parametrize("reader", sorted(READERS))
def test_a_fifo_as_any_input_is_refused_at_once_in_one_line(reader, goods, tmp_path):
    fifo = tmp_path / f"in{READERS[reader][1]}"
    os.mkfifo(fifo)
    done = _fabline(_argv(reader, fifo, goods, tmp_path / "out"), tmp_path)
    _one_line(done.returncode, done.stderr, f"{fifo}: is a FIFO (named pipe), not a regular file")
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("reader", sorted(READERS))
@pytest.mark.parametrize("what", ["device", "folder", "oversized"])
def test_a_device_a_folder_or_an_oversized_file_as_any_input_is_refused(reader, what, goods, cli, tmp_path):
    _, suffix, kind = READERS[reader]
    path = tmp_path / f"in{suffix}"
    if what == "device":
        path.symlink_to("/dev/zero")
        expected = f"{path}: is a character device, not a regular file"
    elif what == "folder":
        path.mkdir()
        expected = f"{path}: is a folder, not a regular file"
    else:
        with open(path, "wb") as handle:  # sparse: no disk space is used
            handle.truncate(INPUT_LIMITS[kind] + 1)
        expected = f"{path}: {INPUT_LIMITS[kind] + 1} bytes, more than the {INPUT_LIMITS[kind]} bytes"
    code, _, err = cli(*_argv(reader, path, goods, tmp_path / "out"))
    _one_line(code, err, expected)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("reader", sorted(READERS))
def test_a_nul_byte_in_any_input_path_is_refused(reader, goods, cli, tmp_path):
    path = f"{tmp_path}/in\0put{READERS[reader][1]}"
    code, _, err = cli(*_argv(reader, path, goods, tmp_path / "out"))
    _one_line(code, err, "holds a NUL byte")
    assert "embedded null" not in err


def test_a_nul_byte_in_a_nestings_parts_file_is_refused(chain, cli, tmp_path):  # noqa: F811
    data = json.loads(chain["nesting"].read_text())
    data["parts_file"] = "c.parts\0.json"
    nesting = tmp_path / "n.json"
    nesting.write_text(json.dumps(data))
    for argv in (["nest", "--check", nesting], ["export", nesting, "-o", tmp_path / "e"]):
        code, _, err = cli(*argv)
        _one_line(code, err, "holds a NUL byte")


def test_a_fifo_as_a_nestings_parts_file_or_a_jobs_model_is_refused_at_once(chain, goods, tmp_path):  # noqa: F811
    fifo = tmp_path / "fifo.json"
    os.mkfifo(fifo)
    data = json.loads(chain["nesting"].read_text())
    data["parts_file"] = str(fifo)
    (tmp_path / "n.json").write_text(json.dumps(data))
    done = _fabline(["nest", "--check", "n.json"], tmp_path)
    _one_line(done.returncode, done.stderr, f"{fifo}: is a FIFO")
    (tmp_path / "job.toml").write_text(f'name = "f"\n[model]\nfile = "{fifo}"\n[output]\nfolder = "out"\n')
    done = _fabline(["run", "job.toml"], tmp_path)
    _one_line(done.returncode, done.stderr, "is a FIFO")
    assert not (tmp_path / "out").exists()


def test_undecodable_text_names_the_file_and_the_byte_offset(cli, tmp_path):
    path = tmp_path / "n.json"
    path.write_bytes(b'{"format": "fabline.network/1", "name": "caf\xe9"}')
    code, _, err = cli("inspect", path)
    _one_line(code, err, f"{path}: cannot read: not UTF-8 text at byte 44 (0xe9: ")
    with pytest.raises(FablineError, match=r"job.toml: cannot read: not UTF-8 text at byte 2 \(0xff"):
        (tmp_path / "job.toml").write_bytes(b"# \xff\n")
        read_text(tmp_path / "job.toml", kind="config")


def test_open_input_reads_a_regular_file_and_a_symlink_to_one(tmp_path):
    real = tmp_path / "real.json"
    real.write_bytes(b"[1]")
    (tmp_path / "link.json").symlink_to(real)
    for path in (real, tmp_path / "link.json"):
        with open_input(path, "json") as handle:
            assert handle.read() == b"[1]"
    with pytest.raises(FablineError, match="missing.json: file not found"):
        open_input(tmp_path / "missing.json", "json")


def test_a_fifo_among_the_survey_photos_is_named_at_once(tmp_path):
    photos = tmp_path / "photos"
    photos.mkdir()
    os.mkfifo(photos / "a.png")
    done = _fabline(["survey", "calibrate", str(photos), "-o", str(tmp_path / "camera.json")], tmp_path)
    _one_line(done.returncode, done.stderr, f"{photos / 'a.png'}: is a FIFO (named pipe), not a regular file")
    assert not (tmp_path / "camera.json").exists()
