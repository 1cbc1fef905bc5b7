"""GRBL 1.1 protocol logic without a port: classify controller lines, parse status reports, count characters.

Everything here is pure: the streamer feeds it bytes it read and asks it what to send, so the
protocol is tested without any serial device.
"""

from __future__ import annotations

import re
from collections import deque
from dataclasses import dataclass, field

RX_BUFFER_SIZE = 128
"""Bytes of the controller's serial receive buffer (`[OPT:...,128]`): the character-counting window."""

STATUS_QUERY = b"?"
FEED_HOLD = b"!"
CYCLE_START = b"~"
SOFT_RESET = b"\x18"
JOG_CANCEL = b"\x85"
OVERRIDES: dict[str, bytes] = {
    "feed 100%": b"\x90", "feed +10%": b"\x91", "feed -10%": b"\x92", "feed +1%": b"\x93", "feed -1%": b"\x94",
    "rapid 100%": b"\x95", "rapid 50%": b"\x96", "rapid 25%": b"\x97",
    "power 100%": b"\x99", "power +10%": b"\x9a", "power -10%": b"\x9b", "power +1%": b"\x9c", "power -1%": b"\x9d",
}
"""Grbl 1.1's real-time override commands (one byte each, acted on at once, even mid-program): feed rate, rapid
rate, and spindle speed, which is the laser's power in laser mode."""

_BANNER = re.compile(r"^(?:Grbl|GrblHAL) (\S+) \[.*'\$' (?:or '\$HELP' )?for help\]$")
"""Grbl's, grblHAL's and FluidNC's banners (fabline.link.dialects tells them apart)."""


@dataclass(frozen=True)
class Response:
    """One line from the controller, classified.

    kind is one of: ok, error, alarm, status, banner, message, feedback, setting, other.
    `code` holds N of error:N / ALARM:N, `text` the payload (message text, version, raw line).
    """

    kind: str
    text: str
    code: int | None = None
    status: "StatusReport | None" = None


@dataclass(frozen=True)
class StatusReport:
    """A parsed `<...>` status report; fields the report did not carry are None."""

    state: str
    substate: int | None = None
    mpos: tuple[float, ...] | None = None
    wpos: tuple[float, ...] | None = None
    wco: tuple[float, ...] | None = None
    planner_free: int | None = None
    rx_free: int | None = None
    line_number: int | None = None
    feed: float | None = None
    speed: float | None = None
    overrides: tuple[int, int, int] | None = None
    pins: str | None = None
    accessories: str | None = None

    def work_position(self, wco: tuple[float, ...] | None) -> tuple[float, ...] | None:
        """Work position: WPos if reported, else MPos minus the last known work coordinate offset."""
        if self.wpos is not None:
            return self.wpos
        if self.mpos is None:
            return None
        offset = self.wco or wco or (0.0,) * len(self.mpos)
        return tuple(m - o for m, o in zip(self.mpos, offset))

    def machine_position(self, wco: tuple[float, ...] | None) -> tuple[float, ...] | None:
        """Machine position: MPos if reported, else WPos plus the last known work coordinate offset."""
        if self.mpos is not None:
            return self.mpos
        if self.wpos is None:
            return None
        offset = self.wco or wco or (0.0,) * len(self.wpos)
        return tuple(w + o for w, o in zip(self.wpos, offset))


def _floats(text: str) -> tuple[float, ...]:
    return tuple(float(part) for part in text.split(","))


