"""Shared test fixtures: built-in design networks (built once per session) and a CLI runner."""

from __future__ import annotations

import pytest

from fabline.cli import main
from fabline.model.designs import catenoid_network, enneper_network, helicoid_network


@pytest.fixture(scope="session")
def enneper():
    return enneper_network()


@pytest.fixture(scope="session")
def catenoid():
    return catenoid_network()


@pytest.fixture(scope="session")
def helicoid():
    return helicoid_network()


@pytest.fixture
def cli(capsys):
    """Run `fabline ARGS...` in-process; returns (exit code, stdout, stderr), also of a usage error (SystemExit)."""

    def run(*args: str):
        try:
            code = main([str(a) for a in args])
        except SystemExit as stop:
            code = stop.code if isinstance(stop.code, int) else 1
        out = capsys.readouterr()
        return code, out.out, out.err

    return run
