"""Lengths in a model's own units (known only once its file is read): a number written with a unit or without
one (then in the model's units), and the check that refuses a value implausible in those units, saying what was
probably meant (`--spacing 0.35` on a surface in mm is a spacing in metres; `--tag-size 0.065` is metres too).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from fabline.errors import FablineError
from fabline.units import MM_PER_UNIT, parse_length

UNIT_NAMES = {"mm": "millimetres", "cm": "centimetres", "m": "metres", "in": "inches", "ft": "feet"}
"""The units a model can be in (the model format's UNIT_TO_MM), by name."""
_TRIED = ("m", "mm", "cm", "in", "ft")
"""The order a mistaken plain number is tried in the other units: metres and millimetres are the usual confusion."""
_UNIT = re.compile(r"[a-zA-Z\"]*\s*$")


@dataclass(frozen=True)
class Length:
    """A length as written: its number, the unit written with it (None: the model's units) and the text."""

    value: float
    unit: str | None = None
    text: str = ""

    def in_units(self, units: str) -> float:
        """The length in `units` (a plain number is in them already)."""
        return self.value if self.unit is None else self.value * MM_PER_UNIT[self.unit] / MM_PER_UNIT[units]


def parse_model_length(text: str) -> Length:
    """A length from '0.35' (model units), '17mm', '0.35 m', '1in'; a ValueError saying the accepted forms."""
    try:
        millimetres = parse_length(text, "mm")  # the form, the unit and the size checked as for any length
    except ValueError as exc:
        raise ValueError(str(exc).replace("a number in mm or", "a number in the model's units or")) from None
    unit = _UNIT.search(text)[0].strip().lower() or None
    return Length(millimetres if unit is None else millimetres / MM_PER_UNIT[unit], unit, text.strip())


def model_length(length: float | Length, units: str, source: str, plausible_mm: tuple[float, float],
                 what: str) -> float:
    """`length` in the model's `units`, refused (FablineError) when `what` could not be that long: a plain number
    that another unit would make plausible gets the value probably meant (`give 350`)."""
    given = length if isinstance(length, Length) else Length(float(length), None, f"{float(length):g}")
    value = given.in_units(units)
    low, high = (bound / MM_PER_UNIT[units] for bound in plausible_mm)
    if low <= value <= high:
        return value
    if given.unit is not None:
        raise FablineError(f"{source} {given.text}: {what} must be {_length_text(plausible_mm[0])} to "
                           f"{_length_text(plausible_mm[1])}, got {value:g} {units}")
    return check_plausible(value, units, plausible_mm, source, what)


def check_plausible(value: float, units: str, plausible_mm: tuple[float, float], source: str, what: str) -> float:
    """`value` (a plain number in `units`) when `what` can be that long; else a FablineError naming `source`, the
    range and, when another unit would make the number plausible, what to give instead."""
    low, high = (bound / MM_PER_UNIT[units] for bound in plausible_mm)
    number = isinstance(value, (int, float)) and not isinstance(value, bool)
    if number and low <= value <= high:  # NaN fails
        return float(value)
    hint = ""
    for other in (unit for unit in _TRIED if unit != units) if number else ():
        if plausible_mm[0] <= value * MM_PER_UNIT[other] <= plausible_mm[1]:
            hint = f"; {value:g} looks like {UNIT_NAMES[other]}: give {value * MM_PER_UNIT[other] / MM_PER_UNIT[units]:g}"
            break
    shown = f"{value:g}" if number else repr(value)
    raise FablineError(f"{source} {shown}: {what} in {UNIT_NAMES[units]} must be {low:g} to {high:g}{hint}")


def _length_text(millimetres: float) -> str:
    return f"{millimetres:g} mm" if millimetres < 1000 else f"{millimetres / 1000:g} m"
