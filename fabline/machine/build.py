"""What a Grbl build can do, as its `$I` answer tells: version, compile-time option letters, buffer sizes.

Grbl 1.1 answers `$I` with `[VER:1.1h.20190830:]` and `[OPT:V,15,128]`: option letters, planner blocks,
receive-buffer bytes. A stock build has only `V` (variable spindle); `N` adds the `Ln:` line number to status
reports and `M` the mist coolant M7 (see Grbl's interface documentation, "$I - View build info").
"""

from __future__ import annotations

import re
from dataclasses import dataclass

_VERSION = re.compile(r"^VER:([^:\]]+)")
_OPTIONS = re.compile(r"^OPT:([^,]*),(\d+),(\d+)")


@dataclass(frozen=True)
class BuildInfo:
    """A Grbl build's capabilities; the defaults are a stock Grbl 1.1h build."""

    version: str = "1.1h.20190830"
    options: str = "V"
    planner_blocks: int = 15
    rx_buffer: int = 128

    @property
    def line_numbers(self) -> bool:
        """Status reports carry `Ln:` (compile option USE_LINE_NUMBERS, off in a stock build)."""
        return "N" in self.options

    @property
    def mist_coolant(self) -> bool:
        """M7 is accepted (compile option ENABLE_M7, off in a stock build: error:20)."""
        return "M" in self.options

    def lines(self) -> list[str]:
        """The `$I` feedback lines this build sends."""
        return [f"[VER:{self.version}:]", f"[OPT:{self.options},{self.planner_blocks},{self.rx_buffer}]"]

    @classmethod
    def parse(cls, feedback: list[str]) -> "BuildInfo":
        """From the feedback lines of `$I` (brackets removed or not); fields not reported keep stock values."""
        found: dict = {}
        for text in feedback:
            text = text.strip().strip("[]")
            if match := _VERSION.match(text):
                found["version"] = match.group(1)
            elif match := _OPTIONS.match(text):
                found.update(options=match.group(1), planner_blocks=int(match.group(2)),
                             rx_buffer=int(match.group(3)))
        return cls(**found)


STOCK_BUILD = BuildInfo()
"""A stock Grbl 1.1h build as compiled from gnea/grbl's defaults: no line numbers, no M7, 15 blocks, 128 bytes."""

ANY_BUILD = BuildInfo(options="VNMR")
"""A build with every option that changes what the G-code parser accepts (M7, M56): a program is read with it
before the controller has said which build it is; what the real build lacks is then a compatibility problem."""

