"""The argparse types of length, size and load options (`fabline.units` reads the text): a plain number is in the
option's base unit, which the help names (`HelpFormatter` adds it to the default)."""

from __future__ import annotations

import argparse
from typing import Callable

from fabline.fileio import MAX_MM
from fabline.model_units import Length, parse_model_length
from fabline.units import MM_PER_UNIT, parse_length, parse_load, parse_size


def _option_type(read: Callable[[str], float], unit: str) -> Callable[[str], float]:
    """An argparse type from a reader of the option's text whose plain numbers are in `unit`: its ValueError becomes
    argparse's one-line error, and the help names the unit (`HelpFormatter` adds it to the default)."""

    def parse(text: str) -> float:
        try:
            return read(text)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    parse.__name__ = "float"  # argparse names the type in its messages; the campaign test finds number options
    parse.unit = unit
    return parse


def length(unit: str) -> Callable[[str], float]:
    """The argparse type of a length option whose plain numbers are in `unit` ('mm' or 'm')."""
    return _option_type(lambda text: parse_length(text, unit), unit)


def load(unit: str) -> Callable[[str], float]:
    """The argparse type of a load option whose plain numbers are in `unit` ('kN/m2' or 'N'), or with a unit as the
    job file takes them (`0.8kPa`, `750 N/m2`, `1.5kN`)."""

    def read(text: str) -> float:
        try:
            number = float(text)
        except ValueError:
            return parse_load(text, unit)  # a string with a unit
        return parse_load(number, unit)

    return _option_type(read, unit)


def length_model(text: str) -> Length:
    """The argparse type of a positive length in the model's units (`--spacing 0.35` on a surface in m), or with
    a unit (`17mm`, `0.35 m`); the stage converts it once it has read the model's units, and checks it is
    plausible in them."""
    try:
        length = parse_model_length(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    if not length.value > 0:
        raise argparse.ArgumentTypeError(f"must be a positive length, got {text!r}")
    return length


length_model.__name__ = "float"  # argparse names the type in its messages; the campaign test finds number options
length_model.unit = "model units"


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


def profile(text: str) -> str:
    """The argparse type of a strip profile HEIGHTxTHICKNESS (`--profile 100x1.5`, `10cm x 1.5mm`): plain numbers
    in mm; given to the stage as the plain "HxT" in mm it reads (`fabline.unroll.parse_profile`)."""
    try:
        height, thickness = parse_size(text, "mm")
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected HEIGHTxTHICKNESS in mm or with a unit: 100x1.5, 10cm x 1.5mm; "
                                         f"got {text!r}") from None
    if not (height > 0 and thickness > 0):
        raise argparse.ArgumentTypeError(f"height and thickness must be positive, got {text!r}")
    return "x".join(f"{value:.9f}".rstrip("0").rstrip(".") for value in (height, thickness))


profile.unit = "mm"

length_mm = length("mm")
length_m = length("m")
load_area = load("kN/m2")
load_point = load("N")
