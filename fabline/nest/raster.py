"""Raster irregular nesting: free positions of a part on a sheet from a correlation of occupancy grids.

The sheet's usable area becomes a grid of cells; every part placed so far is rasterised
conservatively (any cell its clearance zone touches is occupied), and so is the part to place.
Correlating the two grids (FFT, only over the windows where the part could fit at all) gives every
collision-free position at once. Many copies of an identical part are first laid on the densest
lattice found on the part's discrete no-fit polygon with itself, at the offset that fits most copies
into the free space; the rest are placed greedily bottom-left, each placement striking out the
positions it blocks for the next copy, so no pair of polygons is ever tested.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
import shapely
from scipy.signal import fftconvolve
from shapely import affinity
from shapely.geometry import Polygon

# Safety factor on the obstacle buffer: a cell touched by a shape has its centre within res/sqrt(2)
# of it; one full cell covers that and any rounding in the polygon filler.
OBSTACLE_BUFFER_CELLS = 1.0


@dataclass(frozen=True)
class Template:
    """A part at one rotation rasterised at one resolution: the mask of its clearance zone and its offset."""

    rotation: float
    mask: np.ndarray
    origin: tuple[float, float]

    @property
    def shape(self) -> tuple[int, int]:
        """Mask size in cells (rows, columns)."""
        return self.mask.shape


def make_template(solid: Polygon, rotation: float, res: float, half_clearance: float) -> Template:
    """Mask of the cells touched by the part (rotated about its origin) grown by half the clearance."""
    zone = affinity.rotate(solid, rotation, origin=(0.0, 0.0)).buffer(half_clearance, quad_segs=8)
    minx, miny, maxx, maxy = zone.bounds
    cols = max(1, math.ceil((maxx - minx) / res - 1e-9))
    rows = max(1, math.ceil((maxy - miny) / res - 1e-9))
    grown = zone.buffer(res * math.sqrt(0.5) + 1e-6, quad_segs=4)
    shapely.prepare(grown)
    cx = minx + (np.arange(cols) + 0.5) * res
    cy = miny + (np.arange(rows) + 0.5) * res
    gx, gy = np.meshgrid(cx, cy)
    mask = shapely.contains_xy(grown, gx, gy)
    return Template(rotation, mask, (minx, miny))


def blocked_offsets(placed: Template, other: Template) -> np.ndarray:
    """Offsets q - p where `other` at q hits `placed` at p: index (u, v) is offset (u - rows(other) + 1, v - cols(other) + 1)."""
    return fftconvolve(placed.mask.astype(np.float32), other.mask[::-1, ::-1].astype(np.float32), mode="full") > 0.5


class Canvas:
    """The occupancy grid of one sheet's usable area at one resolution."""

    def __init__(self, width: float, height: float, margin: float, res: float):
        self.res = res
        self.x0 = self.y0 = margin
        self.cols = max(0, int(math.floor((width - 2 * margin) / res + 1e-9)))
        self.rows = max(0, int(math.floor((height - 2 * margin) / res + 1e-9)))
        self.grid = np.zeros((self.rows, self.cols), dtype=np.uint8)
        self.holes = np.zeros((self.rows, self.cols), dtype=np.uint8)

    def _fill(self, target: np.ndarray, rings: list, value: int = 1) -> None:
        """Fill closed rings (sheet mm) into a grid, cell centres inside, with sub-cell precision."""
        shift = 4
        scale = (1 << shift) / self.res
        contours = [np.round((np.asarray(r.coords)[:, :2] - (self.x0 + 0.5 * self.res, self.y0 + 0.5 * self.res))
                             * scale).astype(np.int32) for r in rings]
        cv2.fillPoly(target, contours, value, lineType=cv2.LINE_8, shift=shift)

    def mark_holes(self, polygon: Polygon) -> None:
        """Remember the holes of a placed part (sheet mm): small parts are tried there first."""
        for ring in polygon.interiors:
            self._fill(self.holes, [ring])

    def hole_positions(self, template: Template) -> np.ndarray:
        """Mask-corner cells that put the template's centre cell inside a remembered hole."""
        rows, cols = template.shape
        out = np.zeros((self.rows, self.cols), dtype=bool)
        centre = self.holes[rows // 2:, cols // 2:].astype(bool)
        out[:centre.shape[0], :centre.shape[1]] = centre
        return out

    @property
    def occupied(self) -> np.ndarray:
        """Boolean occupancy (rows = y, columns = x)."""
        return self.grid.astype(bool)

    def block_rectangle(self, xmin: float, ymin: float, xmax: float, ymax: float) -> None:
        """Mark every cell that touches an axis-aligned rectangle (sheet mm)."""
        j0 = max(0, int(math.floor((xmin - self.x0) / self.res)))
        j1 = min(self.cols, int(math.ceil((xmax - self.x0) / self.res)))
        i0 = max(0, int(math.floor((ymin - self.y0) / self.res)))
        i1 = min(self.rows, int(math.ceil((ymax - self.y0) / self.res)))
        if j1 > j0 and i1 > i0:
            self.grid[i0:i1, j0:j1] = 1

    def block_polygon(self, polygon: Polygon, half_clearance: float) -> None:
        """Mark every cell touched by the polygon (sheet mm, holes kept free) grown by half the clearance."""
        zone = polygon.buffer(half_clearance + OBSTACLE_BUFFER_CELLS * self.res, quad_segs=8)
        if zone.is_empty:
            return
        for part in getattr(zone, "geoms", [zone]):
            self._fill(self.grid, [part.exterior, *part.interiors])

    def stamp(self, template: Template, i: int, j: int) -> None:
        """Mark the cells of a template placed with its mask corner at cell (i, j)."""
        rows, cols = template.shape
        self.grid[i:i + rows, j:j + cols] |= template.mask.astype(np.uint8)

    def translation(self, template: Template, i: int, j: int) -> tuple[float, float]:
        """The placement (x, y) that puts the template's mask corner on cell (i, j)."""
        return (self.x0 + j * self.res - template.origin[0], self.y0 + i * self.res - template.origin[1])

    def free_positions(self, template: Template) -> np.ndarray:
        """Boolean grid of mask-corner cells where the template fits without touching anything."""
        rows, cols = template.shape
        out = np.zeros((self.rows, self.cols), dtype=bool)
        span_i, span_j = self.rows - rows + 1, self.cols - cols + 1
        if span_i <= 0 or span_j <= 0:
            return out
        # Cheap necessary condition from an integral image: few enough occupied cells under the mask's box.
        integral = cv2.integral(self.grid, sdepth=cv2.CV_32S)
        under = (integral[rows:rows + span_i, cols:cols + span_j] - integral[:span_i, cols:cols + span_j]
                 - integral[rows:rows + span_i, :span_j] + integral[:span_i, :span_j])
        candidates = under <= rows * cols - int(template.mask.sum())
        kernel = template.mask[::-1, ::-1].astype(np.float32)
        for top, bottom in _runs(candidates.any(axis=1)):
            for left, right in _runs(candidates[top:bottom].any(axis=0)):
                window = self.grid[top:bottom + rows - 1, left:right + cols - 1].astype(np.float32)
                hits = fftconvolve(window, kernel, mode="valid") if window.any() else 0.0
                out[top:bottom, left:right] = (hits < 0.5) & candidates[top:bottom, left:right]
        return out


def _runs(flags: np.ndarray) -> list[tuple[int, int]]:
    """Half-open index ranges of the runs of True in a 1-D boolean array."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], flags.astype(np.int8), [0]])))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist()))


@dataclass(frozen=True)
class Lattice:
    """A repeating pattern of one template: copies at every integer combination of two cell vectors (di, dj)."""

    template: Template
    a: tuple[int, int]
    b: tuple[int, int]

    @property
    def cell_area(self) -> int:
        """Cells per copy: the area of the lattice's fundamental parallelogram."""
        return abs(self.a[0] * self.b[1] - self.a[1] * self.b[0])


def densest_lattice(template: Template, reach: int = 3) -> Lattice | None:
    """The lattice of least cell area whose copies of `template` never overlap (raster no-fit polygon with itself).

    Candidate basis vectors are the free offsets next to the blocked region (the shortest free vector in
    every direction); a pair is kept when every combination m a + n b, |m|, |n| <= `reach`, is free.
    """
    blocked = blocked_offsets(template, template)
    rows, cols = template.shape
    centre = np.array([rows - 1, cols - 1])
    padded = np.pad(blocked, 1)
    near = (padded[:-2, 1:-1] | padded[2:, 1:-1] | padded[1:-1, :-2] | padded[1:-1, 2:]) & ~blocked
    di, dj = np.nonzero(near)
    vectors = np.column_stack([di, dj]) - centre
    vectors = vectors[(vectors[:, 0] > 0) | ((vectors[:, 0] == 0) & (vectors[:, 1] > 0))]
    if len(vectors) < 2:
        return None
    a, b = vectors[:, None, :], vectors[None, :, :]
    det = np.abs(a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0])
    order = np.argsort(det, axis=None)
    order = order[det.reshape(-1)[order] > 0]
    steps = np.array([(m, n) for m in range(-reach, reach + 1) for n in range(-reach, reach + 1) if (m, n) != (0, 0)])

    def free(points: np.ndarray) -> np.ndarray:
        index = points + centre
        inside = (index[..., 0] >= 0) & (index[..., 0] < blocked.shape[0]) & (index[..., 1] >= 0) & (index[..., 1] < blocked.shape[1])
        hit = np.zeros(points.shape[:-1], dtype=bool)
        hit[inside] = blocked[index[inside][:, 0], index[inside][:, 1]]
        return ~hit

    for start in range(0, len(order), 2048):
        chunk = order[start:start + 2048]
        first, second = np.unravel_index(chunk, det.shape)
        points = steps[None, :, 0, None] * vectors[first][:, None, :] + steps[None, :, 1, None] * vectors[second][:, None, :]
        for k in np.flatnonzero(free(points).all(axis=1)):
            a, b = vectors[first[k]], vectors[second[k]]
            if free(_lattice_points_within(a, b, blocked.shape)).all():
                return Lattice(template, (int(a[0]), int(a[1])), (int(b[0]), int(b[1])))
    return None


