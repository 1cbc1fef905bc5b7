"""The operator's requests to a running stream, from any thread or a signal handler: pause, resume, abort,
overrides; and the time the machine stood held waiting for the operator."""

from __future__ import annotations

import threading
import time

from fabline.errors import FablineError
from fabline.link.protocol import CYCLE_START, FEED_HOLD, OVERRIDES


def override_byte(name: str) -> bytes:
    """The real-time byte of the override `name` (`OVERRIDES`: 'feed +10%', ...); an unknown name is refused."""
    if name not in OVERRIDES:
        raise FablineError(f"unknown override {name!r} (use one of: {', '.join(OVERRIDES)})")
    return OVERRIDES[name]


class Controls:
    """Real-time bytes queued for the stream loop, the pause and abort flags, the held time of this run."""

    def __init__(self):
        self.aborting = threading.Event()
        self._lock = threading.RLock()  # taken by signal handlers too (SIGUSR1 resume), in the thread they interrupt
        self._realtime: list[bytes] = []
        self.paused = False
        self.message: str | None = None
        self.held, self._held_since = 0.0, None  # wall seconds held waiting for the operator in this run

    def pause(self) -> None:
        with self._lock:
            self._realtime.append(FEED_HOLD)
            self.paused = True
            if self._held_since is None:
                self._held_since = time.monotonic()

    def resume(self) -> None:
        with self._lock:
            self._realtime.append(CYCLE_START)
            self.paused = False
            self.message = None
            if self._held_since is not None:
                self.held += time.monotonic() - self._held_since
                self._held_since = None

    def override(self, name: str) -> None:
        byte = override_byte(name)
        with self._lock:
            self._realtime.append(byte)

    def program_paused(self, message: str) -> None:
        """The program itself stopped the machine (M0): held until the operator resumes."""
        with self._lock:
            self.paused = True
            self.message = message
            if self._held_since is None:
                self._held_since = time.monotonic()

    def take(self) -> list[bytes]:
        """The real-time bytes asked for since the last call."""
        with self._lock:
            pending, self._realtime = self._realtime, []
        return pending

    def start(self, now: float) -> None:
        """A stream starts at `now`: nothing held yet, unless it starts paused."""
        with self._lock:
            self.held, self._held_since = 0.0, (now if self.paused else None)

    def held_now(self) -> float:
        """Wall seconds held waiting for the operator so far in this run, a hold in progress included."""
        with self._lock:
            since = self._held_since
            return self.held + (time.monotonic() - since if since is not None else 0.0)
