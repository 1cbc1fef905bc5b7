"""What a controller's build can do, as its `$I` answer tells: firmware, version, option letters, buffer sizes.

Grbl 1.1 answers `$I` with `[VER:1.1h.20190830:]` and `[OPT:V,15,128]`: option letters, planner blocks,
receive-buffer bytes. A stock build has only `V` (variable spindle); `N` adds the `Ln:` line number to status
reports and `M` the mist coolant M7 (see Grbl's interface documentation, "$I - View build info").
grblHAL (grblHAL/core report.c, report_build_info) adds two numbers to OPT (axes, tool table entries) and
lines such as `[AXS:3:XYZ]`, `[NEWOPT:...]` and `[FIRMWARE:grblHAL]`; its `N` is always there.
FluidNC (bdring/FluidNC Report.cpp, report_build_info) answers `[VER:3.9 FluidNC v3.9.5:]` and option letters
only (`[OPT:PHSEW]`): its buffer sizes are not in `$I` (the `Bf:` of a status report says them).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

_VERSION = re.compile(r"^VER:([^:\]]+)")
_OPTIONS = re.compile(r"^OPT:([^,\]]*)(?:,(\d+),(\d+)(?:,(\d+),(\d+))?)?$")


@dataclass(frozen=True)
class BuildInfo:
    """A controller build's capabilities; the defaults are a stock Grbl 1.1h build."""

    version: str = "1.1h.20190830"
    options: str = "V"
    planner_blocks: int = 15
    rx_buffer: int = 128
    firmware: str = "grbl"
    """The firmware family: grbl (gnea/grbl 1.1), grblhal or fluidnc."""
    axes: int = 3

    @property
    def line_numbers(self) -> bool:
        """Status reports carry `Ln:` (compile option USE_LINE_NUMBERS, off in a stock build)."""
        return "N" in self.options

    @property
    def mist_coolant(self) -> bool:
        """M7 is accepted (compile option ENABLE_M7, off in a stock build: error:20)."""
        return "M" in self.options

    def lines(self) -> list[str]:
        """The `$I` feedback lines this build sends (before its `ok`)."""
        version = f"[VER:{self.version}:]"
        if self.firmware == "fluidnc":
            return [version, f"[OPT:{self.options}]", "[MSG:Machine: fabline simulator]"]
        if self.firmware == "grblhal":
            return [version, f"[OPT:{self.options},{self.planner_blocks},{self.rx_buffer},{self.axes},0]",
                    f"[AXS:{self.axes}:{'XYZABC'[:self.axes]}]", "[NEWOPT:ENUMS,RT+,SED]", "[FIRMWARE:grblHAL]"]
        return [version, f"[OPT:{self.options},{self.planner_blocks},{self.rx_buffer}]"]

    @classmethod
    def parse(cls, feedback: list[str], firmware: str = "grbl") -> "BuildInfo":
        """From the feedback lines of `$I` (brackets removed or not) of a `firmware` controller (the answer's own
        `[FIRMWARE:grblHAL]` or `FluidNC` version overrides it); fields not reported keep that firmware's stock
        values."""
        texts = [text.strip().strip("[]") for text in feedback]
        for text in texts:
            if text == "FIRMWARE:grblHAL":
                firmware = "grblhal"
            elif (match := _VERSION.match(text)) and "FluidNC" in match.group(1):
                firmware = "fluidnc"
        stock = STOCK_BUILDS[firmware]
        found: dict = {"firmware": firmware}
        for text in texts:
            if match := _VERSION.match(text):
                found["version"] = match.group(1)
            elif match := _OPTIONS.match(text):
                found["options"] = match.group(1)
                if match.group(2):
                    found.update(planner_blocks=int(match.group(2)), rx_buffer=int(match.group(3)))
                if match.group(4):
                    found["axes"] = int(match.group(4))
        return BuildInfo(**{**stock.__dict__, **found})


STOCK_BUILD = BuildInfo()
"""A stock Grbl 1.1h build as compiled from gnea/grbl's defaults: no line numbers, no M7, 15 blocks, 128 bytes."""

GRBLHAL_BUILD = BuildInfo(version="1.1f.20240222", options="VNMSL", planner_blocks=100, rx_buffer=1024,
                          firmware="grblhal")
"""A stock grblHAL build: line numbers always compiled in, mist coolant, 100 planner blocks
(DEFAULT_PLANNER_BUFFER_BLOCKS), RX_BUFFER_SIZE 1024."""

FLUIDNC_BUILD = BuildInfo(version="3.9 FluidNC v3.9.5", options="PHSEW", planner_blocks=15, rx_buffer=128,
                          firmware="fluidnc")
"""A stock FluidNC on an ESP32: `planner_blocks: 16` in its config, of which it fills 15 (Planner.cpp reports
planner_blocks - 1 free), and the UART's 128-byte FIFO (Uart::rx_buffer_available is UART_FIFO_LEN - available)."""

STOCK_BUILDS = {"grbl": STOCK_BUILD, "grblhal": GRBLHAL_BUILD, "fluidnc": FLUIDNC_BUILD}

ANY_BUILD = BuildInfo(options="VNMR")
"""A build with every option that changes what the G-code parser accepts (M7, M56): a program is read with it
before the controller has said which build it is; what the real build lacks is then a compatibility problem."""