def _lattice_points_within(a: np.ndarray, b: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Every nonzero lattice vector m a + n b inside the box of half-size `shape` (the no-fit raster's reach)."""
    corners = np.array([[r, c] for r in (-shape[0], shape[0]) for c in (-shape[1], shape[1])], dtype=float)
    coefficients = corners @ np.linalg.inv(np.array([a, b], dtype=float).T).T
    low, high = np.floor(coefficients.min(axis=0)).astype(int), np.ceil(coefficients.max(axis=0)).astype(int)
    m, n = np.meshgrid(np.arange(low[0], high[0] + 1), np.arange(low[1], high[1] + 1), indexing="ij")
    keep = (m != 0) | (n != 0)
    return m[keep][:, None] * a + n[keep][:, None] * b


def lattice_spots(free: np.ndarray, lattice: Lattice) -> np.ndarray:
    """Cells (i, j) of the lattice coset with the most free positions, bottom row first."""
    i, j = np.nonzero(free)
    if len(i) == 0:
        return np.zeros((0, 2), dtype=int)
    i, j = i.astype(np.int64), j.astype(np.int64)
    (a0, a1), (b0, b1), det = lattice.a, lattice.b, lattice.cell_area
    # A cell's coordinates in the basis (a, b), times the determinant, are the integers below (the adjugate);
    # two cells are in the same coset exactly when both agree modulo the determinant.
    coset = ((b1 * i - b0 * j) % det) * det + (a0 * j - a1 * i) % det
    keep = coset == np.bincount(coset).argmax()
    return np.column_stack([i[keep], j[keep]])


def place_copies(canvas: Canvas, templates: list[Template], count: int,
                 lattice: Lattice | None = None) -> list[tuple[Template, int, int]]:
    """Place up to `count` copies: first on the best-fitting repeat of `lattice` (when given), then bottom-left
    first in any rotation; each copy blocks the positions it overlaps for the next."""
    placed: list[tuple[Template, int, int]] = []
    if canvas.holes.any():
        placed = _greedy_copies(canvas, templates, count, in_holes=True)
        count -= len(placed)
    if lattice is not None:
        for i, j in lattice_spots(canvas.free_positions(lattice.template), lattice)[:count]:
            placed.append((lattice.template, int(i), int(j)))
            canvas.stamp(lattice.template, int(i), int(j))
        count -= len(placed)
    return placed + _greedy_copies(canvas, templates, count)


def _greedy_copies(canvas: Canvas, templates: list[Template], count: int,
                   in_holes: bool = False) -> list[tuple[Template, int, int]]:
    """Bottom-left greedy placement of up to `count` copies over all templates (only inside holes if asked)."""
    if count <= 0:
        return []
    free = [canvas.free_positions(t) & canvas.hole_positions(t) if in_holes else canvas.free_positions(t)
            for t in templates]
    flat = [f.reshape(-1) for f in free]
    pointer = [0] * len(templates)
    blocked = {(a, b): blocked_offsets(templates[a], templates[b])
               for a in range(len(templates)) for b in range(len(templates))}
    placed = []
    while len(placed) < count:
        best, best_index = -1, None
        for k, f in enumerate(flat):
            if pointer[k] >= f.size:
                continue
            step = int(np.argmax(f[pointer[k]:]))
            pointer[k] += step
            if f[pointer[k]] and (best_index is None or pointer[k] < best_index):
                best, best_index = k, pointer[k]
            elif not f[pointer[k]]:
                pointer[k] = f.size
        if best_index is None:
            break
        chosen = templates[best]
        i, j = divmod(best_index, canvas.cols)
        placed.append((chosen, i, j))
        canvas.stamp(chosen, i, j)
        for k, (other, positions) in enumerate(zip(templates, free)):
            hit = blocked[best, k]
            orows, ocols = other.shape
            top, left = i - orows + 1, j - ocols + 1
            u0, v0 = max(0, -top), max(0, -left)
            u1 = min(hit.shape[0], canvas.rows - top)
            v1 = min(hit.shape[1], canvas.cols - left)
            if u1 > u0 and v1 > v0:
                positions[top + u0:top + u1, left + v0:left + v1] &= ~hit[u0:u1, v0:v1]
    return placed
