"""Progress bars for long work: shown on a terminal, silent in pipes, tests and CI."""

from __future__ import annotations

import sys
from typing import Iterable, TypeVar

from tqdm import tqdm

T = TypeVar("T")


def progress(items: Iterable[T], desc: str, total: int | None = None) -> Iterable[T]:
    """Wrap `items` in a progress bar on stderr when stderr is a terminal."""
    return tqdm(items, desc=desc, total=total, disable=not sys.stderr.isatty(), leave=False, unit="it")
