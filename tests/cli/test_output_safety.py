"""Output safety (issue 16, items 1, 2, 8, 16): no command replaces a device, FIFO or socket, destroys one of its
inputs or leaves part of its outputs behind when it fails; a symlink is written through; temp files orphaned by
a killed run are swept; a Ctrl-C never leaves a complete file reported as "interrupted"."""

from __future__ import annotations

import os
import signal
import socket
import stat
import time

import pytest

from fabline import fileio
from fabline.errors import FablineError
from fabline.fileio import OutputSet, atomic_output, check_outputs, sweep_orphans, write_json

from .test_cli_outputs import chain  # noqa: F401 (the fixture: a small catenoid's model, parts and nesting)


def _snapshot(folder):
    return {p.relative_to(folder): p.read_bytes() for p in folder.rglob("*") if p.is_file() and not p.is_symlink()}


def _special(kind: str, path):
    """Make a FIFO, a socket or a character device (/dev/full's numbers) at `path`; skip where it cannot be."""
    if kind == "fifo":
        os.mkfifo(path)
    elif kind == "socket":
        server = socket.socket(socket.AF_UNIX)
        server.bind(str(path))
        return server
    else:
        try:
            os.mknod(path, stat.S_IFCHR | 0o666, os.makedev(1, 7))
        except PermissionError:
            pytest.skip("cannot make a device node here (not root)")
    return None


@pytest.mark.parametrize("kind", ["fifo", "socket", "device"])
def test_an_output_that_is_not_a_regular_file_is_refused_and_kept(kind, chain, cli, tmp_path):
    target = tmp_path / "out.json"
    server = _special(kind, target)
    try:
        code, _, err = cli("design", "catenoid", "--count", "8", "-o", target)
        mode = os.lstat(target).st_mode
    finally:
        if server is not None:
            server.close()
    assert code == 2 and err.count("\n") == 1 and "not a regular file" in err, err
    assert {"fifo": stat.S_ISFIFO, "socket": stat.S_ISSOCK, "device": stat.S_ISCHR}[kind](mode)
    assert sorted(os.listdir(tmp_path)) == ["out.json"]


def test_a_symlink_is_written_through_and_stays_a_link(chain, cli, tmp_path):
    real = tmp_path / "real.json"
    real.write_text("old")
    link = tmp_path / "link.json"
    link.symlink_to(real)
    code, _, err = cli("design", "catenoid", "--count", "8", "-o", link)
    assert code == 0, err
    assert link.is_symlink() and os.readlink(link) == str(real)
    assert real.read_text().startswith("{") and sorted(os.listdir(tmp_path)) == ["link.json", "real.json"]


SAME_AS_INPUT = {
    "unroll -o model": ["unroll", "{network}", "-o", "{network}"],
    "nest -o parts": ["nest", "{parts}", "-o", "{parts}"],
    "nest --stock-out parts": ["nest", "{parts}", "-o", "{folder}/x.json", "--stock-out", "{parts}"],
    "import -o curves": ["import", "{network}", "-o", "{network}"],
    "stream --log program": ["stream", "{folder}/program.gcode", "--port", "sim://same", "--log", "{folder}/program.gcode"],
    "stream --journal program": ["stream", "{folder}/program.gcode", "--port", "sim://same",
                                 "--journal", "{folder}/program.gcode"],
    "unroll -o a hard link of the model": ["unroll", "{network}", "-o", "{folder}/hardlink.json"],
    "nest -o parts through another path": ["nest", "{parts}", "-o", "{folder}/../{folder.name}/c.parts.json"],
}


@pytest.mark.parametrize("case", sorted(SAME_AS_INPUT))
def test_an_output_that_is_an_input_is_refused_and_the_input_kept(case, chain, cli):
    folder = chain["folder"]
    hardlink = folder / "hardlink.json"
    if not hardlink.exists():
        os.link(chain["network"], hardlink)
    before = _snapshot(folder)
    code, _, err = cli(*[a.format(**chain) for a in SAME_AS_INPUT[case]])
    assert code == 2 and err.count("\n") == 1 and "is also an input of this command" in err, err
    assert _snapshot(folder) == before


def test_two_outputs_on_one_file_are_refused(chain, cli, tmp_path):
    code, _, err = cli("nest", chain["parts"], "-o", tmp_path / "n.json", "--stock-out", tmp_path / "n.json")
    assert code == 2 and "named twice as an output" in err, err
    assert os.listdir(tmp_path) == []


def test_a_trailing_slash_names_a_folder_not_a_file(cli, tmp_path):
    code, _, err = cli("design", "catenoid", "--count", "8", "-o", f"{tmp_path}/newdir/")
    assert code == 2 and err.count("\n") == 1 and "names a folder" in err, err
    assert os.listdir(tmp_path) == []


