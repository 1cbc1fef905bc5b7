"""Long curved parts (edge bars) stacked one above the other, each as low as its true outline allows.

A raster fill places a curved bar by its cells one at a time and leaves wide gaps between bars that
curve alike; translated copies of a smooth arc nest inside each other at a pitch little more than the
bar's width. Each bar is moved up from just above the sheet's strip rows until its outline keeps the
clearance from the parts already there (shapely, then bisection), in the rotations its grain allows.
"""

from __future__ import annotations

from shapely import affinity
from shapely.geometry import Polygon
from shapely.ops import unary_union
from shapely.prepared import prep

SCAN_STEP = 20.0     # mm: the coarse step the drop takes before bisection
BISECTION_TOL = 0.1  # mm: how close to the lowest clear position a bar is laid
# The clearance zone is a buffer whose round corners are chords inside the true circle; this much more keeps
# a part outside the zone at least the clearance away (a chord's sag at 16 segments a quarter is 0.12 % of it).
BUFFER_MARGIN = 0.02


class StackSheet:
    """One sheet's free space for stacking: above the top of its strip rows, clear of its other parts' zones."""

    def __init__(self, width: float, height: float, margin: float, clearance: float, rows_top: float | None):
        self.width, self.height, self.margin, self.clearance = width, height, margin, clearance
        # below the top of the rows nothing is free (they fill their sheet's width), so a drop starts above them
        self.floor = margin if rows_top is None else max(margin, rows_top + clearance)
        self.polygons: list[Polygon] = []
        self._zone = None

    def add(self, polygon: Polygon) -> None:
        """A part laid on the sheet (in sheet coordinates): later drops keep the clearance from it."""
        self.polygons.append(polygon)
        self._zone = None

    def _clear(self, polygon: Polygon) -> bool:
        if not self.polygons:
            return True
        if self._zone is None:
            zone = unary_union(self.polygons).buffer(self.clearance + BUFFER_MARGIN, quad_segs=16)
            self._zone = prep(zone)
        return not self._zone.intersects(polygon)

    def lowest_drop(self, moving: Polygon, x: float, y_from: float, y_max: float) -> float | None:
        """The lowest y in [y_from, y_max] (at SCAN_STEP, refined by bisection) where `moving` translated by (x, y)
        is clear of the parts' zones; None where none is up to y_max. Scanning from below keeps the answer a clear
        position even where the clear set is not one interval."""
        def clear(y: float) -> bool:
            return self._clear(affinity.translate(moving, x, y))

        y = y_from
        if clear(y):
            return y
        while y < y_max:
            low, high = y, min(y + SCAN_STEP, y_max)
            if clear(high):
                while high - low > BISECTION_TOL:
                    middle = (low + high) / 2.0
                    low, high = (low, middle) if clear(middle) else (middle, high)
                return high
            y = high
        return None

    def place(self, moving: Polygon, rotations: list[float]) -> tuple[float, float, float] | None:
        """Where `moving` (in its own coordinates) goes: (x, y, rotation) of the lowest clear position, at the left
        margin, centred or at the right margin, over `rotations`; None if it fits nowhere above the rows."""
        best = None
        for rotation in rotations:
            turned = affinity.rotate(moving, rotation, origin=(0, 0))
            minx, miny, maxx, maxy = turned.bounds
            room = self.width - 2 * self.margin - (maxx - minx)
            y_from, y_max = self.floor - miny, self.height - self.margin - maxy
            if room < -1e-9 or y_from > y_max + 1e-9:
                continue
            for x in dict.fromkeys((self.margin - minx, self.margin + room / 2 - minx, self.margin + room - minx)):
                y = self.lowest_drop(turned, x, y_from, y_max)
                if y is not None and (best is None or y + maxy < best[1] + best[3]):
                    best = (x, y, rotation, maxy)
        return None if best is None else best[:3]
