"""Shared test fixtures: built-in design networks (built once per session) and a CLI runner."""

from __future__ import annotations

import atexit
import os
import shutil
import signal
import tempfile

import pytest

from fabline.cli import main
from fabline.model.designs import catenoid_network, enneper_network, helicoid_network


# runner servers the tests start publish a discovery record in the user's state folder: a folder of the tests' own
os.environ["XDG_STATE_HOME"] = tempfile.mkdtemp(prefix="fabline-test-state-")
atexit.register(shutil.rmtree, os.environ["XDG_STATE_HOME"], True)

# the Ctrl-C tests send SIGINT as a terminal does; a shell's background job starts with SIGINT ignored, and every
# process it starts would inherit that, so the tests run with Python's own handler, as from a terminal
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture(scope="session")
def enneper():
    return enneper_network()


@pytest.fixture(scope="session")
def catenoid():
    return catenoid_network()


@pytest.fixture(scope="session")
def helicoid():
    return helicoid_network()


def without_usage(err: str) -> str:
    """stderr of a command-line mistake without the usage argparse prints after it, checked: one error line
    (`fabline CMD: error: ...`), then at most the usage of that very command, nothing else."""
    error, marker, usage = err.partition("\nusage: ")
    if marker:
        prog = error.split(": error: ", 1)[0]
        assert usage.startswith(f"{prog} ") and "\n\n" not in usage and "Traceback" not in usage, err
        return error + "\n"
    return err


@pytest.fixture
def cli(capsys):
    """Run `fabline ARGS...` in-process; returns (exit code, stdout, stderr), also of a usage error (SystemExit);
    the usage after an argparse error is checked and left out (`without_usage`)."""

    def run(*args: str):
        try:
            code = main([str(a) for a in args])
        except SystemExit as stop:
            code = stop.code if isinstance(stop.code, int) else 1
        out = capsys.readouterr()
        return code, out.out, without_usage(out.err)

    return run


CAMPAIGNS = ("test_bad_input_campaign.py", "test_hostile_campaign.py")


def pytest_terminal_summary(terminalreporter):
    _campaign_counts(terminalreporter)
    _time_per_folder(terminalreporter)


def _time_per_folder(terminalreporter):
    """The suite's time per folder (a stage's tests): the sum of its tests' set-up, call and tear-down times, and
    its count of tests. Workers run files side by side, so the sums add up to more than the wall time."""
    seconds: dict[str, float] = {}
    tests: dict[str, set] = {}
    for reports in terminalreporter.stats.values():
        for report in reports:
            nodeid, duration = getattr(report, "nodeid", ""), getattr(report, "duration", None)
            if not nodeid.startswith("tests/") or duration is None:
                continue
            parts = nodeid.split("::")[0].split("/")
            folder = parts[1] if len(parts) > 2 else "(top)"
            seconds[folder] = seconds.get(folder, 0.0) + duration
            tests.setdefault(folder, set()).add(nodeid)
    if seconds:
        terminalreporter.write_sep("-", "time per folder (sum of test times; workers run files side by side)")
        for folder, total in sorted(seconds.items(), key=lambda item: -item[1]):
            terminalreporter.write_line(f"{folder:<12}{total:>9.1f} s{len(tests[folder]):>7} tests")
        terminalreporter.write_line(f"{'total':<12}{sum(seconds.values()):>9.1f} s{sum(map(len, tests.values())):>7} tests")


def _campaign_counts(terminalreporter):
    """The campaigns' count of cases per reader (per output kind, number option and hostile kind), in every run that
    ran them, even with -q."""
    counts: dict[str, list[int]] = {}
    for outcome in ("passed", "failed", "skipped"):
        for report in terminalreporter.stats.get(outcome, []):
            nodeid = getattr(report, "nodeid", "")
            if not any(name in nodeid for name in CAMPAIGNS) or "[" not in nodeid or report.when not in ("call", "setup"):
                continue
            if outcome != "skipped" and report.when == "setup":
                continue
            case = nodeid.split("[", 1)[1]
            reader = (case.split(":")[0] if "output_that_must_not" not in nodeid
                      else "outputs: " + case.rsplit("-", 1)[-1].rstrip("]"))
            counts.setdefault(reader, [0, 0, 0])[("passed", "failed", "skipped").index(outcome)] += 1
    if counts:
        terminalreporter.write_sep("-", "bad-input campaign: cases per reader (passed/failed/skipped)")
        for reader, (passed, failed, skipped) in sorted(counts.items()):
            terminalreporter.write_line(f"{reader:<32}{passed + failed + skipped:>5}   {passed}/{failed}/{skipped}")
        terminalreporter.write_line(f"{'total':<32}{sum(map(sum, counts.values())):>5}")
