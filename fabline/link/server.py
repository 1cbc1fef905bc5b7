"""Run a GRBL simulator in its own process, reachable over TCP on 127.0.0.1 or over a pseudo-terminal.

A controller must outlive the host that drives it: tests and the job runner kill the host (even with
SIGKILL) and start a new one, and the simulator's executed-line log must stay the truth. Use
`SimulatorServer` from Python, or `fabline grbl-sim` / `python -m fabline.link.server` from a shell;
the server prints the URL to connect to (`socket://127.0.0.1:PORT` or a `/dev/pts/N` path) on its
first line. With `baud`, bytes travel no faster than a serial line at that rate (10 bits per byte).
"""

from __future__ import annotations

import argparse
import os
import pty
import signal
import socket
import subprocess
import sys
import threading
import time
import tty
import urllib.parse
from pathlib import Path

from fabline.errors import FablineError
from fabline.link.protocol_sim import simulator_from_options
from fabline.link.simulator import ConnectionDropped, GrblSimulator


class _Pacer:
    """Token bucket for one direction of a serial line: at most baud/10 bytes per second."""

    def __init__(self, baud: int | None):
        self.rate = baud / 10.0 if baud else None
        self.allowance = 0.0
        self.last = time.monotonic()

    def budget(self, wanted: int) -> int:
        """How many of `wanted` bytes may go now (waiting a little if none may)."""
        if self.rate is None:
            return wanted
        while True:
            now = time.monotonic()
            self.allowance = min(self.allowance + (now - self.last) * self.rate, 64.0)
            self.last = now
            if self.allowance >= 1:
                allowed = min(wanted, int(self.allowance))
                self.allowance -= allowed
                return allowed
            time.sleep((1 - self.allowance) / self.rate)


def _pump_out(simulator: GrblSimulator, write, stop: threading.Event, pacer: _Pacer) -> None:
    """Copy the controller's output to the host, paced like the serial line."""
    while not stop.is_set():
        data = simulator.read(pacer.budget(4096) if pacer.rate else 4096, 0.05)
        if data:
            try:
                write(data)
            except OSError:
                return


def _serve_socket(simulator: GrblSimulator, baud: int | None, port: int) -> None:
    listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    listener.bind(("127.0.0.1", port))
    listener.listen(1)
    print(f"socket://127.0.0.1:{listener.getsockname()[1]}", flush=True)
    while True:
        connection, _ = listener.accept()
        connection.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        number = simulator.attach()
        stop = threading.Event()
        writer = threading.Thread(target=_pump_out, args=(simulator, connection.sendall, stop, _Pacer(baud)), daemon=True)
        writer.start()
        pacer = _Pacer(baud)
        try:
            while True:
                data = connection.recv(pacer.budget(4096))
                if not data:
                    break
                simulator.receive(data)
        except (ConnectionDropped, OSError):
            pass
        finally:
            stop.set()
            writer.join()
            simulator.detach(number)
            connection.close()


def _serve_pty(simulator: GrblSimulator, baud: int | None) -> None:
    master, slave = pty.openpty()
    tty.setraw(slave)
    print(os.ttyname(slave), flush=True)
    simulator.attach()
    stop = threading.Event()
    threading.Thread(target=_pump_out, args=(simulator, lambda data: os.write(master, data), stop, _Pacer(baud)),
                     daemon=True).start()
    pacer = _Pacer(baud)
    while True:
        data = os.read(master, pacer.budget(4096))
        try:
            simulator.receive(data)
        except ConnectionDropped:
            continue


def serve(transport: str, options: str, baud: int | None, port: int = 0) -> None:
    """Run a simulator until killed; `options` as in a sim:// URL (time_scale, log, fault injection)."""
    simulator = simulator_from_options(options)
    if transport == "tcp":
        _serve_socket(simulator, baud, port)
    elif transport == "pty":
        _serve_pty(simulator, baud)
    else:
        raise ValueError(f"unknown transport {transport!r}")


class SimulatorServer:
    """A simulator process; `url` is what a Streamer (or `fabline stream --port`) connects to.

    `log` receives every executed line in order (see `executed_file_lines`); `time_scale` > 1 runs
    motion faster; `baud` paces bytes like a serial line; `faults` are sim:// fault options.
    """

    def __init__(self, *, log: str | os.PathLike | None = None, time_scale: float = 1.0, transport: str = "tcp",
                 baud: int | None = None, faults: dict | None = None):
        options = {"time_scale": time_scale, **(faults or {})}
        if log is not None:
            options["log"] = str(log)
        self.command = [sys.executable, "-m", "fabline.link.server", "--transport", transport,
                        "--options", urllib.parse.urlencode(options)]
        if baud:
            self.command += ["--baud", str(baud)]
        self.process: subprocess.Popen | None = None
        self.url: str | None = None

    def start(self) -> str:
        """Start the process and return the URL it listens on."""
        self.process = subprocess.Popen(self.command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                        cwd=Path(__file__).resolve().parents[2], start_new_session=True)
        self.url = self.process.stdout.readline().strip()
        if not self.url:
            error = self.process.stderr.read().strip().splitlines()
            raise FablineError(f"the GRBL simulator did not start: {error[-1] if error else 'no output'}")
        return self.url

    def stop(self) -> None:
        """Stop the process (the executed-line log is flushed line by line, so it is complete)."""
        if self.process is not None and self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        if self.process is not None:
            self.process.stdout.close()
            self.process.stderr.close()

    def __enter__(self) -> "SimulatorServer":
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()


def executed_file_lines(log: str | os.PathLike) -> list[int]:
    """The file line numbers (N words) of the program lines a simulator executed, in order.

    Lines without an N word (a resume's modal preamble) are left out, so for a complete job the
    result equals the file lines of the program's commands exactly once each, in order.
    """
    numbers = []
    for text in Path(log).read_text(encoding="ascii").splitlines():
        if text.startswith("N"):
            digits = ""
            for char in text[1:]:
                if not char.isdigit():
                    break
                digits += char
            numbers.append(int(digits))
    return numbers


def main(argv: list[str] | None = None) -> int:
    """`python -m fabline.link.server --transport tcp|pty --options 'time_scale=100&log=x.log' [--baud 115200]`."""
    parser = argparse.ArgumentParser(prog="fabline.link.server", description=__doc__.splitlines()[0])
    parser.add_argument("--transport", choices=("tcp", "pty"), default="tcp")
    parser.add_argument("--options", default="", help="sim:// options, e.g. 'time_scale=100&log=run.log'")
    parser.add_argument("--baud", type=int, default=None, help="pace bytes like a serial line at this rate")
    parser.add_argument("--listen-port", type=int, default=0, help="TCP port on 127.0.0.1 (0: any free port)")
    args = parser.parse_args(argv)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
    try:
        serve(args.transport, args.options, args.baud, args.listen_port)
    except ValueError as exc:
        print(f"fabline.link.server: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
