"""Bought hardware (data in hardware.toml): the bracing cable and metric bolts, sized from the stack-up they pass.

A bolt's size is the largest metric size whose fine clearance hole (ISO 273) fits the part's hole (a carriage bolt:
whose square neck, side d, fits the square hole); its length is the grip (everything it clamps) plus the nut and
two pitches of thread beyond it, rounded up to the next standard length of its kind.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

from fabline.errors import FablineError
from fabline.fileio import read_toml

BUILTIN_HARDWARE = Path(__file__).with_name("hardware.toml")
BOLT_KINDS = ("carriage", "hex", "button")


@dataclass(frozen=True)
class Cable:
    """A bracing cable: diameter (mm), metallic fill factor and density (kg/m3); its mass per metre follows."""

    description: str
    diameter: float
    fill_factor: float
    density: float
    end_fitting: str

    @property
    def kg_per_m(self) -> float:
        return self.fill_factor * math.pi * self.diameter ** 2 / 4.0 * self.density * 1e-6


@dataclass(frozen=True)
class BoltSize:
    """One metric size: nominal d, pitch, clearance hole, nut and washer (mm, g) and head masses by kind (g)."""

    name: str
    d: float
    pitch: float
    clearance_hole: float
    nut_height: float
    nut_mass: float
    washer_thickness: float
    washer_mass: float
    head_mass: dict


@dataclass(frozen=True)
class Bolt:
    """A sized bolt: kind, metric size, length (mm), its grip and mass with its nut (g)."""

    kind: str
    size: BoltSize
    length: float
    grip: float
    mass_g: float

    @property
    def name(self) -> str:
        return f"{self.size.name}x{self.length:g}"


@dataclass(frozen=True)
class Catalogue:
    """Everything hardware.toml declares."""

    cable: Cable
    sizes: tuple[BoltSize, ...]
    lengths: dict
    density: float
    protrusion_pitches: float
    coupler: dict  # the shear blocks' wood: description, density (kg/m3)

    def size_for_hole(self, hole: float, square: bool = False) -> BoltSize:
        """The largest size whose clearance hole (square: whose square neck, side d) fits a hole `hole` mm across."""
        fitting = [s for s in self.sizes if (s.d if square else s.clearance_hole) <= hole + 1e-9]
        if not fitting:
            raise FablineError(f"a {hole:g} mm {'square ' if square else ''}hole is smaller than any bolt in "
                               f"{BUILTIN_HARDWARE.name} (smallest {self.sizes[0].name})")
        return max(fitting, key=lambda s: s.d)

    def bolt(self, kind: str, hole: float, grip: float, washers: int = 0, square: bool = False) -> Bolt:
        """A `kind` bolt through a `hole` mm hole clamping `grip` mm, with `washers` plain washers and one nut."""
        size = self.size_for_hole(hole, square)
        need = grip + washers * size.washer_thickness + size.nut_height + self.protrusion_pitches * size.pitch
        standard = [float(v) for v in self.lengths[kind] if v >= need - 1e-9]
        if not standard:
            raise FablineError(f"a {size.name} {kind} bolt for a {grip:g} mm grip needs {need:.1f} mm, longer than "
                               f"the longest standard length {max(self.lengths[kind]):g} mm ({BUILTIN_HARDWARE.name})")
        length = standard[0]
        shank = math.pi * size.d ** 2 / 4.0 * length * self.density * 1e-6  # g
        mass = shank + size.head_mass[kind] + size.nut_mass + washers * size.washer_mass
        return Bolt(kind, size, length, grip + washers * size.washer_thickness, mass)


@lru_cache(maxsize=4)
def load_catalogue(path: Path = BUILTIN_HARDWARE) -> Catalogue:
    """The hardware catalogue from `path` (the built-in one by default), checked."""
    data = read_toml(path)
    try:
        cable = Cable(**data["cable"])
        bolt = data["bolt"]
        sizes = tuple(sorted((BoltSize(name, **values) for name, values in bolt["sizes"].items()), key=lambda s: s.d))
        lengths = {kind: sorted(bolt["lengths"][kind]) for kind in BOLT_KINDS}
        coupler = {"description": str(data["coupler"]["description"]), "density": float(data["coupler"]["density"])}
        return Catalogue(cable, sizes, lengths, float(bolt["density"]), float(bolt["protrusion_pitches"]), coupler)
    except (KeyError, TypeError) as exc:
        raise FablineError(f"{path}: malformed hardware catalogue ({exc})") from None
