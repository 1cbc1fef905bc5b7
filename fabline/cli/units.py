"""The argparse types of length and size options (`fabline.units` reads the text): a plain number is in the
option's base unit, which the help names (`HelpFormatter` adds it to the default)."""

from __future__ import annotations

import argparse
from typing import Callable

from fabline.fileio import MAX_MM
from fabline.units import MM_PER_UNIT, parse_length, parse_size


def length(unit: str) -> Callable[[str], float]:
    """The argparse type of a length option whose plain numbers are in `unit` ('mm' or 'm'); the option's help
    names the unit (`HelpFormatter` adds it to the default)."""

    def parse(text: str) -> float:
        try:
            return parse_length(text, unit)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    parse.__name__ = "float"  # argparse names the type in its messages; the campaign test finds number options
    parse.unit = unit
    return parse


def size(unit: str) -> Callable[[str], tuple[float, float]]:
    """The argparse type of a WIDTHxHEIGHT option whose plain numbers are in `unit`: both positive, at most
    MAX_MM (the largest sheet or footprint any stage takes)."""

    def parse(text: str) -> tuple[float, float]:
        try:
            width, height = parse_size(text, unit)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
        if not (0 < width * MM_PER_UNIT[unit] <= MAX_MM and 0 < height * MM_PER_UNIT[unit] <= MAX_MM):
            raise argparse.ArgumentTypeError(f"width and height must be positive, at most {MAX_MM / 1e3:g} m, "
                                             f"got {text!r}")
        return width, height

    parse.__name__ = "size"
    parse.unit = unit
    return parse


length_mm = length("mm")
length_m = length("m")
