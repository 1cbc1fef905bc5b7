"""Part geometry for nesting: each part's flattened outline as shapely polygons, checked once up front.

Nesting works on the flattened outline (arcs split finely); the holes are kept so small parts may go
into large enough holes when the user allows it. Identical parts share a key so they are nested as a
group (one pattern, many copies) instead of one by one.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np
import shapely
from shapely.geometry import Polygon
from shapely.validation import explain_validity

from fabline.errors import FablineError
from fabline.unroll.parts import Part, flatten_contour

# Flattening tolerance for arcs (mm): far below any gap a laser leaves, and finer than the validator's own
# flattening, so a chord never hides more of an arc than the validator's tolerance allows.
ARC_TOLERANCE = 0.005


@dataclass
class NestShape:
    """One part as the nester sees it: its polygon (with holes) in the part frame and what it may do."""

    part: Part
    polygon: Polygon
    solid: Polygon
    key: str
    strip_like: bool

    @property
    def id(self) -> str:
        """The part id."""
        return self.part.id

    @property
    def area(self) -> float:
        """Net area (outline minus holes), mm²."""
        return float(self.polygon.area)

    def rotations(self, steps: int) -> list[float]:
        """Allowed rotations in degrees: `steps` equal steps of a full turn, only 0/180 for grain-bound parts."""
        angles = [round(360.0 * k / steps, 6) for k in range(steps)]
        return [a for a in angles if a in (0.0, 180.0)] if self.part.grain else angles


def part_polygon(part: Part) -> Polygon:
    """The part's outline with its holes as a valid shapely polygon; a bad outline is a FablineError naming the part."""
    outline = flatten_contour(part.outline, ARC_TOLERANCE)
    holes = [flatten_contour(h, ARC_TOLERANCE) for h in part.holes]
    shell = Polygon(outline)
    if not shell.is_valid:
        raise FablineError(f"part {part.id}: outline is self-intersecting or degenerate ({explain_validity(shell)})")
    if shell.area <= 0:
        raise FablineError(f"part {part.id}: outline has no area")
    for k, hole in enumerate(holes):
        ring = Polygon(hole)
        if not ring.is_valid:
            raise FablineError(f"part {part.id}: holes[{k}] is self-intersecting ({explain_validity(ring)})")
        if not shell.contains(ring):
            raise FablineError(f"part {part.id}: holes[{k}] is not inside the outline")
    polygon = Polygon(outline, holes)
    if not polygon.is_valid:
        raise FablineError(f"part {part.id}: holes overlap each other ({explain_validity(polygon)})")
    return polygon


def shape_key(part: Part) -> str:
    """A key equal for parts with the same geometry and grain rule, so identical parts are nested as one group."""
    digest = hashlib.sha1()
    digest.update(b"g" if part.grain else b"-")
    for contour in [part.outline, *part.holes]:
        digest.update(np.round(np.asarray(contour, dtype=float), 3).tobytes())
        digest.update(b"|")
    return digest.hexdigest()


def is_strip_like(polygon: Polygon, kind: str) -> bool:
    """A strip, straight or bent in plane so little that its outline is its bounding rectangle apart from small
    notches and the bend: it nests in rows, by that rectangle."""
    if kind not in ("strip", "curved-strip"):
        return False
    box = shapely.envelope(polygon.exterior)
    if box.area <= 0 or Polygon(polygon.exterior).area / box.area < 0.9:
        return False
    if kind == "curved-strip":  # its long edges are arcs inside the box: the area alone says how much a row wastes
        return True
    xmin, ymin, xmax, ymax = box.bounds
    long_edges = [shapely.LineString([(xmin, ymin), (xmax, ymin)]), shapely.LineString([(xmin, ymax), (xmax, ymax)])]
    return all(polygon.exterior.intersection(edge).length >= 0.5 * edge.length for edge in long_edges)


def nest_shapes(parts: list[Part]) -> list[NestShape]:
    """Polygons, identity keys and strip classification for every part, checking each outline.

    Identical parts (same key) share one polygon, so a thousand washers cost one geometry check.
    """
    shapes = []
    known: dict[tuple[str, str], tuple[Polygon, Polygon, bool]] = {}
    for part in parts:
        key = shape_key(part)
        if (key, part.kind) not in known:
            polygon = part_polygon(part)
            known[key, part.kind] = (polygon, Polygon(polygon.exterior), is_strip_like(polygon, part.kind))
        polygon, solid, strip_like = known[key, part.kind]
        shapes.append(NestShape(part, polygon, solid, key, strip_like))
    return shapes
