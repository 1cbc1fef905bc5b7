"""The `fabline` command line: a thin layer that parses arguments and calls the stage packages.

Each module listed in STAGE_COMMANDS defines `register(subparsers)`, which adds its subcommands
and sets `func` on each parser; `func(args)` returns the exit code (0 on success). `main` imports only
the module of the command it runs, and no module here imports a stage until its command runs (the stages'
libraries take seconds to import): `fabline --help` and every command's `--help` need none.
"""

from __future__ import annotations

import argparse
import difflib
import importlib
import math
import os
import re
import signal
import sys
import warnings
from contextlib import nullcontext
from typing import Callable

from fabline import __version__
from fabline.cli.stops import StopSignals, forget_unhandled_interrupt
from fabline.errors import FablineError, Terminated
from fabline.fileio import OutputSet

STAGE_COMMANDS = {"model": ("design", "inspect"), "importing": ("import",), "unroll": ("unroll", "limits"),
                  "nest": ("nest",), "export": ("export", "gcode-check"), "link": ("stream", "grbl-sim"),
                  "survey": ("survey",), "assembly": ("assembly",), "analysis": ("analyse",),
                  "jobs": ("run", "runner")}
"""CLI module -> the commands it registers (a test checks this against the modules)."""
KEEPS_PARTIAL_OUTPUTS = ("run", "runner", "stream", "grbl-sim")
"""Commands whose files must outlive a failure (journals, logs, the programs an interrupted run resumes): their
stages keep their own output sets. Every other command is one `OutputSet`: it fails or is interrupted whole."""
CLOSED_PIPE = 141
"""Exit code when the reader of the output went away (`fabline runner status | head -1`): 128 + SIGPIPE, as a
shell reports a command that a closed pipe stopped."""
NEGATIVE_NUMBER = re.compile(r"^-\.?\d")
"""An argument that is a value, not an option: a negative number, point or length (`-0.22,0.04,0.006`, `-1e-3`,
`-25mm`); argparse's own pattern takes only plain numbers (no option of fabline's starts with a digit)."""


def positive(kind: type, most: float = math.inf) -> Callable[[str], int | float]:
    """An argparse type shared by the stages' commands: a finite number of `kind` (int or float) above 0 and at
    most `most`."""

    def parse(text: str) -> int | float:
        try:
            value = kind(text)
        except ValueError:
            value = math.nan
        if not (0 < value <= min(most, MAX_OPTION_NUMBER)):  # NaN fails too
            bound = f", at most {most:g}" if most < math.inf else ""
            raise argparse.ArgumentTypeError(
                f"must be a positive {'whole number' if kind is int else 'number'}{bound}, got {text!r}")
        return value

    parse.__name__ = kind.__name__  # argparse names the type in its messages; the campaign test finds number options
    return parse


MAX_OPTION_NUMBER = 1e9
"""The largest size of any number option (a plain int or float option; many have tighter limits of their own):
beyond it a value is a mistake, and products of such values overflow."""


def bounded(kind: type) -> Callable[[str], int | float]:
    """An argparse type for a plain int or float option: a finite number of at most MAX_OPTION_NUMBER in size."""

    def parse(text: str) -> int | float:
        try:
            value = kind(text)
        except ValueError:
            value = math.nan
        if not (math.isfinite(value) if isinstance(value, float) else True) or abs(value) > MAX_OPTION_NUMBER:
            raise argparse.ArgumentTypeError(f"must be a finite {'whole number' if kind is int else 'number'} of at "
                                             f"most {MAX_OPTION_NUMBER:g} in size, got {text!r}")
        return value

    parse.__name__ = kind.__name__  # argparse names the type in "invalid int value" messages
    return parse


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """`--help` of every command: descriptions keep their line breaks, and every option with a default shows it,
    with the unit of a length option (`(default: 0.2 mm)`)."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text, default = action.help or "", action.default
        if ("%(default)" in text or default is None or default is False or default is argparse.SUPPRESS
                or default == [] or not action.option_strings):
            return text
        unit = getattr(action.type, "unit", None)
        shown = "x".join(f"{v:g}" for v in default) if isinstance(default, tuple) else str(default)
        return text + f" (default: {shown}{f' {unit}' if unit else ''})".replace("%", "%%")  # help is %-formatted


class OneLineParser(argparse.ArgumentParser):
    """An argument parser whose mistakes are one line (`fabline CMD: error: ...`, exit 2), as the stages' are, followed
    by the command's usage; a misspelled option gets the nearest option's name."""

    def __init__(self, *args, formatter_class: type = HelpFormatter, **kwargs):
        super().__init__(*args, formatter_class=formatter_class, **kwargs)
        self._negative_number_matcher = NEGATIVE_NUMBER  # read by argparse's option parsing (3.10 to 3.13)

    def _print_message(self, message: str, file=None) -> None:
        """Help, usage and errors written as argparse writes them, but a closed pipe is not swallowed (newer
        argparse releases drop an OSError here, older ones raise it): `main` ends every closed pipe alike."""
        if message:
            (file or sys.stderr).write(message)

    def error(self, message: str):
        wrong = re.search(r"invalid choice: '([^']*)'", message)
        commands = [a for a in self._actions if isinstance(a, argparse._SubParsersAction)]
        if wrong and commands:
            nearest = difflib.get_close_matches(wrong[1], list(commands[0].choices), n=1, cutoff=0.6)
            message = message.split(" (choose from", 1)[0] + (f"; did you mean {nearest[0]}?" if nearest else
                                                             f" (see {self.prog} --help)")
        self.exit(2, f"{self.prog}: error: {message}\n{self.format_usage()}")

    def parse_args(self, args=None, namespace=None):
        namespace, extras = self.parse_known_args(args, namespace)
        if extras:
            parser = _chosen_command(self, namespace)
            unknown = next((a for a in extras if a.startswith("-") and not NEGATIVE_NUMBER.match(a)), None)
            if unknown is None:
                parser.error(f"unexpected argument(s): {' '.join(extras)}")
            name = unknown.split("=", 1)[0]
            known = [o for a in parser._actions if a.help != argparse.SUPPRESS for o in a.option_strings]
            nearest = difflib.get_close_matches(name, known, n=1, cutoff=0.6)
            parser.error(f"unknown option {name}" + (f"; did you mean {nearest[0]}?" if nearest else
                                                     f" (see {parser.prog} --help)"))
        return namespace


def _chosen_command(parser: argparse.ArgumentParser, namespace: argparse.Namespace) -> argparse.ArgumentParser:
    """The innermost sub-command parser `namespace` was parsed by (`fabline runner pause` -> its parser)."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction) and getattr(namespace, action.dest, None) in action.choices:
            return _chosen_command(action.choices[getattr(namespace, action.dest)], namespace)
    return parser


