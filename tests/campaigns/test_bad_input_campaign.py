"""The bad-input campaign (issue 16): generated cases per reader (every file format fabline reads), per number
option and per kind of output (device, FIFO, socket, symlink to an input, same as an input, unwritable, full
disk). Every case must end in one line on stderr and exit 2, leave every input byte-identical and leave no
output or temp file. The count of cases per reader is printed at the end of the run (conftest.py)."""

from __future__ import annotations

import argparse
import json
import os
import shutil
import socket
import stat
import subprocess
import zlib
from pathlib import Path

import numpy as np
import pytest

from conftest import without_usage
from fabline.cli import STAGE_COMMANDS, build_parser, main

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


# --- the world: one valid file of every format, made once --------------------------------------------------

_WORLD: list[Path] = []


@pytest.fixture(scope="module")
def world():
    return world_folder()


def world_folder() -> Path:
    """The world's folder, made once per session (its files also name the cases, at collection)."""
    if not _WORLD:
        import atexit
        import tempfile

        folder = Path(tempfile.mkdtemp(prefix="fabline-campaign-"))
        atexit.register(shutil.rmtree, folder, True)
        _make_world(folder)
        _WORLD.append(folder)
    return _WORLD[0]


def _make_world(folder: Path) -> None:
    """One valid file of every format fabline reads."""
    import cv2
    import rhino3dm
    import trimesh

    from fabline.machine.profile import BUILTIN_DIR
    from fabline.model import load_network, save_network
    from fabline.model.designs import catenoid_network
    from fabline.model.writers import write_dxf, write_obj
    from fabline.shop.stock import StockItem, save_stock
    from fabline.survey.camera import Camera, save_camera

    network = catenoid_network(waist=1.0, height=1.5, count=8)
    save_network(network, folder / "net.json")
    for args in (["unroll", "net.json", "-o", "parts.json", "--no-hardware"],
                 ["nest", "parts.json", "-o", "nesting.json", "--time-limit", "1"]):
        assert _run([folder / a if a.endswith(".json") else a for a in args])[0] == 0
    save_stock([StockItem("sheet", 4000.0, 2000.0, 3)], folder / "stock.json")
    write_obj(load_network(folder / "net.json"), folder / "curves.obj")
    write_dxf(load_network(folder / "net.json"), folder / "curves.dxf")
    plane = trimesh.Trimesh([[-5, -5, 0], [5, -5, 0], [5, 5, 0], [-5, 5, 0]], [[0, 1, 2], [0, 2, 3]])
    plane.export(folder / "surface.stl")
    model = rhino3dm.File3dm()
    model.Objects.AddCurve(rhino3dm.PolylineCurve([rhino3dm.Point3d(0, 0, 0), rhino3dm.Point3d(1, 0, 0)]))
    model.Write(str(folder / "curves.3dm"), 7)
    shutil.copy(BUILTIN_DIR / "grbl-laser.toml", folder / "machine.toml")
    (folder / "materials.toml").write_text('[custom]\ndescription = "test"\nE = 200000.0\nG = 77000.0\n'
                                           'f_y = 230.0\ndensity = 7900.0\n')
    (folder / "job.toml").write_text('name = "campaign"\nstages = ["unroll"]\n[model]\nfile = "net.json"\n'
                                     '[output]\nfolder = "job-out"\n')
    save_camera(Camera(np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]]), np.zeros(5), 640, 480),
                folder / "camera.json")
    photo = (np.random.default_rng(1).random((480, 640)) * 255).astype(np.uint8)
    cv2.imwrite(str(folder / "photo.png"), photo)
    (folder / "program.gcode").write_text("G21\nG90\nG0 X1 Y1\nG1 X5 Y5 F1000\nM2\n")


def _digest(folder: Path, skip: Path | None = None) -> dict:
    """Every file under `folder` (but `skip`) with its kind, size, inode and modification time in ns: a file whose
    bytes changed was written in place (new time) or replaced (new inode)."""
    seen = {}
    for path in sorted(folder.rglob("*")):
        if skip is not None and (path == skip or skip in path.parents):
            continue
        status = path.lstat()
        seen[path.relative_to(folder)] = (stat.S_IFMT(status.st_mode), status.st_size, status.st_ino, status.st_mtime_ns)
    return seen


