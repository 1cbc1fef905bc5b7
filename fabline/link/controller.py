"""What is Grbl's own in talking to a controller: its banner, `$I` build and `$$` settings, soft reset, `$X`,
check mode `$C`, the parser tag in `$G`, the half-line flush.

grblHAL and FluidNC speak the same protocol; what differs (banner, where the build and settings are reported,
how a setting is changed) is the controller's `dialect` (fabline.link.dialects), known once `$I` answered.
"""

from __future__ import annotations

import re
import time

from fabline.errors import FablineError
from fabline.link.connection import Connection
from fabline.link.dialects import DIALECTS, GRBL, recognise
from fabline.link.protocol import CYCLE_START, FEED_HOLD, SOFT_RESET, STATUS_QUERY
from fabline.machine.build import STOCK_BUILD, BuildInfo

_FLUSH_LINE = b"#\n"
_TAG = re.compile(r"\bT(\d+)\b")


class Grbl:
    """A controller speaking Grbl 1.1's protocol on `connection` (Grbl, grblHAL or FluidNC: its `dialect`): its
    build, settings and banner once detected."""

    def __init__(self, connection: Connection):
        self.connection = connection
        self.build = STOCK_BUILD
        self.dialect = GRBL
        self.rx_buffer = STOCK_BUILD.rx_buffer
        self.settings: dict[int, float] = {}
        self.version: str | None = None
        """The banner, if the controller sent one."""

    @property
    def url(self) -> str:
        return self.connection.url

    def open(self) -> None:
        """Open the port and make sure a GRBL 1.1 controller answers; only then start the exchange log."""
        self.connection.connect()
        self.detect()
        self.connection.start_log(f"connected to {self.url}: {self.dialect.label} {self.build.version}, "
                                  f"rx buffer {self.rx_buffer}")

    def detect(self) -> None:
        """Wake the controller and wait for a banner or a status report; read its build options and settings."""
        link = self.connection
        deadline = time.monotonic() + link.connect_timeout
        link.status = None
        while link.status is None:
            if time.monotonic() > deadline:
                raise FablineError(f"port {self.url}: no GRBL answer within {link.connect_timeout:g} s "
                                   "(not a GRBL controller, wrong port or wrong baud rate?)")
            link.write(STATUS_QUERY)
            end = time.monotonic() + 0.25
            while time.monotonic() < end and link.status is None:
                for response in link.read(0.05):
                    if response.kind == "banner":
                        self.version = response.text
                        self.dialect = recognise(response.text) or self.dialect
        if link.status.state == "Check":  # left by a host that died during --check: nothing ran, leave it
            self.flush_partial_line()
            self.leave_check()
            link.status = link.query_status()
        if link.status.state == "Idle":  # a critical alarm ignores everything but a reset
            self.flush_partial_line()
            self.read_build_info()

    def read_build_info(self) -> None:
        """The build from `$I` (its firmware, buffer sizes, `Ln:` or not, M7 or not) and the settings (`$$`, and
        FluidNC's config) in Grbl's numbers."""
        link = self.connection
        feedback = link.command(b"$I\n")
        self.build = BuildInfo.parse(feedback, self.dialect.name)
        self.dialect = DIALECTS[self.build.firmware]
        link.explain_error = self.dialect.explain_error
        if not any(text.startswith("OPT:") for text in feedback):
            link.exchange("#", "no [OPT:...] in $I: assuming a stock build")
        if not self.build.version.startswith(self.dialect.version_prefix):
            raise FablineError(f"port {self.url}: {self.dialect.label.split()[0]} {self.build.version} found; fabline "
                               f"streams to Grbl 1.1, grblHAL 1.1 and FluidNC")
        self.rx_buffer = self.build.rx_buffer
        if self.dialect.name == "fluidnc" and link.status is not None and link.status.rx_free is not None:
            self.rx_buffer = link.status.rx_free  # not in its $I; an idle `Bf:` ($10 with 2) shows the empty buffer
        self.settings = self.dialect.read_settings(
            lambda line, every_line: link.command(line, every_line=every_line))

    def reconnect(self, timeout: float) -> bool:
        """Try to reopen the port for `timeout` seconds (a USB cable plugged back in)."""
        link = self.connection
        link.close_port()
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                link.connect()
                self.detect()
                link.exchange("#", "reconnected")
                return True
            except FablineError:
                link.close_port()
                time.sleep(0.2)
        return False

    def ready(self, unlock: bool) -> None:
        """A new job needs an idle controller; a soft reset clears any half-received line and the tag."""
        status = self.connection.query_status()
        if status.state not in ("Idle", "Alarm"):
            raise FablineError(f"{self.url}: the controller is busy ({status.state}); wait for it or reset it")
        if status.state == "Alarm" and not unlock:
            raise FablineError(f"{self.url}: the controller is in alarm; home it or unlock it (--unlock) first")
        self.soft_reset(unlock=unlock)

    def soft_reset(self, unlock: bool = True) -> None:
        """Ctrl-X: flush buffers and parser state; unlock the ALARM:3 a reset during a hold causes."""
        link = self.connection
        link.write(SOFT_RESET)
        if link.listener is not None:
            link.listener.reset()
        alarm, deadline = None, time.monotonic() + link.answer_wait
        banner = False
        while not banner:
            if time.monotonic() > deadline:
                raise FablineError(f"{self.url}: no banner after a soft reset")
            for response in link.read(0.05):
                if response.kind == "banner":
                    banner = True
                elif response.kind == "alarm":
                    alarm = response.code
        time.sleep(0.05)
        link.read(0.02)
        status = link.query_status()
        if status.state == "Alarm" and unlock:
            link.command(b"$X\n")
            link.exchange("#", f"unlocked after {self.dialect.explain_alarm(alarm) if alarm else 'alarm'}")

    def feed_hold(self) -> None:
        self.connection.write(FEED_HOLD)

    def cycle_start(self) -> None:
        self.connection.write(CYCLE_START)

    def flush_partial_line(self) -> None:
        """Discard a line a lost connection left half-received: with `#` appended no line parses, so the
        controller answers exactly one error and executes nothing (stray oks of older lines are skipped)."""
        self.connection.read(0.05)
        self.connection.command(_FLUSH_LINE, expect_error=True)

    def parser_tag(self) -> int | None:
        """The T word of the parser state (`$G`): the tag of the last line parsed."""
        modes = self.connection.command(b"$G\n")
        return next((int(match.group(1)) for text in modes if (match := _TAG.search(text))), None)

    def enter_check(self) -> None:
        """Check mode: lines are parsed and answered, nothing moves."""
        self.connection.command(b"$C\n")

    def leave_check(self) -> None:
        """Out of check mode (Grbl resets itself: wait for its banner)."""
        self.connection.command(b"$C\n", until_banner=True)
