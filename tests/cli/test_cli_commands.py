"""The command line loads only the module of the command it runs: its table of commands must match the modules."""

from __future__ import annotations

import argparse
import importlib
import subprocess
import sys

from fabline.cli import STAGE_COMMANDS, main


def test_each_cli_module_registers_exactly_the_commands_the_table_lists():
    for module, commands in STAGE_COMMANDS.items():
        subparsers = argparse.ArgumentParser().add_subparsers()
        importlib.import_module(f"fabline.cli.{module}").register(subparsers)
        assert tuple(subparsers.choices) == commands, module


def test_help_lists_every_command_and_an_unknown_command_is_a_usage_error(capsys):
    for argv, code in ((["--help"], 0), (["frobnicate"], 2)):
        try:
            main(argv)
        except SystemExit as exit_:
            assert exit_.code == code
    out, err = capsys.readouterr()
    assert all(command in out for commands in STAGE_COMMANDS.values() for command in commands)
    assert "invalid choice: 'frobnicate'" in err


def test_a_format_only_command_does_not_import_the_solvers():
    """`fabline export` reads parts.json and nesting.json: the unroller, the nester and the survey stay unloaded."""
    code = ("import sys; from fabline.cli import build_parser; build_parser(('export',)).parse_args(['export', 'n.json']);"
            "import fabline.export, fabline.nest.layout, fabline.unroll.parts;"
            "print(sorted(m for m in ('fabline.unroll.unroller', 'fabline.nest.nester', 'fabline.survey', 'scipy.signal',"
            " 'trimesh') if m in sys.modules))")
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert loaded == "[]"
