"""The settings of an unroll run: profile, material, joint and seam dimensions, and what to make.

Every length in millimetres. Derived sizes (slot width 2 t, slot depth h/2 + clearance, end length h/2)
follow domain.md section 5 unless given explicitly.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

from fabline.errors import FablineError
from fabline.geometry.offsets import PAIR_SPACING_MM
from fabline.mechanics.materials import Material, Profile, get_material

SINGULARITY_MODES = ("joint", "slots")
TEXT_GAP = 1.5  # mm between a mark and its text, and between text and an edge


def _default_material() -> Material:
    return get_material("steel-s235")


@dataclass
class UnrollOptions:
    """How to unroll a network: see docs/unrolling.md for what each setting does and its default's origin."""

    profile: Profile = field(default_factory=lambda: Profile(100.0, 1.5))
    material: Material = field(default_factory=_default_material)
    pair_spacing: float = PAIR_SPACING_MM  # d: centre distance of a pair's two strips; 0 makes single lamellas
    slot_clearance: float = 1.0         # slot depth = h/2 + this
    slot_width: float | None = None     # default 2 t: lets the joint rotate during assembly
    min_web: float | None = None        # least material between two slots; default the slot width
    overlap: float = 150.0              # length of a seam's overlap
    min_overlap: float | None = None    # where no seam fits, overlaps shorten down to this; default 2/3 of overlap
    screw_hole: float = 5.5             # diameter of the six seam screw holes
    sheet_length: float = 4000.0
    sheet_margin: float = 10.0          # usable strip length = sheet_length - 2 * sheet_margin
    end_length: float | None = None     # strip beyond its outermost slot or node; default h/2
    compensate_twist: bool = False      # lengthen node distances by the helix contraction of the centre fibre
    singularity: str = "joint"          # valence-6 nodes: separate hexagonal "joint" or "slots" for three pairs
    hardware: bool = True               # washers, clamps and singularity joints as parts too
    bolt_square: float = 8.5            # carriage bolt neck, square hole in washers and clamps
    text_height: float = 6.0            # cap height of engraved node ids and labels
    min_crossing_angle: float = 30.0    # the slotted joint rotates up to 60 degrees from square
    straight_tolerance: float = 0.01    # a strip within this of straight is cut as a rectangle
    strict: bool = False                # structural warnings become errors
    edge_members: bool = False          # the boundary curves as flat curved bars, top and bottom (unroll.edges)
    edge_width: float | None = None     # width of an edge member's bar; default the lamella height h
    cable_pretension: float = 1.0       # cables are cut this much short per metre (mm/m), so tensioning fits them
    cable_end_allowance: float = 80.0   # cable beyond each end clamp's centre: its outer hole and the end stop
    supports: bool = False              # brackets (fin and base plate) at the support nodes, cut from plate
    support_plate: float = 6.0          # their plate thickness (the thesis's 6 mm)
    support_material: str = "steel-s235"  # their plate material (a materials file name)
    support_height: float = 150.0       # from a support's bolt down to its footing, vertically
    couplers: int = 0                   # shear blocks in this many node intervals from each support (0: none)

    @property
    def slot(self) -> float:
        """Slot width (mm)."""
        return self.slot_width if self.slot_width is not None else 2.0 * self.profile.t

    @property
    def slot_depth(self) -> float:
        """Slot depth from its edge, round end included (mm)."""
        return self.profile.h / 2.0 + self.slot_clearance

    @property
    def web(self) -> float:
        """Least material between two neighbouring slots (mm)."""
        return self.min_web if self.min_web is not None else self.slot

    @property
    def shortest_overlap(self) -> float:
        """The shortest seam overlap allowed where the full one fits nowhere (mm)."""
        return self.min_overlap if self.min_overlap is not None else 2.0 * self.overlap / 3.0

    @property
    def end(self) -> float:
        """Strip length beyond the outermost slot or node (mm)."""
        return self.end_length if self.end_length is not None else self.profile.h / 2.0

    @property
    def free_height(self) -> float:
        """Height of the strip's unslotted half, from its free edge to the slot ends (mm)."""
        return self.profile.h - self.slot_depth

    @property
    def engrave_height(self) -> float:
        """Cap height of engraved text: `text_height`, shrunk so node ids and a label fit in the free half."""
        return max(0.5, min(self.text_height, (self.free_height - 3.0 * TEXT_GAP) / 2.5))

    @property
    def usable_length(self) -> float:
        """Longest strip segment a sheet holds (mm): the nester's rule (`fabline.shop.stock.usable_extent`)."""
        from fabline.shop.stock import usable_extent

        return usable_extent(self.sheet_length, self.sheet_margin)

    def check(self, name: Callable[[str], str] = lambda key: "--" + key.replace("_", "-")) -> "UnrollOptions":
        """Raise a FablineError naming, as `name(field)` gives it, the first setting that cannot work (the command
        line's option by default; a job file names its own keys, which are these fields' names)."""
        positive = ("overlap", "screw_hole", "sheet_length", "text_height", "bolt_square", "slot_width", "end_length",
                    "straight_tolerance", "edge_width", "cable_end_allowance", "support_plate", "support_height")
        for key in positive:
            value = {"slot_width": self.slot, "end_length": self.end,
                     "edge_width": self.profile.h if self.edge_width is None else self.edge_width}.get(key, getattr(self, key))
            if not 0 < value < math.inf:
                raise FablineError(f"{name(key)}: must be positive, got {value:g}")
        for key in ("pair_spacing", "slot_clearance", "sheet_margin", "min_web"):
            value = self.web if key == "min_web" else getattr(self, key)
            if not 0 <= value < math.inf:
                raise FablineError(f"{name(key)}: must not be negative, got {value:g}")
        if 0 < self.pair_spacing <= self.profile.t + self.slot:
            raise FablineError(f"{name('pair_spacing')}: {self.pair_spacing:g} mm leaves no room between two "
                               f"{self.profile.t:g} mm strips with {self.slot:g} mm slots (use 0 for single lamellas)")
        if self.slot_depth >= self.profile.h:
            raise FablineError(f"{name('slot_clearance')}: slot depth {self.slot_depth:g} mm (h/2 + clearance) cuts "
                               f"through the {self.profile.h:g} mm strip")
        if self.usable_length <= 2.0 * self.overlap:
            raise FablineError(f"{name('overlap')}: usable sheet length {self.usable_length:g} mm is not longer than "
                               f"two overlaps of {self.overlap:g} mm")
        if not 0 < self.shortest_overlap <= self.overlap:
            raise FablineError(f"{name('min_overlap')}: must be positive and at most the overlap "
                               f"{self.overlap:g} mm, got {self.shortest_overlap:g}")
        largest_hole = min(self.profile.h / 4.0, self.shortest_overlap / 6.0)  # half a hole of material around each
        if self.screw_hole > largest_hole:
            raise FablineError(f"{name('screw_hole')}: {self.screw_hole:g} mm does not fit a seam of the "
                               f"{self.profile.h:g} mm strip with a {self.shortest_overlap:g} mm overlap "
                               f"(at most min(h/4, min overlap/6) = {largest_hole:g} mm)")
        if not 0 <= self.couplers <= 1000:
            raise FablineError(f"{name('couplers')}: {self.couplers} node intervals from each support: use 0 (none) "
                               "to 1000")
        if not 0 <= self.cable_pretension < 100:
            raise FablineError(f"{name('cable_pretension')}: {self.cable_pretension:g} mm/m must be at least 0 and "
                               "under 100 mm/m (10 %)")
        if self.singularity not in SINGULARITY_MODES:
            raise FablineError(f"{name('singularity')}: {self.singularity!r}: use one of {', '.join(SINGULARITY_MODES)}")
        if not 0 < self.min_crossing_angle <= 90:
            raise FablineError(f"{name('min_crossing_angle')}: {self.min_crossing_angle:g} must lie in (0, 90] degrees")
        return self
