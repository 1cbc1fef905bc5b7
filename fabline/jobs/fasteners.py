"""Every bolt and screw the parts call for, with its size and length from the stack-up it passes through.

The stack-ups (docs/unrolling.md, "Fasteners"), h x t the profile, every hardware plate cut from the strips' sheet
(thickness t):
- crossing node: a carriage bolt on the node's axis along the normal, its square neck in the top star washer's
  square hole, through the top washer, past the lamellas' height h, through the bottom washer, one nut: grip
  h + 2t, plus t where the node has a cable clamp (it lies on the top washer, under the bolt head);
- singularity joint: a hex bolt through each bolt hole of the top plate, between the pair, through the bottom
  plate: grip h + 2t;
- seam: a button head screw through the two overlapping strips, a washer and a nut: grip 2t;
- edge bolt: a hex bolt through the edge bars at each bar hole and a spacer tube filling the gap between the top and
  bottom bars (which lie on top of the washers' layer); where the bar hole is a node with washers, the node's carriage
  bolt is the edge bolt, longer (one bolt per axis), and washers and lamella fill the gap (`edge_fasteners`);
- lamella end: a hex bolt through the end-fix holes of the pair's two strips and the square tube cleat between them,
  which the edge bars clamp (`end_fix_fasteners`).
Sizes come from the parts' own holes (`fabline.mechanics.hardware`: the largest size whose clearance fits).
"""

from __future__ import annotations

from collections import Counter
from typing import Any

import numpy as np
import shapely

from fabline.mechanics.hardware import Bolt, Catalogue
from fabline.unroll.parts import Part, flatten_contour


def hole_across(hole: np.ndarray) -> float:
    """A round hole's diameter, or a square hole's side (its area's square root), mm."""
    ring = flatten_contour(np.asarray(hole))[:, :2]
    area = shapely.Polygon(ring).area
    diameter = float(np.ptp(ring[:, 0]))
    return diameter if abs(area - np.pi * diameter ** 2 / 4.0) < 0.05 * area else float(np.sqrt(area))


def bolt_row(item: str, bolt: Bolt, count: int, per: str) -> dict[str, Any]:
    return {"item": f"{item} {bolt.name}", "kind": "fastener", "size": bolt.size.name, "length_mm": bolt.length,
            "count": count, "unit_mass_kg": round(bolt.mass_g / 1000.0, 5),
            "total_mass_kg": round(bolt.mass_g * count / 1000.0, 3), "per": per, "grip_mm": round(bolt.grip, 2)}


def _grouped(item: str, what: str, bolts: list[tuple[Bolt, int, str]]) -> list[dict[str, Any]]:
    """One row per bolt size and length from (bolt, count, its stack-up) entries; `per` says each stack-up's count."""
    groups: dict[str, list[tuple[Bolt, int, str]]] = {}
    for entry in bolts:
        groups.setdefault(entry[0].name, []).append(entry)
    return [bolt_row(item, entries[0][0], sum(c for _, c, _ in entries),
                 what + "; ".join(f"{c} {stack}" for _, c, stack in entries)) for entries in groups.values()]


def fastener_rows(parts: list[Part], h: float, t: float, screw_hole_mm: float | None, catalogue: Catalogue,
                  fins: dict[str, float] | None = None) -> list[dict[str, Any]]:
    """BOM rows (item, kind, size, length_mm, count, masses, per, grip) of the node bolts, joint bolts and seam screws,
    one per size and length. `fins`: support nodes and their fin plate's thickness, which a node bolt there also
    passes where the node has no edge bolt."""
    washers = [p for p in parts if p.kind == "washer" and p.meta.get("side") == "T"]
    clamped = {p.meta.get("node") for p in parts if p.kind == "clamp"}
    rows = []
    if washers:
        square = hole_across(washers[0].holes[0])
        edge_nodes = {node["id"] for p in parts if p.meta.get("member") == "edge" for node in p.nodes}
        fin = {n: v for n, v in (fins or {}).items() if n not in edge_nodes}
        counts = Counter((p.meta.get("node") in clamped, fin.get(p.meta.get("node"), 0.0)) for p in washers
                         if p.meta.get("node") not in edge_nodes)  # there the edge bolt is the node's bolt
        rows.extend(_grouped("carriage bolt with nut", "crossing node: ", [
            (catalogue.bolt("carriage", square, h + 2.0 * t + (t if with_clamp else 0.0) + plate, square=True), count,
             "through washer, h, washer" + (", clamp" if with_clamp else "") + (f", {plate:g} mm support fin" if plate else ""))
            for (with_clamp, plate), count in sorted(counts.items())]))
    joints = [p for p in parts if p.kind == "joint" and p.meta.get("side") == "T"]
    if joints:
        bolt = catalogue.bolt("hex", hole_across(joints[0].holes[0]), h + 2.0 * t)
        rows.append(bolt_row("hex bolt with nut", bolt, sum(len(p.holes) for p in joints),
                         f"bolt hole of a singularity joint ({len(joints)} joints): plate, h, plate"))
    strips = [p for p in parts if p.kind in ("strip", "curved-strip")]  # edge bars have seams too
    holes = [hole_across(hole) for p in strips for hole in p.holes]
    screws = [d for d in holes if screw_hole_mm is None or abs(d - screw_hole_mm) < 0.05]
    if screws:
        bolt = catalogue.bolt("button", screws[0], 2.0 * t, washers=1)
        rows.append(bolt_row("button head screw with washer and nut", bolt, len(screws) // 2,
                         "seam screw: 6 per seam, through the two overlapping strips or edge bars"))
    return rows