def _run(args) -> tuple[int, str]:
    """Run the command line in-process; the exit code and stderr (usage errors too: SystemExit, their usage checked
    and left out)."""
    import contextlib
    import io

    err, out = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
        try:
            code = main([str(a) for a in args])
        except SystemExit as stop:
            code = stop.code if isinstance(stop.code, int) else 1
    return code, without_usage(err.getvalue())


def _assert_refused(args, world: Path, out: Path) -> str:
    """The case's contract: exit 2, one line on stderr, the world unchanged, nothing left in `out`, no temp file."""
    before = _digest(world, skip=out)
    existing = _digest(out) if out.exists() else {}
    code, err = _run(args)
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2, f"exit {code}: {err[-500:]}"
    assert len(lines) == 1 and lines[0].startswith("fabline"), err[-500:]
    assert _digest(world, skip=out) == before, "an input changed"
    assert (_digest(out) if out.exists() else {}) == existing, "an output was left"
    assert not [p for p in world.rglob("*.tmp")], "a temp file was left"
    return lines[0]


# --- file cases: per reader, generic byte damage and format-aware mutations ---------------------------------

READERS = {
    # reader: (file in the world, command with {f} for the damaged copy and {out} for the output folder)
    "network": ("net.json", ["import", "{f}", "-o", "{out}/n.json"]),
    "network-unroll": ("net.json", ["unroll", "{f}", "-o", "{out}/p.json", "--no-hardware"]),
    "obj": ("curves.obj", ["import", "{f}", "--surface", "{world}/surface.stl", "-o", "{out}/n.json"]),
    "stl": ("surface.stl", ["import", "{world}/curves.obj", "--surface", "{f}", "-o", "{out}/n.json"]),
    "dxf": ("curves.dxf", ["import", "{f}", "--surface", "{world}/surface.stl", "-o", "{out}/n.json"]),
    "3dm": ("curves.3dm", ["import", "{f}", "-o", "{out}/n.json"]),
    "parts": ("parts.json", ["nest", "{f}", "-o", "{out}/n.json", "--time-limit", "1"]),
    "nesting": ("nesting.json", ["export", "{f}", "--gcode", "{out}/g", "--dxf", "{out}/d"]),
    "stock": ("stock.json", ["nest", "{world}/parts.json", "--stock", "{f}", "-o", "{out}/n.json"]),
    "machine": ("machine.toml", ["export", "{world}/nesting.json", "--machine", "{f}", "--gcode", "{out}/g"]),
    "job": ("job.toml", ["run", "{f}"]),
    "materials": ("materials.toml", ["unroll", "{world}/net.json", "--materials", "{f}", "--material", "custom",
                                     "-o", "{out}/p.json"]),
    "camera": ("camera.json", ["survey", "detect", "{world}/photo.png", "--camera", "{f}", "--tag-size", "0.065"]),
    "photo": ("photo.png", ["survey", "detect", "{f}"]),
    "gcode": ("program.gcode", ["stream", "{f}", "--port", "sim://campaign", "--journal", "{out}/j",
                                "--log", "{out}/l"]),
}
SUFFIX = {"network": ".json", "network-unroll": ".json", "job": ".toml"}


