"""Where a part's id goes on a sheet picture: inside the part's material, clear of its holes, as large as fits.

The label is a straight line of text in a box `label_length(text)` long and one em high. Candidates are the
part's widest point (`shapely.maximum_inscribed_circle`) and a grid of points inside it, each with the direction
of the outline nearest to it: along a strip or a curved edge bar that is the tangent of its centre line, on a
washer the arm it lies on. The candidate whose box stays inside the material at the largest size wins.
"""

from __future__ import annotations

from functools import lru_cache
from typing import NamedTuple

import numpy as np
import shapely
from shapely.geometry import Polygon

GRID = 9                 # candidate points per side of the part's bounding box
SIZES = 14               # label sizes tried, from the largest allowed down by SHRINK each
SHRINK = 0.8
EM_HEIGHT = 1.0          # the box's height in ems (capitals and digits with room above and below)
# advance widths in ems, generous for the common sans-serif faces (DejaVu Sans: W 0.99, M 0.86, digits 0.64)
_WIDE = {"W": 1.0, "M": 0.9, "m": 0.98, "w": 0.82}
_NARROW = {"-": 0.4, ".": 0.34, " ": 0.34, "/": 0.36, "I": 0.32, "i": 0.3, "l": 0.3, "j": 0.3, "J": 0.32}


class Spot(NamedTuple):
    """A label's centre (x, y) and unit direction (dx, dy) in the part's frame, and its font size (mm)."""

    x: float
    y: float
    dx: float
    dy: float
    size: float


def label_length(text: str, size: float) -> float:
    """The length of `text` set at font size `size`, an upper bound for the usual sans-serif faces."""
    return size * sum(_WIDE.get(c, _NARROW.get(c, 0.62 if c.islower() else 0.8)) for c in text)


def label_spot(outline: np.ndarray, holes: tuple[np.ndarray, ...], text: str, largest: float) -> Spot | None:
    """The best place for `text` on the part with closed `outline` and `holes` ((N, 2) arrays, part frame, mm),
    at most `largest` mm high; None when the part has no material at all."""
    key = (outline.tobytes(), outline.shape, tuple((h.tobytes(), h.shape) for h in holes),
           round(label_length(text, 1.0), 3), round(largest, 3))
    return _spot(key)


@lru_cache(maxsize=4096)
def _spot(key: tuple) -> Spot | None:
    """`label_spot` by its key (the shape's bytes and the label's length): thousands of washers share a shape."""
    outline = np.frombuffer(key[0]).reshape(key[1])
    holes = [np.frombuffer(data).reshape(shape) for data, shape in key[2]]
    ems, largest = key[3], key[4]
    solid = Polygon(outline[:, :2], [h[:, :2] for h in holes]).buffer(0)
    if solid.is_empty or solid.area <= 0:
        return None
    if solid.geom_type == "MultiPolygon":
        solid = max(solid.geoms, key=lambda g: g.area)
    centres, directions = _candidates(solid)
    shapely.prepare(solid)
    for size in largest * SHRINK ** np.arange(SIZES):
        boxes = _boxes(centres, directions, ems * size, EM_HEIGHT * size)
        inside = shapely.contains(solid, boxes)
        if inside.any():
            k = int(np.argmax(inside))
            return Spot(float(centres[k, 0]), float(centres[k, 1]), float(directions[k, 0]), float(directions[k, 1]),
                        float(size))
    k = 0  # nothing fits even at the smallest size: the widest point, along the outline, smallest
    return Spot(float(centres[k, 0]), float(centres[k, 1]), float(directions[k, 0]), float(directions[k, 1]),
                float(largest * SHRINK ** (SIZES - 1)))


def _candidates(solid: Polygon) -> tuple[np.ndarray, np.ndarray]:
    """Candidate centres (the widest point first, then a grid inside the material) and the unit direction of the
    outline nearest to each."""
    widest = shapely.get_coordinates(shapely.maximum_inscribed_circle(solid, tolerance=solid.length * 5e-3))[0]
    x0, y0, x1, y1 = solid.bounds
    gx, gy = np.meshgrid(np.linspace(x0, x1, GRID + 2)[1:-1], np.linspace(y0, y1, GRID + 2)[1:-1])
    grid = np.column_stack([gx.ravel(), gy.ravel()])
    grid = grid[shapely.contains_xy(solid, grid[:, 0], grid[:, 1])]
    centres = np.vstack([widest[None, :], grid])
    ring = solid.exterior
    at = shapely.line_locate_point(ring, shapely.points(centres))
    step = max(ring.length * 1e-3, 1e-6)
    ahead = shapely.get_coordinates(shapely.line_interpolate_point(ring, np.minimum(at + step, ring.length)))
    behind = shapely.get_coordinates(shapely.line_interpolate_point(ring, np.maximum(at - step, 0.0)))
    direction = ahead - behind
    length = np.linalg.norm(direction, axis=1, keepdims=True)
    direction = np.where(length > 0, direction / np.maximum(length, 1e-12), [[1.0, 0.0]])
    return centres, direction


def _boxes(centres: np.ndarray, directions: np.ndarray, length: float, height: float) -> np.ndarray:
    """The label boxes (shapely polygons), `length` along each direction and `height` across, on each centre."""
    along = directions * (length / 2.0)
    across = np.column_stack([-directions[:, 1], directions[:, 0]]) * (height / 2.0)
    corners = np.stack([centres - along - across, centres + along - across, centres + along + across,
                        centres - along + across, centres - along - across], axis=1)
    return shapely.polygons(corners)