def test_unroll_whose_previews_fail_removes_parts_json_too(chain, cli, tmp_path):
    svg = tmp_path / "svg"
    svg.mkdir()
    os.mkfifo(svg / "B-004-L.svg")  # one preview's name is taken by a FIFO, found only when that preview is written
    code, _, err = cli("unroll", chain["network"], "-o", tmp_path / "p.json", "--no-hardware", "--svg", svg)
    assert code == 2 and "not a regular file" in err, err
    assert sorted(os.listdir(tmp_path)) == ["svg"] and os.listdir(svg) == ["B-004-L.svg"]


def test_export_that_fails_midway_leaves_nothing_and_restores_what_it_replaced(chain, cli, tmp_path, monkeypatch):
    gcode = tmp_path / "g"
    assert cli("export", chain["nesting"], "--gcode", gcode, "--dxf", tmp_path / "d")[0] == 0
    before = _snapshot(tmp_path)
    assert len(before) >= 3
    real_replace, calls = os.replace, []

    def disk_full_on_third(source, target):
        calls.append(target)
        if len(calls) == 3:
            raise OSError(28, "No space left on device")
        real_replace(source, target)

    monkeypatch.setattr(fileio.os, "replace", disk_full_on_third)
    code, _, err = cli("export", chain["nesting"], "--gcode", gcode, "--dxf", tmp_path / "d")
    monkeypatch.undo()
    assert code == 2 and "No space left on device" in err, err
    assert _snapshot(tmp_path) == before and not [p for p in tmp_path.rglob(".*")]
    fresh = tmp_path / "fresh"
    monkeypatch.setattr(fileio.os, "replace", disk_full_on_third)
    calls.clear()
    code, _, err = cli("export", chain["nesting"], "--gcode", fresh / "g", "--dxf", fresh / "d")
    assert code == 2 and not fresh.exists()


def test_orphaned_temp_files_of_a_killed_run_are_swept_on_the_next_write(tmp_path):
    dead = os.fork()
    if dead == 0:
        os._exit(0)
    os.waitpid(dead, 0)
    old = time.time() - 3600
    orphans = [tmp_path / f".parts.json.fabline{dead}-ab12cd34.tmp", tmp_path / f".x.svg.fabline{dead}-zz.tmp"]
    alive = tmp_path / f".n.json.fabline{os.getppid()}-ab12cd34.tmp"   # a running process's temp file
    foreign = tmp_path / ".notes.txt.ab12cd34.tmp"                      # not our pattern
    for path in orphans + [alive, foreign]:
        path.write_bytes(b"x" * 100)
        os.utime(path, (old, old))
    write_json(tmp_path / "n.json", {"a": 1})
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([alive.name, foreign.name, "n.json"])
    assert sweep_orphans(tmp_path) == 0  # once per folder and process


def test_a_ctrl_c_right_after_the_rename_leaves_no_file_reported_as_interrupted(cli, tmp_path, monkeypatch):
    """A Ctrl-C after the rename but before the command ends: the output is removed and the old one is back,
    so "interrupted" is true; a Ctrl-C while the command commits its outputs is too late to interrupt it."""
    target = tmp_path / "n.json"
    target.write_text("previous")
    real_replace = os.replace

    def replace_then_interrupt(source, destination):
        real_replace(source, destination)
        signal.raise_signal(signal.SIGINT)

    monkeypatch.setattr(fileio.os, "replace", replace_then_interrupt)
    code, _, err = cli("design", "catenoid", "--count", "8", "-o", target)
    assert code == 130 and "interrupted; nothing was written" in err, err
    assert target.read_text() == "previous" and os.listdir(tmp_path) == ["n.json"]
    monkeypatch.undo()

    real_commit = OutputSet.commit

    def commit_interrupted(self):
        signal.raise_signal(signal.SIGINT)
        real_commit(self)

    monkeypatch.setattr(OutputSet, "commit", commit_interrupted)
    code, out, err = cli("design", "catenoid", "--count", "8", "-o", target)
    assert code == 0 and "interrupted" not in err, err
    assert target.read_text().startswith("{") and os.listdir(tmp_path) == ["n.json"]


def test_nested_output_sets_hand_their_files_to_the_enclosing_one(tmp_path):
    (tmp_path / "a").write_text("old a")
    with pytest.raises(FablineError):
        with OutputSet():
            with OutputSet():
                write_json(tmp_path / "a", 1)
                write_json(tmp_path / "sub" / "b", 2)
            write_json(tmp_path / "a", 3)
            raise FablineError("a later stage fails")
    assert sorted(os.listdir(tmp_path)) == ["a"] and (tmp_path / "a").read_text() == "old a"
    with OutputSet() as outputs:
        check_outputs(inputs=(tmp_path / "a",))
        with pytest.raises(FablineError, match="is also an input"):
            with atomic_output(tmp_path / "a") as handle:
                handle.write("lost")
    assert outputs.written == {} and (tmp_path / "a").read_text() == "old a"
