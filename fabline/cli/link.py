"""CLI for the hardware link: `fabline stream` (G-code to a GRBL controller) and `fabline grbl-sim` (a simulator)."""

from __future__ import annotations

import argparse
import contextlib
import os
import select
import shlex
import signal
import sys
import termios
import threading
import tty
import urllib.parse
from typing import TYPE_CHECKING

from fabline.cli import positive
from fabline.cli.choices import STREAM_MODES
from fabline.errors import FablineError
from fabline.fileio import check_outputs

if TYPE_CHECKING:
    from fabline.link import Progress, Streamer

KEYS_HELP = "keys: p = pause/resume (feed hold), q = abort safely"
STOPPED = 1
"""Exit code of a run stopped by the operator or a signal: the journal allows --resume. Errors and refusals exit 2."""


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add `stream` and `grbl-sim`."""
    stream = subparsers.add_parser("stream", help="stream a G-code file to a GRBL 1.1 controller (journaled, resumable)")
    stream.add_argument("gcode", help="G-code file")
    stream.add_argument("--port", required=True,
                        help="serial device or pyserial URL: /dev/ttyUSB0, socket://HOST:PORT, rfc2217://..., sim://grbl")
    stream.add_argument("--baud", type=positive(int), default=115200, help="baud rate, bits per second")
    stream.add_argument("--check", action="store_true", help="run the program through GRBL check mode ($C) first")
    stream.add_argument("--resume", action="store_true", help="continue an interrupted job from its journal")
    stream.add_argument("--restart", action="store_true",
                        help="start over from the first line although an earlier run of this program was interrupted")
    stream.add_argument("--unlock", action="store_true", help="clear an alarm ($X) left by an interrupted job")
    stream.add_argument("--from-line", type=int, metavar="N",
                        help="with --resume: restart at file line N (the operator's choice, used whatever the journal says)")
    stream.add_argument("--machine", metavar="NAME",
                        help="machine profile (name or .toml) to check the controller against, instead of the one the "
                             "program's header names")
    stream.add_argument("--force", action="store_true",
                        help="stream although the controller's settings conflict with the program (logged)")
    stream.add_argument("--journal", help="journal file (default: <gcode>.journal)")
    stream.add_argument("--log", help="exchange log (default: <gcode>.link.log)")
    stream.add_argument("--mode", choices=STREAM_MODES, default="counting",
                        help="character counting or simple send-response")
    stream.add_argument("--status-rate", type=float, default=5.0, help="status reports per second (Hz)")
    stream.add_argument("--connect-timeout", type=positive(float), default=5.0, help="seconds to wait for GRBL")
    stream.add_argument("--reconnect-timeout", type=float, default=30.0,
                        help="seconds to wait for a dropped port to come back (0 = stop at once)")
    stream.set_defaults(func=_stream)

    sim = subparsers.add_parser("grbl-sim", help="run a Grbl 1.1h (or grblHAL, FluidNC) simulator on 127.0.0.1 TCP or a pseudo-terminal")
    sim.add_argument("--transport", choices=("tcp", "pty"), default="tcp", help="TCP socket or pseudo-terminal")
    sim.add_argument("--listen-port", type=int, default=0, help="TCP port on 127.0.0.1 (0: any free port)")
    sim.add_argument("--log", help="executed-line log (append-only)")
    sim.add_argument("--time-scale", type=float, default=1.0, help="run motion this many times faster (a factor)")
    sim.add_argument("--line-time", type=float, default=0.0,
                     help="seconds the firmware spends parsing and planning each line (0: instant)")
    sim.add_argument("--baud", type=int, help="pace bytes like a serial line at this rate, bits per second")
    sim.add_argument("--adapter-latency", type=float, default=0.0,
                     help="batch answers like a USB-serial bridge flushing every this many seconds (Uno: 0.004)")
    sim.add_argument("--firmware", choices=("grbl", "grblhal", "fluidnc"), default="grbl",
                     help="answer as a stock build of this firmware: Grbl 1.1h (the default), grblHAL or FluidNC")
    sim.add_argument("--build-options",
                     help="the build's $I option letters (default the firmware's stock build: V for Grbl; VN adds "
                     "Ln: line numbers)")
    sim.add_argument("--planner-blocks", type=positive(int),
                     help="planner size in blocks (default the firmware's stock build: 15 for Grbl)")
    sim.add_argument("--rx-buffer", type=positive(int),
                     help="serial receive buffer, bytes (default the firmware's stock build: 128 for Grbl)")
    sim.add_argument("--machine", metavar="NAME",
                     help="set the controller up as this machine profile (name or .toml): its $N settings, e.g. "
                     "grbl-laser for the example job's programs (laser mode $32=1, 4100 x 2100 mm travel)")
    sim.add_argument("--setting", action="append", default=[], metavar="N=VALUE",
                     help="a Grbl $N setting other than its default, e.g. --setting 32=1 for laser mode")
    sim.add_argument("--fault", action="append", default=[], metavar="KEY=VALUE",
                     help="inject a fault: drop_at=BYTES, corrupt_at=BYTES, error_line=N, alarm_line=N, stall_at=BYTES ...")
    sim.set_defaults(func=_grbl_sim)


def _stream(args: argparse.Namespace) -> int:
    from fabline.link import Streamer, default_journal_path
    from fabline.progress import StreamBar

    if args.status_rate <= 0:
        raise FablineError(f"--status-rate must be positive, got {args.status_rate}")
    streamer = Streamer(args.port, baud=args.baud, mode=args.mode, status_interval=1.0 / args.status_rate,
                        connect_timeout=args.connect_timeout, reconnect_timeout=args.reconnect_timeout,
                        exchange_log=args.log or f"{args.gcode}.link.log")
    journal = args.journal or default_journal_path(args.gcode)
    check_outputs(files=(args.log or f"{args.gcode}.link.log", journal), inputs=(args.gcode,))
    interactive = sys.stdin.isatty() and sys.stderr.isatty()
    bar = StreamBar()
    if interactive:
        print(KEYS_HELP, file=sys.stderr)

    shown = [None]

    def show(progress: Progress) -> None:
        if progress.message != shown[0]:
            shown[0] = progress.message
            if progress.message:
                how = "press p" if interactive else f"send SIGUSR1 to process {os.getpid()}"
                bar.write(f"{args.gcode}: {progress.message} ({how})")
        position = ",".join(f"{v:.2f}" for v in progress.position) if progress.position else "?"
        state = "Paused" if streamer.paused and progress.state != "Hold" else progress.state
        bar.show(progress.acked, progress.total, progress.eta, f"{state} @ {position} line {progress.file_line or '-'}")

    with _keyboard(streamer, interactive), _abort_on_interrupt(streamer):
        try:
            result = streamer.run(args.gcode, on_progress=show, journal=journal, resume=args.resume, check=args.check,
                                  unlock=args.unlock, start_line=args.from_line, restart=args.restart,
                                  machine=args.machine, force=args.force)
        finally:
            bar.close()
    if not result.completed:
        print(f"stopped ({result.reason}) with {result.executed} of {result.total} lines executed; "
              f"continue with: {shlex.join(['fabline', 'stream', args.gcode, '--port', args.port, '--resume'])}",
              file=sys.stderr)
        return STOPPED
    rate = result.total / result.elapsed if result.elapsed > 0 else float("inf")
    print(f"{args.gcode}: {result.total} lines streamed to {args.port} in {result.elapsed:.1f} s ({rate:.0f} lines/s)")
    return 0


@contextlib.contextmanager
def _keyboard(streamer: Streamer, interactive: bool):
    """On a terminal, read single keys in a thread: p toggles pause, q aborts. Does nothing otherwise."""
    if not interactive:
        yield
        return
    descriptor = sys.stdin.fileno()
    saved = termios.tcgetattr(descriptor)
    stop = threading.Event()

    def listen() -> None:
        while not stop.is_set():
            ready, _, _ = select.select([descriptor], [], [], 0.1)
            if not ready:
                continue
            key = os.read(descriptor, 1).decode("ascii", errors="ignore").lower()
            if key in ("p", " "):
                streamer.resume() if streamer.paused else streamer.pause()
            elif key in ("q", "a"):
                streamer.abort()

    tty.setcbreak(descriptor)
    thread = threading.Thread(target=listen, daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join()
        termios.tcsetattr(descriptor, termios.TCSADRAIN, saved)


@contextlib.contextmanager
def _abort_on_interrupt(streamer: Streamer):
    """Ctrl-C, SIGTERM and SIGHUP stop the machine safely (feed hold, reset, "stopped" in the journal) instead of
    abandoning it mid-move; SIGUSR1 is cycle start after a program pause (M0) when no keyboard is attached."""
    from fabline.link import STOP_SIGNALS

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {number: signal.signal(number, lambda *_: streamer.abort()) for number in STOP_SIGNALS}
    previous[signal.SIGUSR1] = signal.signal(signal.SIGUSR1, lambda *_: streamer.resume())
    try:
        yield
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)


def _grbl_sim(args: argparse.Namespace) -> int:
    from fabline.link.server import serve

    options = {"time_scale": args.time_scale, "line_time": args.line_time, "firmware": args.firmware}
    for key in ("build_options", "planner_blocks", "rx_buffer"):
        if getattr(args, key) is not None:
            options[key] = getattr(args, key)
    if args.machine:
        options["machine"] = args.machine
    if args.setting:
        options["settings"] = ",".join(setting.replace("=", ":", 1) for setting in args.setting)
    if args.log:
        options["log"] = args.log
    for fault in args.fault:
        key, equals, value = fault.partition("=")
        if not equals:
            raise FablineError(f"--fault {fault!r}: expected KEY=VALUE")
        options[key] = value
    try:
        serve(args.transport, urllib.parse.urlencode(options), args.baud, args.listen_port, args.adapter_latency)
    except ValueError as exc:
        raise FablineError(str(exc)) from None
    except OSError as exc:
        raise FablineError(f"grbl-sim: cannot listen: {exc.strerror}") from None
    return 0
