"""Pausing Python's cyclic garbage collector around bulk work that makes millions of acyclic objects."""

from __future__ import annotations

import gc
from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def collector_paused() -> Iterator[None]:
    """Pause the cyclic collector: a large unroll or parts file creates millions of acyclic objects (parts, arrays,
    JSON lists), and the collector's repeated full passes over them cost a fifth to a half of the run. Restored after."""
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was_enabled:
            gc.enable()
