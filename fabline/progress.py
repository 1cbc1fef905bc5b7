"""Progress bars for long work (shown on a terminal, silent in pipes, tests and CI) and the time a job has left.

`estimate` is the one ETA rule of fabline: the planner's machine time (`fabline.machine.motion`), corrected by the
pace actually made so far. The stream bar, the `fabline run` display and summary, the report and the runner page
all use it.
"""

from __future__ import annotations

import sys
import time
import urllib.parse
from dataclasses import dataclass
from typing import Callable, Iterable, TypeVar

from tqdm import tqdm

from fabline.units import duration

T = TypeVar("T")

PRIOR_SHARE = 0.05
"""How much planned time (share of the whole) the planner's own pace counts for against the pace observed."""


class StreamBar:
    """A terminal bar for a program being streamed: its length and percentage the share of the planned machine time
    done (`Eta.fraction`: a sheet whose one long cut is most of its time is not nearly done when most of its short
    lines are), then lines done of all, elapsed and remaining time and a status text; silent unless stderr is a
    terminal. `position` stacks several (one per machine)."""

    SCALE = 1000
    """Steps of the bar (a tenth of a percent)."""

    def __init__(self, desc: str = "", position: int = 0, leave: bool = True, unit: str = "line"):
        self.unit = unit
        self.bar = tqdm(total=self.SCALE, unit=unit, desc=desc, position=position, leave=leave, dynamic_ncols=True,
                        disable=not sys.stderr.isatty(), bar_format="{l_bar}{bar}|")

    def show(self, done: int, total: int, eta: "Eta | None", status: str = "", desc: str | None = None) -> None:
        """Redraw with `done` of `total` lines (or sheets), the time and `status` (and a new `desc`); the bar by the
        planned machine time of `eta`, by `done` of `total` only while no plan is known."""
        fraction = eta.fraction if eta is not None and eta.fraction is not None else (done / total if total else 0.0)
        self.bar.n = round(self.SCALE * min(max(fraction, 0.0), 1.0))
        if desc is not None:
            self.bar.set_description_str(desc, refresh=False)
        counted = f"{done}/{total}" + ("" if self.unit == "line" else f" {self.unit}s")
        text = ", ".join(part for part in (counted, eta.describe() if eta else "") if part) + (f"; {status}" if status else "")
        self.bar.bar_format = "{l_bar}{bar}| " + text.replace("{", "{{").replace("}", "}}")
        self.bar.refresh()

    def write(self, text: str) -> None:
        """A message above the bar."""
        self.bar.write(text, file=sys.stderr)

    def close(self) -> None:
        self.bar.close()


def above_bars(say: Callable[[str], None]) -> Callable[[str], None]:
    """`say` that prints its line above the progress bars on a terminal instead of through them."""
    def said(text: str) -> None:
        with tqdm.external_write_mode():
            say(text)
    return said


def progress(items: Iterable[T], desc: str, total: int | None = None) -> Iterable[T]:
    """Wrap `items` in a progress bar on stderr when stderr is a terminal."""
    return tqdm(items, desc=desc, total=total, disable=not sys.stderr.isatty(), leave=False, unit="it")


@dataclass(frozen=True)
class Eta:
    """Where a piece of work stands in time: seconds `elapsed`, estimated seconds `remaining`, the planner's
    `planned` seconds for all of it, and `pace`, actual seconds per planned second (smoothed)."""

    elapsed: float
    remaining: float
    planned: float
    pace: float
    planned_done: float = 0.0

    @property
    def total(self) -> float:
        """Estimated seconds from start to finish."""
        return self.elapsed + self.remaining

    @property
    def fraction(self) -> float | None:
        """The share of the work done by planned machine time (what progress bars and percentages show); None
        when nothing is planned."""
        return min(self.planned_done / self.planned, 1.0) if self.planned > 0 else None

    def as_dict(self) -> dict:
        """JSON-ready, seconds to 0.1."""
        return {"elapsed_s": round(self.elapsed, 1), "remaining_s": round(self.remaining, 1),
                "planned_s": round(self.planned, 1), "pace": round(self.pace, 3)}

    def describe(self) -> str:
        """`elapsed 0:01:02, remaining 1:20:00`, for a terminal or a summary line."""
        return f"elapsed {duration(self.elapsed)}, remaining {duration(self.remaining)}"


def estimate(planned_total: float, planned_done: float, elapsed: float) -> Eta:
    """The time left of work the planner says takes `planned_total` seconds, of which `planned_done` are done in
    `elapsed` actual seconds: the planned rest times the observed pace (elapsed / planned done), the pace shrunk
    towards the planner's own (1) by a prior worth PRIOR_SHARE of the work, so an early start-up delay or a
    single slow line does not swing the estimate, while a machine that keeps a different pace is followed."""
    planned_total, planned_done = max(planned_total, 0.0), min(max(planned_done, 0.0), max(planned_total, 0.0))
    prior = PRIOR_SHARE * planned_total
    pace = (elapsed + prior) / (planned_done + prior) if planned_done + prior > 0 else 1.0
    return Eta(elapsed, (planned_total - planned_done) * pace, planned_total, pace, planned_done)


def finish_time(finish_at: float, now: float) -> str:
    """When work ends (Unix times), as a clock on the wall reads it: `14:05` today, with its date from tomorrow on
    (`Thu 3 Dec 14:05`, and the year when it is another year): a 49-hour job does not end at a time of today."""
    end, today = time.localtime(finish_at), time.localtime(now)
    clock = time.strftime("%H:%M", end)
    if end[:3] == today[:3]:
        return clock
    day = f"{time.strftime('%a', end)} {end.tm_mday} {time.strftime('%b', end)}"
    return f"{day} {end.tm_year} {clock}" if end.tm_year != today.tm_year else f"{day} {clock}"


def simulated_speedup(port: str) -> float:
    """How many times faster than real time the machine at `port` runs: a `sim://` URL's time_scale, else 1."""
    if not port.startswith("sim://"):
        return 1.0
    values = urllib.parse.parse_qs(urllib.parse.urlsplit(port).query).get("time_scale")
    try:
        scale = float(values[-1]) if values else 1.0
    except ValueError:
        return 1.0
    return scale if scale > 0 else 1.0
