"""Faults injected into the simulator by tests: a dropped connection, line noise, an error, an alarm, a stall."""

from __future__ import annotations

from dataclasses import dataclass, field


class ConnectionDropped(Exception):
    """Raised to the transport when an injected fault cuts the connection."""


@dataclass
class Faults:
    """Faults to inject. Byte offsets count every byte the controller received since it was created.

    drop_at: cut the connection once the controller has received this many bytes (one per entry).
    corrupt_at: replace the byte at this offset with '#', as line noise would.
    error_line: answer error:`error_code` instead of executing the line numbered N<error_line> (once).
    alarm_line: raise ALARM:`alarm_code` halfway through executing line N<alarm_line> (once).
    stall_at / stall_seconds: stop reading and answering for a while once this many bytes arrived.
    """

    drop_at: list[int] = field(default_factory=list)
    corrupt_at: list[int] = field(default_factory=list)
    error_line: int | None = None
    error_code: int = 20
    alarm_line: int | None = None
    alarm_code: int = 1
    stall_at: int | None = None
    stall_seconds: float = 0.0