def parse_status(text: str) -> StatusReport:
    """Parse a status report such as `<Run|MPos:4.864,4.864,0.000|Bf:14,128|FS:707,118|Ov:100,100,100|A:C>`."""
    if not (text.startswith("<") and text.endswith(">")):
        raise ValueError(f"not a status report: {text!r}")
    state_field, *fields = text[1:-1].split("|")
    state, _, sub = state_field.partition(":")
    values: dict = {"state": state, "substate": int(sub) if sub else None}
    for item in fields:
        name, _, value = item.partition(":")
        if name == "MPos":
            values["mpos"] = _floats(value)
        elif name == "WPos":
            values["wpos"] = _floats(value)
        elif name == "WCO":
            values["wco"] = _floats(value)
        elif name == "Bf":
            planner, rx = value.split(",")
            values["planner_free"], values["rx_free"] = int(planner), int(rx)
        elif name == "Ln":
            values["line_number"] = int(value)
        elif name == "FS":  # grblHAL adds the spindle's measured rpm as a third value
            feed, speed, *_ = value.split(",")
            values["feed"], values["speed"] = float(feed), float(speed)
        elif name == "F":
            values["feed"] = float(value)
        elif name == "Ov":
            values["overrides"] = tuple(int(v) for v in value.split(","))
        elif name == "Pn":
            values["pins"] = value
        elif name == "A":
            values["accessories"] = value
    return StatusReport(**values)


def classify(line: str) -> Response:
    """Classify one line (line ending removed) the controller sent."""
    if line == "ok":
        return Response("ok", line)
    if line.startswith("error:"):
        return Response("error", line, code=_int_or_none(line[6:]))
    if line.startswith("ALARM:"):
        return Response("alarm", line, code=_int_or_none(line[6:]))
    if line.startswith("<") and line.endswith(">"):
        try:
            return Response("status", line, status=parse_status(line))
        except (ValueError, TypeError):
            return Response("other", line)
    banner = _BANNER.match(line)
    if banner:
        return Response("banner", line)
    if line.startswith("[MSG:") and line.endswith("]"):
        return Response("message", line[5:-1])
    if line.startswith("[") and line.endswith("]"):
        return Response("feedback", line[1:-1])
    if line.startswith("$") and "=" in line:
        return Response("setting", line)
    return Response("other", line)


def _int_or_none(text: str) -> int | None:
    try:
        return int(text)
    except ValueError:
        return None


class LineSplitter:
    """Reassemble controller lines from arbitrary byte chunks (GRBL ends lines with CR LF)."""

    def __init__(self) -> None:
        self._pending = bytearray()

    def feed(self, data: bytes) -> list[str]:
        """Add bytes; return the complete lines they finished, decoded, ends stripped, blanks dropped."""
        self._pending += data
        lines = []
        while True:
            end = self._pending.find(b"\n")
            if end < 0:
                break
            raw = bytes(self._pending[:end]).rstrip(b"\r ").lstrip(b"\r")  # indents kept: FluidNC's $CD is YAML
            del self._pending[: end + 1]
            if raw:
                lines.append(raw.decode("ascii", errors="replace"))
        return lines

    def clear(self) -> None:
        """Forget a partial line (after a reconnect)."""
        self._pending.clear()


@dataclass
class CharacterCounter:
    """The host's model of the controller's receive buffer for character-counting streaming.

    Every line sent but not yet answered occupies its byte length; a new line may go only if it
    fits in the remaining space. With `window=1` line this becomes simple send-response.
    """

    capacity: int = RX_BUFFER_SIZE
    max_lines: int | None = None
    _in_flight: deque = field(default_factory=deque)
    _used: int = 0

    def fits(self, size: int) -> bool:
        """Whether a line of `size` bytes (newline included) may be sent now."""
        if self.max_lines is not None and len(self._in_flight) >= self.max_lines:
            return False
        return self._used + size <= self.capacity

    def sent(self, tag, size: int) -> None:
        """Record that a line (identified by `tag`) of `size` bytes went out."""
        self._in_flight.append((tag, size))
        self._used += size

    def answered(self):
        """Pop the oldest unanswered line's tag: GRBL answers strictly in order."""
        if not self._in_flight:
            raise IndexError("answer with no line in flight")
        tag, size = self._in_flight.popleft()
        self._used -= size
        return tag

    def oldest(self):
        """The tag of the oldest line sent and not yet answered (None if none is)."""
        return self._in_flight[0][0] if self._in_flight else None

    @property
    def in_flight(self) -> int:
        """Number of lines sent and not yet answered."""
        return len(self._in_flight)

    @property
    def used(self) -> int:
        """Bytes sent and not yet answered."""
        return self._used

    def clear(self) -> None:
        """Forget everything in flight (after a reset or a lost connection)."""
        self._in_flight.clear()
        self._used = 0