def _png_claiming(width: int, height: int) -> bytes:
    """A PNG whose header claims width x height grey pixels, with one tiny data chunk."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return len(data).to_bytes(4, "big") + kind + data + zlib.crc32(kind + data).to_bytes(4, "big")
    header = width.to_bytes(4, "big") + height.to_bytes(4, "big") + bytes([8, 0, 0, 0, 0])
    return PNG_SIGNATURE + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(b"\0" * 64)) + chunk(b"IEND", b"")


def _generic(data: bytes, reader: str) -> dict[str, bytes]:
    """Damage any file can suffer (a G-code program cut short is a shorter program: not damage it can see)."""
    cut = {} if reader == "gcode" else {"truncated": data[: len(data) // 3]}
    return {"empty": b"", "binary garbage": bytes(range(256)) * 8, **cut,
            "NUL bytes": data[: len(data) // 2] + b"\0" * 64 + data[len(data) // 2:],
            "not UTF-8": b"\xff\xfe\xfa" + data[3:]}


def _json_leaves(value, path=()):
    """(path, value) of every number in a JSON document, first ones first."""
    if isinstance(value, dict):
        for key, item in value.items():
            yield from _json_leaves(item, path + (key,))
    elif isinstance(value, list):
        for k, item in enumerate(value[:3]):
            yield from _json_leaves(item, path + (k,))
    elif isinstance(value, (int, float)) and not isinstance(value, bool):
        yield path, value


def _set(document, path, value):
    target = document
    for key in path[:-1]:
        target = target[key]
    target[path[-1]] = value


REQUIRED_JSON_KEYS = {
    "network": ("schema", "units", "nodes", "lamellas"), "network-unroll": ("nodes", "lamellas"),
    "parts": ("schema", "parts"), "nesting": ("schema", "parts_file", "sheets"), "stock": ("schema", "sheets"),
    "camera": ("schema", "fx", "width"),
}
HUGE = {"1e308": "1e308", "-1e308": "-1e308", "1e400 (infinite)": "1e400", "10**400": "1" + "0" * 400, "NaN": "NaN"}


def _json_cases(reader: str, data: bytes) -> dict:
    """Mutations of a JSON document, each a function making the damaged file (made only when its case runs)."""
    document = json.loads(data)

    def changed(**fields):
        return lambda: json.dumps({**document, **fields}).encode()

    cases = {"deep lists": b"[" * 100000, "deep objects": b'{"a":' * 5000, "top-level list": b"[]",
             "top-level number": b"5", "wrong schema": changed(schema="fabline.other/1")}
    for key in REQUIRED_JSON_KEYS[reader]:
        cases[f"{key} missing"] = lambda key=key: json.dumps({k: v for k, v in document.items() if k != key}).encode()
        for name, wrong in (("a number", 5), ("text", "x"), ("null", None), ("a list", [5]), ("an object", {"a": 5})):
            number = isinstance(document[key], (int, float)) and name == "a number"
            if type(wrong) is not type(document[key]) and not number and not (key == "schema" and name == "text"):
                cases[f"{key} is {name}"] = changed(**{key: wrong})
    if reader in ("network", "network-unroll", "parts", "nesting", "camera"):
        leaves = [path for path, _ in _json_leaves(document) if path[0] not in FREE_FORM]
        for path in leaves[:12:3]:
            for name, text in HUGE.items():
                cases[f"{'.'.join(map(str, path))} = {name}"] = lambda path=path, text=text: _with_number(document, path, text)
    list_key = {"network": "lamellas", "network-unroll": "nodes", "parts": "parts", "nesting": "sheets",
                "stock": "sheets"}.get(reader)
    if list_key:
        items = document[list_key]
        first = items[0]
        cases[f"{list_key} empty"] = changed(**{list_key: []})
        cases[f"{list_key}[0] a number"] = changed(**{list_key: [5] + items[1:]})
        cases[f"{list_key} doubled"] = changed(**{list_key: items + [first]})
        for key in first:
            for name, wrong in (("a number", 5), ("an object", {"a": 5})):
                if key == "id" and name == "a number" or key in FREE_FORM:
                    continue  # ids may be numbers (written back as text)
                if isinstance(first[key], (int, float)) and not isinstance(first[key], bool) and name == "a number":
                    continue
                if reader == "network-unroll" and key == "kind":
                    continue  # a node kind of 5 is named by the reader: covered by "network"
                if type(wrong) is type(first[key]) or key in OPTIONAL_TEXT.get(reader, ()):
                    continue
                cases[f"{list_key}[0].{key} is {name}"] = changed(**{list_key: [{**first, key: wrong}] + items[1:]})
    return cases


def _with_number(document, path, text: str) -> bytes:
    """The document with the number at `path` written as `text` (JSON text: 1e400, 10**400 digits, NaN)."""
    marked = json.loads(json.dumps(document))
    _set(marked, path, "@@")
    return json.dumps(marked).replace('"@@"', text).encode()


OPTIONAL_TEXT = {"parts": ("label", "lamella"), "nesting": ("stock",), "stock": ()}
"""Fields the readers take as labels: any JSON value is written back as its text (not a mistake)."""
FREE_FORM = ("meta", "report", "summary", "profile", "remnants")
"""Records a file carries for people and reports, which no stage computes with: any JSON value is kept as it is."""


def _toml_cases(reader: str, data: bytes, world: Path) -> dict[str, bytes]:
    import tomllib

    table = tomllib.loads(data.decode())
    text = data.decode()
    cases = {"malformed TOML": b"name = [\n", "unknown key": (text.replace("\n[", "\nbogus_setting = 1\n[", 1)
                                                               if "\n[" in text else text + "bogus_setting = 1\n").encode()}
    if reader == "machine":
        cases["vars = 5"] = (text.replace("\n[", "\nvars = 5\n[", 1)).encode()
        chain = world / "chain"
        chain.mkdir(exist_ok=True)
        for k in range(40):
            (chain / f"c{k}.toml").write_text(f'extends = "{chain}/c{k + 1}.toml"\n' if k < 39 else 'extends = "grbl-laser"\n')
        cases["extends chain of 40 files"] = f'extends = "{chain}/c0.toml"\n'.encode()
        cases["extends itself"] = b'extends = "{self}"\n'
    section = {"materials": "custom", "machine": "bed", "job": "model"}[reader]
    for key, value in (table[section].items() if isinstance(table.get(section), dict) else []):
        wrong = '"text"' if isinstance(value, (int, float)) else "5"
        cases[f"{section}.{key} wrong type"] = _replace_key(text, section, key, wrong).encode()
        if isinstance(value, float):
            cases[f"{section}.{key} = -1"] = _replace_key(text, section, key, "-1.0").encode()
            cases[f"{section}.{key} = 1e308"] = _replace_key(text, section, key, "1e308").encode()
            cases[f"{section}.{key} = nan"] = _replace_key(text, section, key, "nan").encode()
    return cases


def _replace_key(text: str, section: str, key: str, value: str) -> str:
    """`text` with `key = ...` in table [section] set to `value` (first occurrence after the header)."""
    head = text.index(f"[{section}]")
    lines = text[head:].splitlines(keepends=True)
    for k, line in enumerate(lines):
        if line.split("=")[0].strip() == key:
            lines[k] = f"{key} = {value}\n"
            break
    return text[:head] + "".join(lines)


def _photo_cases(data: bytes) -> dict[str, bytes]:
    return {"header claims 100000 x 100000": _png_claiming(100000, 100000),
            "header claims 30000 x 30000": _png_claiming(30000, 30000),
            "text with a .png name": b"not an image\n"}


def _gcode_cases() -> dict[str, bytes]:
    return {"system command $H": b"G21\n$H\nG0 X1\n", "$RST=*": b"$RST=*\n", "real-time !": b"G21\n!\n",
            "1e308 coordinate": b"G21\nG0 X1e308\n", "line of 300 characters": b"G21\nG0 X" + b"1" * 300 + b"\n",
            "F0 feed": b"G21\nG1 X5 F0\n"}


def _mesh_cases(reader: str) -> dict[str, bytes]:
    if reader == "obj":
        return {"faces only": b"f 1 2 3\nf 2 3 4\n", "1e308 vertex": b"o A-1\nv 0 0 0\nv 1e308 0 0\nl 1 2\n",
                "line to a missing vertex": b"o A-1\nv 0 0 0\nl 1 7\n"}
    if reader == "stl":
        return {"ASCII STL with words for numbers": b"solid x\nfacet normal 0 0 1\nouter loop\nvertex a b c\n"
                                                    b"endloop\nendfacet\nendsolid x\n"}
    if reader == "dxf":
        return {"0-byte DXF": b"", "number that is not": b"  0\nSECTION\n  2\nENTITIES\n  0\nLINE\n 10\nnot a number\n"}
    return {}


def _file_cases(world: Path) -> list[tuple[str, str, bytes]]:
    cases = []
    for reader, (name, _) in READERS.items():
        data = (world / name).read_bytes()
        generated = _generic(data, reader)
        if name.endswith(".json"):
            generated.update(_json_cases(reader, data))
        elif reader in ("machine", "materials", "job"):
            generated.update(_toml_cases(reader, data, world))
        elif reader == "photo":
            generated.update(_photo_cases(data))
        elif reader == "gcode":
            generated.update(_gcode_cases())
        else:
            generated.update(_mesh_cases(reader))
        cases += [(reader, case, content) for case, content in generated.items()]
    return cases


def pytest_generate_tests(metafunc):
    if "file_case" in metafunc.fixturenames:
        names = [(reader, case) for reader, case, _ in _file_cases(world_folder())]
        metafunc.parametrize("file_case", names, ids=[f"{reader}: {case}" for reader, case in names])


@pytest.fixture(scope="module")
def file_contents(world):
    return {(r, c): content for r, c, content in _file_cases(world)}


def test_a_damaged_input_file_is_one_line_exit_2(file_case, world, file_contents, tmp_path):
    reader, case = file_case
    name, command = READERS[reader]
    content = file_contents[file_case]
    content = content() if callable(content) else content
    damaged = world / f"damaged-{tmp_path.name}{SUFFIX.get(reader, Path(name).suffix)}"
    damaged.write_bytes(content.replace(b"{self}", str(damaged).encode()))
    out = world / f"out-{tmp_path.name}"
    try:
        _assert_refused([a.format(f=damaged, out=out, world=world) for a in command], world, out)
        assert damaged.read_bytes() == content.replace(b"{self}", str(damaged).encode())
    finally:
        damaged.unlink()
        shutil.rmtree(out, ignore_errors=True)
        shutil.rmtree(world / "job-out", ignore_errors=True)


# --- number options: every int and float option of every command, and the size options ----------------------

def _number_options() -> list[tuple[str, tuple[str, ...], str, type]]:
    """(command, its path, option, int or float) of every number option (`bounded` or `positive` types)."""
    found = []

    def walk(parser: argparse.ArgumentParser, path: tuple[str, ...]) -> None:
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    walk(sub, path + (name,))
            elif action.option_strings and getattr(action.type, "__name__", "") in ("int", "float"):
                found.append((" ".join(path), path, action.option_strings[-1], int if action.type.__name__ == "int" else float))

    walk(build_parser(tuple(STAGE_COMMANDS)), ())
    return found


NUMBER_VALUES = {float: ("nan", "-inf", "1e308"), int: ("1" + "0" * 400, "1e3")}
SIZE_OPTIONS = [
    (("survey", "simulate", "--model", "{world}/net.json", "-o", "{out}/s"), "--resolution", ("100000x100000", "1e308x5", "0x0")),
    (("survey", "simulate", "--model", "{world}/net.json", "-o", "{out}/s"), "--photos", ("100000000",)),
    (("nest", "{world}/parts.json", "-o", "{out}/n.json"), "--sheet-size", ("1e308x2000", "nanx2000", "-4000x2000", "4000", "4 furlong x 2")),
    (("nest", "{world}/parts.json", "-o", "{out}/n.json"), "--remnant-min", ("1e308x5", "x", "0x0")),
    (("unroll", "{world}/net.json", "-o", "{out}/p.json"), "--profile", ("1e308x1.5", "100x0", "nanx1.5")),
    (("design", "enneper", "-o", "{out}/e.json"), "--size", ("1e308x12", "infx12", "0x0")),
    (("design", "catenoid", "-o", "{out}/e.json"), "--count", ("100000000",)),
]


def _number_cases() -> list[tuple[str, tuple, str, str]]:
    cases = []
    for label, path, option, kind in _number_options():
        cases += [(label, path, option, value) for value in NUMBER_VALUES[kind]]
    cases += [(" ".join(a for a in command if not a.startswith(("{", "-"))), command, option, value)
              for command, option, values in SIZE_OPTIONS for value in values]
    return cases


@pytest.mark.parametrize("label, path, option, value", _number_cases(),
                         ids=[f"option: {c[0]} {c[2]} {c[3][:12]}" for c in _number_cases()])
def test_a_bad_number_option_is_one_line_exit_2(label, path, option, value, world, tmp_path):
    out = world / f"out-{tmp_path.name}"
    args = [a.format(world=world, out=out) for a in path] + [option, value]
    try:
        _assert_refused(args, world, out)
    finally:
        shutil.rmtree(out, ignore_errors=True)


# --- outputs: every kind of place an output must not go, for every writing command -------------------------

WRITERS = {
    # command: (arguments with {o} for the output), whether {o} is a folder
    "design -o": (["design", "catenoid", "--count", "8", "-o", "{o}"], False),
    "import -o": (["import", "{world}/net.json", "-o", "{o}"], False),
    "unroll -o": (["unroll", "{world}/net.json", "--no-hardware", "-o", "{o}"], False),
    "unroll --svg": (["unroll", "{world}/net.json", "--no-hardware", "-o", "{side}/p.json", "--svg", "{o}"], True),
    "nest -o": (["nest", "{world}/parts.json", "--time-limit", "1", "-o", "{o}"], False),
    "nest --stock-out": (["nest", "{world}/parts.json", "--time-limit", "1", "-o", "{side}/n.json", "--stock-out", "{o}"],
                         False),
    "nest --svg": (["nest", "{world}/parts.json", "--time-limit", "1", "-o", "{side}/n.json", "--svg", "{o}"], True),
    "export --gcode": (["export", "{world}/nesting.json", "--gcode", "{o}"], True),
    "export --dxf": (["export", "{world}/nesting.json", "--gcode", "{side}/g", "--dxf", "{o}"], True),
    "survey tags -o": (["survey", "tags", "--model", "{world}/net.json", "-o", "{o}"], True),
    "survey calibrate --write-board": (["survey", "calibrate", "--write-board", "{o}"], False),
    "stream --log": (["stream", "{world}/program.gcode", "--port", "sim://outputs", "--journal", "{side}/j",
                      "--log", "{o}"], False),
    "stream --journal": (["stream", "{world}/program.gcode", "--port", "sim://outputs", "--journal", "{o}",
                          "--log", "{records}/exchange.log"], False),  # the exchange log records the refusal
}
OUTPUT_KINDS = ("device", "FIFO", "socket", "symlink to an input", "same as an input", "unwritable", "full disk",
                "a file in the path")


@pytest.fixture(scope="module")
def mounts(tmp_path_factory):
    """A read-only and a 4 KiB tmpfs, where this test may mount them (as root); else None with the reason."""
    base = tmp_path_factory.mktemp("mounts")
    made = {}
    for name, options in (("readonly", "ro,size=64k"), ("full", "size=4k")):
        place = base / name
        place.mkdir()
        result = subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(place)], capture_output=True, text=True)
        made[name] = place if result.returncode == 0 else f"cannot mount a tmpfs here: {result.stderr.strip()}"
    if isinstance(made["full"], Path):  # fill it: every write there fails, however small
        with open(made["full"] / "filler", "wb", buffering=0) as handle:
            try:
                while True:
                    handle.write(b"\0" * 1024)
            except OSError:
                pass
    yield made
    for place in made.values():
        if isinstance(place, Path):
            subprocess.run(["umount", str(place)], capture_output=True)


def _applies(writer: str, kind: str) -> bool:
    """Whether an output kind can be tried on a writer: only a file output of a command that reads an input file
    can be pointed at that input."""
    arguments, folder = WRITERS[writer]
    if kind in ("symlink to an input", "same as an input"):
        return not folder and any(a.startswith("{world}/") for a in arguments)
    return True


OUTPUT_CASES = [(writer, kind) for writer in sorted(WRITERS) for kind in OUTPUT_KINDS if _applies(writer, kind)]


@pytest.mark.parametrize("writer, kind", OUTPUT_CASES, ids=[f"{w}-{k}" for w, k in OUTPUT_CASES])
def test_an_output_that_must_not_be_written_is_one_line_exit_2(writer, kind, world, mounts, tmp_path):
    arguments, folder = WRITERS[writer]
    side = tmp_path / "side"
    target = tmp_path / "target"
    server = None
    if kind == "device":
        os.mknod(target, stat.S_IFCHR | 0o666, os.makedev(1, 7))  # /dev/full's numbers
    elif kind == "FIFO":
        os.mkfifo(target)
    elif kind == "socket":
        server = socket.socket(socket.AF_UNIX)
        server.bind(str(target))
    elif kind in ("symlink to an input", "same as an input"):
        source = Path(next(a for a in arguments if a.startswith("{world}/")).format(world=world))
        if kind == "same as an input":
            target = source
        else:
            target.symlink_to(source)
    elif kind == "unwritable":
        if not isinstance(mounts["readonly"], Path):
            pytest.skip(mounts["readonly"])
        target = mounts["readonly"] / "x"
    elif kind == "full disk":
        if not isinstance(mounts["full"], Path):
            pytest.skip(mounts["full"])
        target = mounts["full"] / tmp_path.name
    else:
        blocker = tmp_path / "blocker"
        blocker.write_text("a file")
        target = blocker / "x"
    try:
        args = [a.format(world=world, o=target, side=side, records=tmp_path / "records") for a in arguments]
        line = _assert_refused(args, world, side)
        if kind in ("device", "FIFO", "socket"):
            assert not stat.S_ISREG(target.lstat().st_mode)
        if kind == "symlink to an input":
            assert target.is_symlink()
        if kind == "full disk":
            assert "No space left on device" in line, line
            assert os.listdir(mounts["full"]) == ["filler"]
        assert not [p for p in tmp_path.rglob("*.tmp")]
    finally:
        if server is not None:
            server.close()
