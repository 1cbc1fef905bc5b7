"""Run a GRBL simulator in its own process, reachable over TCP on 127.0.0.1 or over a pseudo-terminal.

A controller must outlive the host that drives it: tests and the job runner kill the host (even with
SIGKILL) and start a new one, and the simulator's executed-line log must stay the truth. Use
`SimulatorServer` from Python, or `fabline grbl-sim` / `python -m fabline.link.server` from a shell;
the server prints the URL to connect to (`socket://127.0.0.1:PORT` or a `/dev/pts/N` path) on its
first line. With `baud`, bytes travel no faster than a serial line at that rate (10 bits per byte);
with `adapter_latency`, the controller's answers reach the host like through a USB-serial bridge, in
packets sent when 64 bytes are buffered or the oldest byte has waited that long (the Arduino Uno's
16U2 bridge flushes about every 4 ms; an FTDI chip's latency timer defaults to 16 ms).
"""

from __future__ import annotations

import argparse
import fcntl
import os
import pty
import select
import signal
import socket
import struct
import subprocess
import sys
import termios
import threading
import time
import tty
import urllib.parse
from pathlib import Path

from fabline.errors import FablineError
from fabline.link.protocol_sim import simulator_from_options
from fabline.link.simulator import ConnectionDropped, GrblSimulator


class _Wire:
    """One direction of a serial line at baud/10 bytes per second.

    Time on the wire is credit: it accrues only while bytes are waiting to cross (an idle line earns
    nothing), so over any stretch no more bytes arrive than the line could carry; a receiver that was
    descheduled for a moment catches up like a UART's hardware buffer would, up to `BURST` bytes.
    """

    BURST = 128

    def __init__(self, baud: int | None):
        self.rate = baud / 10.0 if baud else None
        self.credit = 0.0
        self.since = time.monotonic()

    def idle(self) -> None:
        """Nothing is waiting: the line earns no credit until bytes appear."""
        self.credit, self.since = 0.0, time.monotonic()

    def take(self, waiting: int) -> int:
        """Sleep until some of `waiting` bytes have crossed; return how many (all at once without a rate)."""
        if self.rate is None:
            return waiting
        wanted = min(waiting, 16)
        while True:
            now = time.monotonic()
            self.credit = min(self.credit + (now - self.since) * self.rate, self.BURST)
            self.since = now
            if self.credit >= wanted:
                count = min(waiting, int(self.credit))
                self.credit -= count
                return count
            time.sleep((wanted - self.credit) / self.rate)


USB_PACKET = 64
"""Bytes per full-speed USB bulk packet: a bridge sends at once when this many are buffered."""


def _pump_out(simulator: GrblSimulator, write, stop: threading.Event, wire: _Wire, adapter_latency: float) -> None:
    """Copy the controller's output to the host at line speed, then through a USB bridge if one is modelled."""
    bridge, oldest = bytearray(), 0.0
    try:
        while not stop.is_set():
            data = simulator.read(4096, 0.0005 if bridge else 0.02)
            if not data:
                wire.idle()
            while data:
                count = wire.take(len(data))
                if not bridge:
                    oldest = time.monotonic()
                bridge += data[:count]
                data = data[count:]
                if adapter_latency <= 0 or len(bridge) >= USB_PACKET:
                    write(bytes(bridge))
                    bridge.clear()
            if bridge and time.monotonic() - oldest >= adapter_latency:
                write(bytes(bridge))
                bridge.clear()
    except OSError:
        return


def _pump_in(fileno: int, read, simulator: GrblSimulator, wire: _Wire) -> None:
    """Deliver the host's bytes to the controller at line speed until the host closes its end."""
    while True:
        ready, _, _ = select.select([fileno], [], [], 0.05)
        if not ready:
            continue
        waiting = struct.unpack("i", fcntl.ioctl(fileno, termios.FIONREAD, b"\0\0\0\0"))[0]
        data = read(wire.take(max(waiting, 1)))
        if not data:
            return
        simulator.receive(data)
        if len(data) >= waiting:
            wire.idle()  # drained: the line earns nothing until the host sends again


def _serve_socket(simulator: GrblSimulator, baud: int | None, port: int, adapter_latency: float) -> None:
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
        writer = threading.Thread(target=_pump_out, args=(simulator, connection.sendall, stop, _Wire(baud),
                                                          adapter_latency), daemon=True)
        writer.start()
        try:
            _pump_in(connection.fileno(), connection.recv, simulator, _Wire(baud))
        except (ConnectionDropped, OSError):
            pass
        finally:
            stop.set()
            writer.join()
            simulator.detach(number)
            connection.close()


def _serve_pty(simulator: GrblSimulator, baud: int | None, adapter_latency: float) -> None:
    master, slave = pty.openpty()
    tty.setraw(slave)
    print(os.ttyname(slave), flush=True)
    simulator.attach()
    threading.Thread(target=_pump_out, args=(simulator, lambda data: os.write(master, data), threading.Event(),
                                             _Wire(baud), adapter_latency), daemon=True).start()
    wire = _Wire(baud)
    while True:
        try:
            _pump_in(master, lambda size: os.read(master, size), simulator, wire)
        except ConnectionDropped:
            continue


def serve(transport: str, options: str, baud: int | None, port: int = 0, adapter_latency: float = 0.0) -> None:
    """Run a simulator until killed; `options` as in a sim:// URL (time_scale, log, fault injection)."""
    simulator = simulator_from_options(options)
    if transport == "tcp":
        _serve_socket(simulator, baud, port, adapter_latency)
    elif transport == "pty":
        _serve_pty(simulator, baud, adapter_latency)
    else:
        raise ValueError(f"unknown transport {transport!r}")


class SimulatorServer:
    """A simulator process; `url` is what a Streamer (or `fabline stream --port`) connects to.

    `log` receives every executed line in order (see `executed_file_lines`); `time_scale` > 1 runs
    motion faster; `line_time` (s) is the firmware's time to parse and plan a line; `baud` paces bytes
    like a serial line; `adapter_latency` (s) batches answers like a USB-serial bridge; `faults` are
    sim:// fault options; `machine` (a profile's name or file) sets the controller up as that machine.
    """

    def __init__(self, *, log: str | os.PathLike | None = None, time_scale: float = 1.0, transport: str = "tcp",
                 baud: int | None = None, adapter_latency: float = 0.0, faults: dict | None = None,
                 line_time: float = 0.0, machine: str | None = None):
        options = {"time_scale": time_scale, **(faults or {}), **({"machine": machine} if machine else {})}
        if line_time:
            options["line_time"] = line_time
        if log is not None:
            options["log"] = str(Path(log).resolve())  # the process runs in the package root, not here
        self.command = [sys.executable, "-m", "fabline.link.server", "--transport", transport,
                        "--options", urllib.parse.urlencode(options)]
        if baud:
            self.command += ["--baud", str(baud)]
        if adapter_latency:
            self.command += ["--adapter-latency", str(adapter_latency)]
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
    parser.add_argument("--adapter-latency", type=float, default=0.0, help="USB-serial bridge flush interval, s")
    args = parser.parse_args(argv)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
    try:
        serve(args.transport, args.options, args.baud, args.listen_port, args.adapter_latency)
    except ValueError as exc:
        print(f"fabline.link.server: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
