"""Stop signals for one command: SIGTERM raises `Terminated` and SIGINT `KeyboardInterrupt` in the main thread, and
each is remembered, so that a stop is never lost.

Python cannot raise out of a callback it runs on its own (a weakref's, a `__del__`): a signal whose handler runs
there is printed as "Exception ignored" and the command goes on (seen under load as SIGTERM landed in importlib's
module-lock callback while the command's modules loaded: the export finished and exited 0). `StopSignals` keeps
such a stop quiet and `raise_pending` raises it again where the command returns, before its outputs are committed.
"""

from __future__ import annotations

import signal
import sys
import threading

from fabline.errors import Terminated


class StopSignals:
    """Context: while inside, SIGTERM and SIGINT raise, and one Python swallows is kept; on exit the old handlers return."""

    def __init__(self) -> None:
        self.pending: KeyboardInterrupt | None = None  # the last stop raised
        self.swallowed: KeyboardInterrupt | None = None  # a stop Python swallowed in a callback, not yet raised again
        self._previous: dict[int, object] = {}
        self._hook = None

    def __enter__(self) -> "StopSignals":
        if threading.current_thread() is not threading.main_thread():  # only the main thread may set handlers
            return self
        self._previous[signal.SIGTERM] = signal.signal(signal.SIGTERM, self._stop)
        if signal.getsignal(signal.SIGINT) is signal.default_int_handler:  # not where the shell ignores Ctrl-C
            self._previous[signal.SIGINT] = signal.signal(signal.SIGINT, self._stop)
        self._hook = sys.unraisablehook
        sys.unraisablehook = self._unraisable
        return self

    def __exit__(self, *exc) -> None:
        for number, handler in self._previous.items():
            signal.signal(number, handler)
        if self._hook is not None:
            sys.unraisablehook = self._hook

    def raise_pending(self) -> None:
        """Raise again the stop that was swallowed where it landed (one a command caught and handled stays handled)."""
        stop, self.swallowed = self.swallowed, None
        if stop is not None:
            raise stop

    def _stop(self, number, frame) -> None:
        self.pending = KeyboardInterrupt() if number == signal.SIGINT else Terminated(number)
        raise self.pending

    def _unraisable(self, unraisable) -> None:
        if unraisable.exc_value is not None and unraisable.exc_value is self.pending:
            self.swallowed = self.pending  # `raise_pending` raises it again
            return
        self._hook(unraisable)


def forget_unhandled_interrupt() -> None:
    """CPython remembers a KeyboardInterrupt that escaped Python code an extension ran with PyRun_String while it
    loaded, and at exit kills itself with SIGINT (exit -2, whatever `main` returned); a PyRun call that succeeds
    clears that memory, so an interrupt handled here exits 130 as it says (seen with Ctrl-C ~0.2 s into unroll)."""
    import ctypes

    ctypes.pythonapi.PyRun_SimpleString(b"pass")