def hidden_alias(parser: argparse.ArgumentParser, canonical: argparse.Action, *names: str) -> None:
    """Old names of an option that still work (job files, scripts, the manual) but no longer show in `--help`."""
    parser.add_argument(*names, dest=canonical.dest, type=canonical.type, choices=canonical.choices,
                        metavar=canonical.metavar, default=argparse.SUPPRESS, help=argparse.SUPPRESS)


def build_parser(modules: tuple[str, ...] = tuple(STAGE_COMMANDS)) -> argparse.ArgumentParser:
    """The argument parser with the subcommands of the given CLI modules (default: all); every plain int or float
    option is `bounded`."""
    parser = OneLineParser(prog="fabline", description="Fabrication pipeline for elastic lamella gridshells.")
    parser.add_argument("--version", action="version", version=f"fabline {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in modules:
        importlib.import_module(f"fabline.cli.{name}").register(subparsers)
    _bound_numbers(parser)
    return parser


def _bound_numbers(parser: argparse.ArgumentParser) -> None:
    for action in parser._actions:
        if action.type in (int, float):
            action.type = bounded(action.type)
        for sub in (action.choices or {}).values() if isinstance(action, argparse._SubParsersAction) else ():
            _bound_numbers(sub)


def main(argv: list[str] | None = None) -> int:
    """Entry point: run one subcommand; a user's mistake becomes one line on stderr and exit code 2; output into a
    closed pipe ends quietly (CLOSED_PIPE), as Python's documentation on SIGPIPE advises."""
    try:
        try:
            return _main(argv)
        finally:
            sys.stdout.flush()  # here, not at exit, where a closed pipe would be a note on stderr
    except BrokenPipeError:
        quiet_stdout()
        return CLOSED_PIPE


def quiet_stdout() -> None:
    """Point standard output at the null device, after its reader went away: what is still buffered or printed
    later (a running job's lines, the flush at exit) goes nowhere instead of failing again."""
    try:
        descriptor = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):  # not a file (a test's buffer): nothing to point
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, descriptor)
    os.close(devnull)


def _main(argv: list[str] | None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    with StopSignals() as stops:
        return _run(argv, stops)


def _run(argv: list[str], stops: StopSignals) -> int:
    """Parse `argv` and run its command as one output set; a user's mistake or a stop becomes a message and a code."""
    command = argv[0] if argv else None
    module = next((name for name, commands in STAGE_COMMANDS.items() if command in commands), None)
    outputs = OutputSet()
    try:
        args = build_parser((module,) if module else tuple(STAGE_COMMANDS)).parse_args(argv)
        with nullcontext() if args.command in KEEPS_PARTIAL_OUTPUTS else outputs, warnings.catch_warnings():
            # numpy's overflow and invalid-value notes on a user's absurd numbers are not messages for the user:
            # the stages check their inputs and say what is wrong in one line
            warnings.filterwarnings("ignore", category=RuntimeWarning, module="numpy")
            code = int(args.func(args) or 0)
            stops.raise_pending()  # a stop swallowed where it landed: the command unwinds as if it had raised
        stops.raise_pending()  # swallowed as the outputs were committed: the command says it had finished
        return code
    except FablineError as exc:
        print(f"fabline {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # the output's reader went away: not a path of the user's (main ends quietly)
        raise
    except OSError as exc:  # a path the user named that cannot be read or written, found where no stage looked
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"fabline {args.command}: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as stop:  # Ctrl-C, or SIGTERM (Terminated), also while the command's modules load
        outputs.rollback()  # what the output set's own exit could not (the signal came as it began): put back
        forget_unhandled_interrupt()
        terminated = isinstance(stop, Terminated)
        if command in KEEPS_PARTIAL_OUTPUTS:
            outcome = ""
        elif outputs.committed:
            outcome = "; it had finished: its outputs are complete and kept"
        else:
            outcome = "; nothing was written"
        print(f"fabline {command}: " if command else "fabline: ", f"{'terminated' if terminated else 'interrupted'}"
              f"{outcome}", sep="", file=sys.stderr)
        return 128 + (stop.number if terminated else signal.SIGINT)


if __name__ == "__main__":
    sys.exit(main())
