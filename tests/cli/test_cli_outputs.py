"""Outputs that cannot be written: every command says which path and why in one line, exits 2, and writes
nothing (it checks its output places before it computes), across the stages."""

from __future__ import annotations

import pytest

PROGRAM = "G21\nG90\nG0 X1 Y1\n"


@pytest.fixture(scope="module")
def chain(tmp_path_factory):
    """A small catenoid carried through design, unroll and nest, and a blocker: a file where a folder is expected."""
    from fabline.cli import main

    folder = tmp_path_factory.mktemp("chain")
    network, parts, nesting = folder / "c.network.json", folder / "c.parts.json", folder / "c.nesting.json"
    assert main(["design", "catenoid", "--waist", "1", "--height", "1.5", "--count", "8", "-o", str(network)]) == 0
    assert main(["unroll", str(network), "-o", str(parts), "--no-hardware"]) == 0
    assert main(["nest", str(parts), "-o", str(nesting), "--time-limit", "2"]) == 0
    blocker = folder / "blocker.txt"
    blocker.write_text("a file, not a folder")
    (folder / "program.gcode").write_text(PROGRAM)
    (folder / "job.toml").write_text(f'name = "c"\n[model]\nfile = "{network.name}"\n[output]\nfolder = "out"\n')
    return {"network": network, "parts": parts, "nesting": nesting, "blocker": blocker, "folder": folder}


CASES = {
    "design into a folder": (["design", "catenoid", "-o", "{folder}"], "is a folder, expected a file name"),
    "unroll previews under a file": (["unroll", "{network}", "-o", "{new}/p.json", "--svg", "{blocker}/svg"],
                                     "blocker.txt is a file"),
    "nest pictures under a file": (["nest", "{parts}", "-o", "{new}/n.json", "--svg", "{blocker}/svg"],
                                   "blocker.txt is a file"),
    "nest stock under a file": (["nest", "{parts}", "-o", "{new}/n.json", "--stock-out", "{blocker}/s.json"],
                                "blocker.txt is a file"),
    "export G-code under a file": (["export", "{nesting}", "--dxf", "{new}/dxf", "--gcode", "{blocker}/g"],
                                   "blocker.txt is a file"),
    "stream journal under a file": (["stream", "{folder}/program.gcode", "--port", "sim://outputs",
                                     "--journal", "{blocker}/j"], "blocker.txt is a file"),
    "runner database under a file": (["runner", "submit", "{folder}/job.toml", "--db", "{blocker}/q.sqlite"],
                                     "blocker.txt is a file"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_an_output_that_cannot_be_written_is_one_line_exit_2_nothing_written(case, chain, cli, tmp_path):
    arguments, message = CASES[case]
    new = tmp_path / "new"
    code, _, err = cli(*[a.format(new=new, **chain) for a in arguments])
    assert code == 2, err
    assert err.count("\n") == 1 and message in err, err
    assert not new.exists()
