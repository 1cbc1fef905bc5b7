"""Port URLs are inputs and outputs too (issue 25 items 1 and 7): pyserial acts on a URL's options as it parses it
(`spy://...?file=F` truncates F before the port opens), so options are checked against what each handler takes
and a file a URL writes is checked like any output before pyserial sees the URL; the port lock is the endpoint's."""

from __future__ import annotations

import socket
import time

import pytest

from fabline.errors import FablineError
from fabline.jobs.jobfile import load_job_file
from fabline.jobs.queue import JobQueue
from fabline.jobs.runner import MachineConfig, Runner
from fabline.link import Streamer, check_port
from fabline.link.ports import port_endpoints
from fabline.locks import exclusive_lock, lock_path

PROGRAM = "G21\nG90\nG1 X1 Y1 F600\n"
JOB = """
name = "ports"
stages = ["unroll", "nest", "export", "stream"]
[model]
design = "enneper"
[model.options]
size = [1.5, 1.5]
spacing = 0.5
[machine]
port = "{port}"
[output]
folder = "out"
"""


@pytest.fixture
def program(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "a.gcode").write_text(PROGRAM, encoding="ascii")
    return tmp_path / "a.gcode"


@pytest.mark.parametrize("port", ["spy:///dev/null?file=a.gcode", "sim://probe-a?log=a.gcode",
                                  "spy:///dev/null?color&file=./a.gcode", "sim://probe-b?log=x.log&log=a.gcode"])
def test_the_probes_command_refuses_and_the_input_survives(cli, program, port):
    code, _, err = cli("stream", "a.gcode", "--port", port)
    assert code == 2 and err.count("\n") == 1 and f"port {port}" in err and "is also an input" in err, err
    assert program.read_text(encoding="ascii") == PROGRAM


def test_a_port_file_that_is_a_device_or_the_journal_is_refused(cli, program):
    for port, said in (("sim://probe-c?log=/dev/null", "not a regular file"),
                       ("spy:///dev/null?file=a.gcode.journal", "named twice")):
        code, _, err = cli("stream", "a.gcode", "--port", port)
        assert code == 2 and said in err, err


@pytest.mark.parametrize("port, option", [("sim://grbl?bogus=1", "bogus"), ("spy:///dev/null?files=x", "files"),
                                          ("socket://127.0.0.1:9?timeout=3", "timeout"),
                                          ("rfc2217://127.0.0.1:9?file=x", "file"), ("loop://?log=x", "log"),
                                          ("cp2110:///dev/hidraw0?x=1", "x")])
def test_an_option_its_handler_does_not_take_is_refused_naming_what_it_takes(port, option):
    with pytest.raises(FablineError, match=f"unknown option '{option}' for"):
        check_port(port)


@pytest.mark.parametrize("port", ["sim://grbl?time_scale=100&machine=grbl-laser&settings=32:1", "sim://x",
                                  "socket://127.0.0.1:23?logging=debug", "/dev/ttyUSB0",
                                  "rfc2217://host:2217?ign_set_control&poll_modem&timeout=3&logging=info",
                                  "spy:///dev/ttyUSB0?color&raw&all", "loop://", "hwgrep://USB&n=2&skip_busy"])
def test_what_pyserial_takes_passes(port):
    assert check_port(port) == []


def test_unknown_schemes_and_log_levels_are_refused():
    with pytest.raises(FablineError, match="unknown scheme ftp://"):
        check_port("ftp://host/x")
    with pytest.raises(FablineError, match="logging='loud'"):
        check_port("socket://127.0.0.1:9?logging=loud")  # pyserial would raise a KeyError


@pytest.mark.parametrize("scheme", ["spy:///dev/null?file", "sim://job-log?log"])
def test_a_job_files_port_writes_only_inside_its_output_folder(tmp_path, cli, scheme):
    victim = tmp_path / "elsewhere" / "victim.txt"
    victim.parent.mkdir()
    victim.write_text("keep me\n")
    job = tmp_path / "ports.toml"
    job.write_text(JOB.format(port=f"{scheme}={victim}"), encoding="utf-8")
    code, out, err = cli("run", job)
    assert code == 2 and err.count("\n") == 1 and "ports.toml: machine.port:" in err and "outside the job's output " \
        "folder" in err, err
    assert victim.read_text() == "keep me\n" and not (tmp_path / "out").exists()
    job.write_text(JOB.format(port=f"{scheme}={tmp_path / 'ports.toml'}"), encoding="utf-8")
    with pytest.raises(FablineError, match="outside the job's output folder"):
        load_job_file(job)
    job.write_text(JOB.format(port=f"{scheme}={tmp_path / 'out' / 'trace.log'}"), encoding="utf-8")
    assert load_job_file(job).machine["ports"] == [f"{scheme}={tmp_path / 'out' / 'trace.log'}"]


def test_the_runner_refuses_a_job_whose_port_writes_a_file(tmp_path):
    trace = tmp_path / "out" / "trace.log"
    job = tmp_path / "ports.toml"
    job.write_text(JOB.format(port=f"spy:///dev/null?file={trace}"), encoding="utf-8")
    db = tmp_path / "runner.sqlite"
    runner = Runner(db, [MachineConfig("m1", "sim://runner-ports?time_scale=1000")], poll=0.05)
    queue = JobQueue(db)
    job_id = queue.submit("ports", str(job))
    runner.start()
    try:
        deadline = time.monotonic() + 60
        while queue.job(job_id).state in ("queued", "preparing"):
            assert time.monotonic() < deadline
            time.sleep(0.05)
        row = queue.job(job_id)
        assert row.state == "failed" and row.error.startswith("ports.toml: machine.ports: port spy:") and \
            "no port may write a file here" in row.error, row.error
        assert not trace.exists() and not (tmp_path / "runs" / f"job-{job_id}").exists()
    finally:
        runner.stop()
        queue.close()
    with pytest.raises(FablineError, match="runner: machine m2: port sim://m2"):
        Runner(db, [MachineConfig("m2", "sim://m2?colour=red")])


def test_resume_and_restart_together_are_refused(cli, program):
    code, _, err = cli("stream", "a.gcode", "--port", "sim://both", "--resume", "--restart")
    assert code == 2 and err.count("\n") == 1 and "--resume and --restart" in err, err


def test_the_port_lock_is_the_endpoints_whatever_names_it(program, tmp_path):
    """localhost and 127.0.0.1 are one TCP port: a stream to one is refused while the other's lock is held."""
    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    port = listener.getsockname()[1]
    listener.close()
    held = port_endpoints(f"socket://127.0.0.1:{port}")
    assert held == [f"tcp://[127.0.0.1]:{port}"]
    assert set(held) <= set(port_endpoints(f"socket://localhost:{port}"))
    assert port_endpoints(f"rfc2217://127.0.0.1:{port}?timeout=1") == held
    with exclusive_lock(lock_path(held[0]), "test"):
        with pytest.raises(FablineError, match=f"port socket://localhost:{port} is in use by process"):
            Streamer(f"socket://localhost:{port}").run(program)
    device = tmp_path / "ttyFAKE"
    device.write_text("")
    (tmp_path / "by-id").symlink_to(device)
    assert port_endpoints(str(tmp_path / "by-id")) == port_endpoints(f"spy://{device}?color") == [str(device)]
