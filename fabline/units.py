"""Lengths and times as people write and read them: lengths with units, as vpype reads them (`3mm`, `0.2 mm`, `4m`,
`25 cm`, `1in`), for every length option of the command line and the length keys of a job file (a plain number
keeps meaning the option's base unit, mm or m); sheet sizes in the same units (`4000x2000`, `4m x 2m`,
`4000x2000mm`: a unit after the last number serves both); and the one precision every summary and report prints
(mm to 0.1, m to the millimetre, times as h:mm:ss).
"""

from __future__ import annotations

import math
import re

from fabline.errors import FablineError

MM_PER_UNIT = {"mm": 1.0, "cm": 10.0, "dm": 100.0, "m": 1000.0, "km": 1e6, "um": 1e-3, "in": 25.4, "inch": 25.4,
               '"': 25.4, "ft": 304.8, "yd": 914.4, "pt": 25.4 / 72, "pc": 25.4 / 6, "px": 25.4 / 96}
"""Millimetres per unit: the metric units, inches, feet, yards and the SVG/CSS units (pt, pc, px at 96 per inch)."""
LENGTH_FORMS = "a number in {unit} or with a unit: 3mm, 0.2 mm, 25 cm, 4m, 1in"
SIZE_FORMS = "WIDTHxHEIGHT in {unit} or with a unit: 4000x2000, 4000x2000mm, 4m x 2m"
MAX_LENGTH_MM = 1e9
"""The largest length any option or key takes, in mm (1000 km): beyond it a value is a mistake."""
_NUMBER = r"[-+]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][-+]?\d+)?"
_LENGTH = re.compile(rf"\s*({_NUMBER})\s*([a-zA-Z\"]*)\s*")
_SIZE = re.compile(rf"\s*({_NUMBER})\s*([a-zA-Z\"]*)\s*[xX×*]\s*({_NUMBER})\s*([a-zA-Z\"]*)\s*")


def parse_length(text: str, unit: str = "mm") -> float:
    """A length in `unit` from '3', '3mm', '0.2 mm', '4m', '1in'; a ValueError saying the accepted forms otherwise."""
    match = _LENGTH.fullmatch(text)
    if not match:
        raise ValueError(f"expected {LENGTH_FORMS.format(unit=unit)}; got {text!r}")
    return _convert(float(match[1]), match[2], unit, text, LENGTH_FORMS)


def parse_size(text: str, unit: str = "mm") -> tuple[float, float]:
    """(width, height) in `unit` from '4000x2000', '4m x 2m', '4000x2000mm' (a unit after the last number serves
    both when the first has none); a ValueError saying the accepted forms otherwise."""
    match = _SIZE.fullmatch(text)
    if not match:
        raise ValueError(f"expected {SIZE_FORMS.format(unit=unit)}; got {text!r}")
    first_unit = match[2] or match[4]
    return (_convert(float(match[1]), first_unit, unit, text, SIZE_FORMS),
            _convert(float(match[3]), match[4], unit, text, SIZE_FORMS))


def _convert(value: float, given: str, unit: str, text: str, forms: str) -> float:
    given = given.lower() or unit
    if given not in MM_PER_UNIT:
        raise ValueError(f"unknown unit {given!r} (use mm, cm, m, in, ft, pt or px); expected {forms.format(unit=unit)}; "
                         f"got {text!r}")
    result = value * MM_PER_UNIT[given] / MM_PER_UNIT[unit]
    if not abs(result * MM_PER_UNIT[unit]) <= MAX_LENGTH_MM:
        raise ValueError(f"{text!r} is longer than {MAX_LENGTH_MM / 1e6:g} km")
    return result


LOAD_UNITS = {"kN/m2": {"kN/m2": 1.0, "kPa": 1.0, "N/m2": 1e-3, "Pa": 1e-3}, "N": {"N": 1.0, "kN": 1000.0}}
"""The loads' units: a number is in the first (kN/m2 for area loads, N for point loads), a string names its unit
(`"750 N/m2"`, `"1 kN"`)."""
_LOAD = re.compile(rf"\s*({_NUMBER})\s*([A-Za-z/0-9]+)\s*")


def parse_load(value: float | str, unit: str) -> float:
    """A load in `unit` ('kN/m2' or 'N') from a number (in `unit`) or a string with one of LOAD_UNITS[unit], not
    negative; a ValueError saying the accepted forms otherwise."""
    units = LOAD_UNITS[unit]
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        number = float(value)
    elif isinstance(value, str) and (match := _LOAD.fullmatch(value)) and match.group(2) in units:
        number = float(match.group(1)) * units[match.group(2)]
    else:
        raise ValueError(f"expected a number in {unit} or a string with a unit ({', '.join(units)}), got {value!r}")
    if not 0.0 <= number < math.inf:
        raise ValueError(f"must not be negative, got {value!r}" if number < 0 else f"must be a finite load, got {value!r}")
    return number


def job_length(value: float | str, unit: str = "mm") -> float:
    """A job file's length key: a number (in `unit`, as before units were accepted) or a string with a unit; a
    FablineError saying the accepted forms otherwise (the caller names the file and key)."""
    if not isinstance(value, str):
        return float(value)  # checked by the stage's options as before
    try:
        return parse_length(value, unit)
    except ValueError as exc:
        raise FablineError(str(exc)) from None


def metres(millimetres: float) -> str:
    """A length for a summary line, in m to the millimetre (`12.346`), as every command prints metres."""
    return f"{millimetres / 1000:.3f}"


def duration(seconds: float) -> str:
    """A time for a summary line as h:mm:ss, hours unbounded (`44:46:46`), as every command prints durations."""
    minutes, secs = divmod(round(max(seconds, 0.0)), 60)
    return f"{minutes // 60}:{minutes % 60:02d}:{secs:02d}"


def mm(value: float | None) -> str:
    """A length in mm as summaries and the report show it: to 0.1 mm (a survey's 10.3431 is 10.3), '-' for none."""
    return "-" if value is None else f"{value:.1f}"
