"""What the runner page's console may send to a machine, checked before it reaches a worker.

The console is for the operator's set-up at the machine, as OctoPrint's, LaserGRBL's and LightBurn's are: a `$N=V`
setting (only after a confirmation: it changes the controller for every later program), unlock (`$X`), home (`$H`),
jog (`$J=...`), the work origin (`G10 L20 P1 X0 Y0`, or `G92 X0 Y0` as Grbl sets a temporary one), the controller's
own reports (`$$`, `$#`, `$G`, `$I`) and Grbl's real-time overrides of feed, rapid and laser power
(`fabline.link.protocol.OVERRIDES`). Anything else is refused: a program is cut through the queue.
"""

from __future__ import annotations

import re

from fabline.errors import FablineError
from fabline.link.protocol import OVERRIDES

_NUMBER = r"-?(\d+\.?\d*|\.\d+)"
_AXES = rf"(\s*[XYZ]\s*{_NUMBER})+"
_LINES = {
    "setting": re.compile(rf"\$\d{{1,3}}={_NUMBER}"),
    "unlock": re.compile(r"\$X"),
    "home": re.compile(r"\$H"),
    "report": re.compile(r"\$[$#GI]"),
    "jog": re.compile(rf"\$J=(\s*(G53|G9[01]|G2[01]|[XYZF]\s*{_NUMBER}))+"),  # with an axis and F: see check_line
    "origin": re.compile(rf"G10\s*L20\s*P[1-6]{_AXES}|G92{_AXES}"),
}
_SAID = ("a $N=V setting, $X (unlock), $H (home), a $J= jog with a feed (e.g. $J=G91 X10 F1000), "
         "a work origin (G10 L20 P1 X0 Y0, or G92 X0 Y0), or $$, $#, $G, $I; a program is cut through the queue")


def check_line(text: str) -> tuple[str, str]:
    """The console line as it is sent (upper case, trimmed) and its kind (setting, unlock, home, report, jog,
    origin); anything else is a FablineError saying what the console sends."""
    if not isinstance(text, str) or "\n" in text or "\r" in text or not text.isascii():
        raise FablineError(f"console: one line of ASCII text expected, got {text!r}")
    line = text.strip().upper()
    kind = next((kind for kind, pattern in _LINES.items() if pattern.fullmatch(line)), None)
    if kind == "jog" and not (re.search(r"[XYZ]", line[3:]) and "F" in line):
        kind = None  # Grbl refuses a jog without a target or a feed rate
    if kind is None:
        raise FablineError(f"console: {line!r} is not sent from the console; send {_SAID}")
    return line, kind


def check_override(name: str) -> str:
    """An override's name as `OVERRIDES` has it ('feed +10%', 'power 100%', ...); anything else is a FablineError."""
    if name not in OVERRIDES:
        raise FablineError(f"console: unknown override {name!r} (use one of: {', '.join(OVERRIDES)})")
    return name
