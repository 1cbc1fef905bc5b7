"""A G-code program ready to stream: comments and whitespace stripped, each line tied to its file line.

Every line goes out as `N<file line><command>T<tag>`: the N word makes status reports (`Ln:`) and the
controller's executed-line log name the line of the file; the T word (tool number, which GRBL stores
and `$G` reports but never acts on) carries `line_tag(index)`, so after a lost connection `$G` tells
which line the controller parsed last. The program is checked before anything moves (ASCII only, no
real-time characters, no T words of its own, fits GRBL's 80-byte line buffer, accepted by the parser).
"""

from __future__ import annotations

import hashlib
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

from fabline.errors import FablineError
from fabline.fileio import read_bytes
from fabline.machine.build import STOCK_BUILD, BuildInfo
from fabline.machine.codes import explain_error, listing
from fabline.machine.gcode import Block, GcodeError, ModalState, Vector, execute, split_words

LINE_BUFFER_SIZE = 80
"""GRBL's line buffer: at most 79 characters after whitespace and comments are removed."""

_LEADING_N = re.compile(r"^N\d+(\.\d*)?")
_MACHINE_COMMENT = re.compile(r"^\s*[;(]\s*machine\s+([^\s()\[\]]+)")
"""The header line `fabline export` writes: `; machine grbl-laser (Grbl 1.1), mode laser, ...`."""


TAG_CYCLE = 255
"""Tags run 1..255 (GRBL's largest tool number); T0 means no program line was parsed since a reset."""




def line_tag(index: int) -> int:
    """The T value sent with the program line at 0-based `index`; `line_tag(-1)` is 0 (nothing parsed)."""
    return 0 if index < 0 else index % TAG_CYCLE + 1


@dataclass(frozen=True)
class ProgramLine:
    """One command line: its 0-based index among commands, 1-based line in the file, text there, compact command."""

    index: int
    file_line: int
    source: str
    command: str

    @property
    def wire(self) -> bytes:
        """The bytes sent to the controller, newline included."""
        return f"N{self.file_line}{self.command}T{line_tag(self.index)}\n".encode("ascii")


@dataclass(frozen=True)
class Program:
    """The command lines of one G-code file, in order, with the file's SHA-256 to tie a journal to it."""

    name: str
    lines: tuple[ProgramLine, ...]
    sha256: str
    machine: str | None = None
    """The machine profile named in the header comments before the first command (`; machine NAME (...)`)."""

    _plans: dict = field(default_factory=dict, compare=False, repr=False)
    """The last plan made (a program is checked, then streamed, from the same start): one parse, not two."""

    def plan(self, modal: ModalState, position: Vector, build: BuildInfo = STOCK_BUILD) -> list[Block]:
        """The block each line becomes when the program starts in `modal` state at work `position` on a controller
        of `build`; every line the firmware would refuse is listed (a refused line changes nothing, as in Grbl)."""
        key = (modal, tuple(position), build)
        if key in self._plans:
            return list(self._plans[key])
        blocks, refused = [], []
        for line in self.lines:
            try:
                block = execute(line.command, modal, position, build=build)
            except GcodeError as exc:
                refused.append(f"{self.name}:{line.file_line}: {explain_error(exc.code)}: {line.source.strip()}")
                continue
            blocks.append(block)
            modal, position = block.modal, block.position
        if refused:
            raise FablineError(listing(refused, f"{len(refused)} lines the controller would refuse"))
        self._plans.clear()
        self._plans[key] = tuple(blocks)
        return blocks


_PLAIN = re.compile(r"[^()?!~$;\x00-\x08\x0a-\x1f]*")
"""A line with no comment and nothing to refuse: stripped in one step, as the loop below would."""


def strip_line(text: str, where: str) -> str:
    """Remove comments `( )` and `;`, whitespace and `%` marks; uppercase; refuse what GRBL cannot take."""
    if _PLAIN.fullmatch(text):
        return _LEADING_N.sub("", "".join(text.split()).replace("%", "").upper())
    out, depth = [], 0
    for column, char in enumerate(text, 1):
        if depth:
            if char == ")":
                depth = 0
            continue
        if char == "(":
            depth = 1
        elif char == ";":
            break
        elif char in "?!~$":
            raise FablineError(f"{where}:{column}: {char!r} is a GRBL real-time or system command character; it cannot be streamed")
        elif ord(char) < 32 and char != "\t":
            raise FablineError(f"{where}:{column}: control character 0x{ord(char):02x} in G-code")
        elif not char.isspace() and char != "%":
            out.append(char.upper())
    if depth:
        raise FablineError(f"{where}: unclosed '(' comment")
    return _LEADING_N.sub("", "".join(out))


def parse_program(data: bytes, name: str, build: BuildInfo = STOCK_BUILD) -> Program:
    """Build a Program from a file's bytes, checked for a controller of `build`; `name` is used in error messages."""
    lines, machine = [], None
    for number, raw in enumerate(data.split(b"\n"), 1):
        where = f"{name}:{number}"
        try:
            text = raw.decode("ascii")
        except UnicodeDecodeError as exc:
            raise FablineError(f"{where}:{exc.start + 1}: non-ASCII byte 0x{raw[exc.start]:02x}; GRBL takes ASCII only") from None
        command = strip_line(text.rstrip("\r"), where)
        if not command:
            header = _MACHINE_COMMENT.match(text) if not lines and machine is None else None
            machine = header.group(1) if header else machine
            continue
        line = ProgramLine(len(lines), number, text.rstrip("\r"), command)
        if len(line.wire) - 1 >= LINE_BUFFER_SIZE:
            raise FablineError(f"{where}: line too long for the controller: {len(line.wire) - 1} characters as sent "
                               f"(with line number and tag), GRBL takes at most {LINE_BUFFER_SIZE - 1}")
        try:
            letters = {letter for letter, _ in split_words(command)}
        except GcodeError as exc:
            raise FablineError(f"{where}: {explain_error(exc.code)}: {line.source.strip()}") from None
        if "T" in letters:
            raise FablineError(f"{where}: T words are not supported (GRBL has no tool changer; "
                               "the streamer uses T to tag lines)")
        lines.append(line)
    if not lines:
        raise FablineError(f"{name}: no G-code commands in the file")
    program = Program(name, tuple(lines), hashlib.sha256(data).hexdigest(), machine)
    program.plan(ModalState(), (0.0, 0.0, 0.0), build)
    return program


def load_program(path: str | os.PathLike, build: BuildInfo = STOCK_BUILD) -> Program:
    """Read and check a G-code file (for a controller of `build`); any problem is a FablineError naming file,
    line and column."""
    return parse_program(read_bytes(path, "gcode"), str(Path(path)), build)