def edge_fasteners(parts: list[Part], h: float, t: float, catalogue: Catalogue,
                   fins: dict[str, float] | None = None) -> list[dict[str, Any]]:
    """The edge members' bolts and spacer tubes: per bar hole a hex bolt through every edge bar listing it, the gap
    between the top and bottom bars (the bars' offsets less their thickness) and, at a support node, the support's fin
    (`fins`: its thickness); a spacer tube fills the gap except at a node with washers. Grouped by bolt length."""
    bars = [p for p in parts if p.meta.get("member") == "edge"]
    if not bars:
        return []
    offsets = [float(p.meta["offset_mm"]) for p in bars]
    gap = max(offsets) - min(offsets) - t
    washer_nodes = {p.meta.get("node") for p in parts if p.kind == "washer"}
    layers = Counter(node["id"] for p in bars for node in p.nodes)
    fins = fins or {}
    stacks = Counter((count, fins.get(node, 0.0), node in washer_nodes) for node, count in layers.items())
    hole = max(hole_across(hole) for p in bars for hole in p.holes)  # the bolt holes (the seams' screw holes are smaller)
    rows = _grouped("edge bolt with nut", "edge bar hole: ", [
        (catalogue.bolt("hex", hole, gap + count * t + plate), nodes,
         f"through {count} bars and " + ("the node's washers and lamellas (its carriage bolt)" if washers else
                                         "the spacer tube") + (f" and a {plate:g} mm support fin" if plate else ""))
        for (count, plate, washers), nodes in sorted(stacks.items())])
    tubes = sum(1 for node in layers if node not in washer_nodes)
    if tubes:
        size = catalogue.size_for_hole(hole)
        outer, wall = size.d + 4.0, 1.5  # a 1.5 mm wall tube the bolt passes (bore d + 1 mm)
        tube_g = np.pi / 4.0 * (outer ** 2 - (outer - 2 * wall) ** 2) * gap * catalogue.density * 1e-6
        rows.append({"item": f"spacer tube {outer:g} x {wall:g} for {size.name}", "kind": "fastener",
                     "size": f"{outer:g}x{wall:g}", "length_mm": round(gap, 2), "count": tubes,
                     "unit_mass_kg": round(tube_g / 1000.0, 5), "total_mass_kg": round(tube_g * tubes / 1000.0, 3),
                     "per": "edge bar hole: between the top and bottom edge bars", "grip_mm": None})
    return rows


def end_fix_count(parts: list[Part]) -> int:
    """The lamella ends fixed to the edge: per lamella its end-fix holes on one strip of the pair (a bolt passes both)."""
    holes: Counter = Counter()
    for p in parts:
        if p.meta.get("end_fixes"):
            holes[(p.lamella, p.meta.get("side"))] += p.meta["end_fixes"]
    per_lamella: dict[str, int] = {}
    for (lamella, _), count in holes.items():
        per_lamella[lamella] = max(per_lamella.get(lamella, 0), count)
    return sum(per_lamella.values())


def end_fix_fasteners(parts: list[Part], h: float, t: float, catalogue: Catalogue) -> list[dict[str, Any]]:
    """Per lamella end a hex bolt through its end-fix holes and a square tube cleat between the pair's strips (side:
    their gap), as tall as the gap between the edge bars that clamp it (h where there are none)."""
    ends = end_fix_count(parts)
    if not ends:
        return []
    fixed = [p for p in parts if p.meta.get("end_fixes")]
    offsets = [float(p.meta.get("offset_mm") or 0.0) for p in fixed]
    spacing = max(offsets) - min(offsets)
    hole = min(hole_across(hole) for p in fixed for hole in p.holes[-p.meta["end_fixes"]:])
    bars = [float(p.meta["offset_mm"]) for p in parts if p.meta.get("member") == "edge"]
    tall = max(bars) - min(bars) - t if bars else h
    bolt = catalogue.bolt("hex", hole, spacing + t)
    rows = [bolt_row("end-fix hex bolt with nut", bolt, ends, "lamella end: through strip, cleat, strip")]
    if spacing > t:
        side, wall = spacing - t, 1.5
        cleat_g = (side ** 2 - (side - 2 * wall) ** 2) * tall * catalogue.density * 1e-6
        rows.append({"item": f"square tube cleat {side:g} x {wall:g}", "kind": "fastener", "size": f"{side:g}x{wall:g}",
                     "length_mm": round(tall, 2), "count": ends, "unit_mass_kg": round(cleat_g / 1000.0, 5),
                     "total_mass_kg": round(cleat_g * ends / 1000.0, 3),
                     "per": "lamella end: between the pair's strips, clamped by the edge bars", "grip_mm": None})
    return rows
