"""Joint hardware cut in the same run as the strips: star washers, cable clamps and singularity joints.

Sizing rule (documented in docs/unrolling.md, Hardware parts), from the profile h x t and the pair spacing d:
- every arm is 2a wide with a = d/2 + 2t, so it covers both strips of a pair with their slot play;
- washer (kind "washer"): two per crossing node, above and below; one arm along each lamella pair at the
  node's design crossing angle, reaching d + h/4 from the bolt, with a square hole for the carriage bolt's neck;
- clamp (kind "clamp"): one per crossing node on every second diagonal (one colour of the grid's
  checkerboard); four arms along the diagonals reaching 15 mm past the washer, each with a cable hole in a tip
  that is bent up 90 degrees at a fold line (engraved) 1 mm past the washer, so the cable runs through it;
- joint (kind "joint"): two hexagonal star plates per singularity node when it gets a separate joint; six
  arms along the three lamellas, reaching h/2 past the pair ends, each with a bolt hole between the pair.
"""

from __future__ import annotations

import re
from functools import lru_cache
from typing import NamedTuple

import numpy as np
from shapely import affinity
from shapely.geometry import Polygon, box
from shapely.ops import unary_union

from fabline.mechanics.materials import Profile
from fabline.unroll.flat import circle
from fabline.unroll.options import TEXT_GAP
from fabline.unroll.parts import Part, Polylines
from fabline.unroll.strokes import characters, gather

CLAMP_EXTRA_REACH = 15.0
CABLE_HOLE = 6.5
FOLD_CLEARANCE = 1.0  # a clamp arm folds up this far past the washer it lies on
MIN_ID_HEIGHT = 1.5  # an id smaller than this is not engraved: the part has no room for it


def engraved_ids(texts: list[str], x_from: float, x_to: float, room: float, height: float,
                 angle_deg: np.ndarray | float = 0.0) -> list[Polylines]:
    """Each text engraved along one arm of a hardware part: centred across it, from x_from to at most x_to along the
    arm at `angle_deg` (per text, or one for all), cap height `height` shrunk to the arm's length and its width
    `room`; an empty Polylines where the text would be under MIN_ID_HEIGHT. All texts in one `gather`."""
    if not texts:
        return []
    chars = characters(texts)
    size = np.minimum(np.minimum(height, room), (x_to - x_from) / np.maximum(chars.widths, 1e-9))
    placed = size >= MIN_ID_HEIGHT
    owner = np.repeat(np.arange(len(texts)), chars.lengths)
    keep = placed[owner]
    glyph, advance, owner = chars.glyph[keep], chars.advance[keep], owner[keep]
    shift = np.column_stack([np.full(len(owner), x_from), -size[owner] / 2.0])
    block = gather(chars.table, glyph, size[owner], shift, advance)
    angle = np.radians(np.broadcast_to(np.asarray(angle_deg, dtype=float), (len(texts),)))
    point_owner = np.repeat(owner, block.point_counts)
    c, s = np.cos(angle[point_owner]), np.sin(angle[point_owner])
    x, y = block.points[:, 0].copy(), block.points[:, 1].copy()
    points = np.column_stack([c * x - s * y, s * x + c * y])
    stroke_owner = owner[block.stroke_owner]
    point_at = np.searchsorted(point_owner, np.arange(len(texts) + 1))
    stroke_at = np.searchsorted(stroke_owner, np.arange(len(texts) + 1))
    return [Polylines(points[point_at[k]:point_at[k + 1]], block.starts[stroke_at[k]:stroke_at[k + 1]] - point_at[k])
            for k in range(len(texts))]


def short_id(node: str) -> str:
    """A node id as engraved on hardware: without the N and the leading zeros of its numbers (N012-007 -> 12-7)."""
    return re.sub(r"(?<![0-9])0+(?=[0-9])", "", node[1:] if re.match(r"N[0-9]", node) else node)


def washer_ids(nodes: list[str], sizes: HardwareSizes, height: float) -> list[Polylines]:
    """The node's short id engraved on each node's washers, along the arm of its first lamella (angle 0)."""
    reach = sizes.bolt_square / np.sqrt(2.0) + TEXT_GAP
    return engraved_ids([short_id(n) for n in nodes], reach, sizes.washer_reach - TEXT_GAP,
                        2.0 * (sizes.half_width - TEXT_GAP), height)


def clamp_ids(nodes: list[str], crossing_deg: list[float], sizes: HardwareSizes, height: float) -> list[Polylines]:
    """The node's short id engraved on each clamp, along its first diagonal arm, between the bolt and its fold line."""
    angles = np.round(np.asarray(crossing_deg, dtype=float) * 2.0) / 2.0 / 2.0
    reach = sizes.bolt_square / np.sqrt(2.0) + TEXT_GAP
    end = sizes.washer_reach + FOLD_CLEARANCE - TEXT_GAP  # short of the fold line
    return engraved_ids([short_id(n) for n in nodes], reach, end, sizes.half_width - 2.0 * TEXT_GAP, height, angles)


class HardwareSizes(NamedTuple):
    """The dimensions every hardware part is drawn from (mm). A named tuple: it keys the shape caches of tens of
    thousands of parts, and a tuple hashes in C, three times faster than a frozen dataclass."""

    half_width: float
    washer_reach: float
    clamp_reach: float
    joint_setback: float
    joint_reach: float
    bolt_square: float
    bolt_hole: float

    @classmethod
    def of(cls, profile: Profile, pair_spacing: float, bolt_square: float) -> "HardwareSizes":
        half = pair_spacing / 2.0 + 2.0 * profile.t
        washer = pair_spacing + profile.h / 4.0
        setback = half / np.tan(np.pi / 6.0) + 2.0 * profile.t
        return cls(half, washer, washer + CLAMP_EXTRA_REACH, setback, setback + profile.h / 2.0,
                   bolt_square, bolt_square)


@lru_cache(maxsize=4096)
def _star(angles_deg: tuple[float, ...], half_width: float, reach: float) -> np.ndarray:
    """Outline of the union of bars through the origin, one per angle, 2 * half_width wide, reaching `reach` both ways.

    Cached: a job has few distinct (rounded) crossing angles but thousands of washers.
    """
    bar = box(-reach, -half_width, reach, half_width)
    contour = _contour(unary_union([affinity.rotate(bar, a, origin=(0, 0)) for a in angles_deg]))
    contour.flags.writeable = False
    return contour


def _contour(polygon: Polygon) -> np.ndarray:
    """The exterior as a closed counter-clockwise vertex list, rounded to 1e-4 mm."""
    ring = polygon.exterior
    coords = np.asarray(ring.coords)
    if not ring.is_ccw:
        coords = coords[::-1]
    return np.round(coords, 4)


@lru_cache(maxsize=4096)
def _square(side: float, angle_deg: float) -> np.ndarray:
    half = side / 2.0
    contour = _contour(affinity.rotate(box(-half, -half, half, half), angle_deg, origin=(0, 0)))
    contour.flags.writeable = False
    return contour


def washer_keys(angles: np.ndarray, bounds: list[int]) -> list[tuple[float, ...]]:
    """Per node (its arm angles in degrees from bounds[k] to bounds[k + 1]), the washer's arm angles: relative to the
    first lamella, rounded to half a degree (the washer's tolerance), distinct and sorted. Rounding for all at once."""
    owner = np.repeat(np.arange(len(bounds) - 1), np.diff(bounds))
    first = angles[np.asarray(bounds[:-1], dtype=int)]
    relative = (np.round((angles - first[owner]) % 180.0 * 2.0) / 2.0 % 180.0).tolist()
    return [tuple(sorted(set(relative[lo:hi]))) for lo, hi in zip(bounds[:-1], bounds[1:])]


def washers(node: str, angles: tuple[float, ...], sizes: HardwareSizes, text: Polylines | list = ()) -> list[Part]:
    """The two star washers (top, bottom) of a node: one arm pair along each lamella pair, at `angles` (`washer_keys`),
    with `text` (`washer_ids`) engraved."""
    outline, hole, label = _washer_shape(angles, sizes)
    # all fields by position, both parts written out: tens of thousands of washers, and keywords, defaults or a
    # comprehension's own call add a third to the cost of each
    return [Part(f"W-{node}-T", "washer", outline, None, [hole], [], [], text, [], label, False,
                 {"node": node, "arm_angles_deg": list(angles), "side": "T"}),
            Part(f"W-{node}-B", "washer", outline, None, [hole], [], [], text, [], label, False,
                 {"node": node, "arm_angles_deg": list(angles), "side": "B"})]


@lru_cache(maxsize=1024)
def _washer_shape(angles: tuple[float, ...], sizes: HardwareSizes) -> tuple[np.ndarray, np.ndarray, str]:
    """Outline, bolt hole and label of the washer for one set of (rounded) arm angles, shared by all such washers."""
    outline = _star(angles, sizes.half_width, sizes.washer_reach)
    hole = _square(sizes.bolt_square, angles[1] / 2.0 if len(angles) > 1 else 0.0)
    return outline, hole, "W " + "/".join(f"{a:g}" for a in angles[1:])


def clamp(node: str, crossing_deg: float, sizes: HardwareSizes, text: Polylines | list = ()) -> Part:
    """The cross-shaped cable clamp of a node: arms along the two diagonals, a cable hole near each arm end, `text`
    (`clamp_ids`) engraved, and a fold line across each arm where its tip is bent up (`clamp_folds`)."""
    angle = round(crossing_deg * 2.0) / 2.0
    outline, holes = _clamp_shape(angle, sizes)
    folds = clamp_folds(angle, sizes)
    return Part(f"C-{node}", "clamp", outline, None, list(holes), [], list(folds), text, [], f"C {angle:g}", False,
                {"node": node, "crossing_deg": angle,
                 "folds": [{"line": line.tolist(), "angle_deg": 90.0, "up": True} for line in folds]})


@lru_cache(maxsize=1024)
def clamp_folds(angle: float, sizes: HardwareSizes) -> tuple[np.ndarray, ...]:
    """Fold lines (engraved score lines) across the four clamp arms, FOLD_CLEARANCE past the washer's reach: each
    arm's tip is bent up 90 degrees, so its cable hole faces along the diagonal and the cable runs through it."""
    at = sizes.washer_reach + FOLD_CLEARANCE
    half = sizes.half_width / 2.0 - TEXT_GAP / 3.0
    lines = []
    for a in np.radians([angle / 2.0, angle / 2.0 + 90.0, angle / 2.0 + 180.0, angle / 2.0 + 270.0]):
        along, across = np.array([np.cos(a), np.sin(a)]), np.array([-np.sin(a), np.cos(a)])
        line = np.array([at * along - half * across, at * along + half * across])
        line.flags.writeable = False
        lines.append(line)
    return tuple(lines)


@lru_cache(maxsize=1024)
def _clamp_shape(angle: float, sizes: HardwareSizes) -> tuple[np.ndarray, tuple[np.ndarray, ...]]:
    """Outline and holes of the clamp for one (rounded) crossing angle, shared by all clamps of that angle."""
    diagonals = [angle / 2.0, angle / 2.0 + 90.0]
    outline = _star(tuple(diagonals), sizes.half_width / 2.0, sizes.clamp_reach)
    holes = [_square(sizes.bolt_square, angle / 2.0)]
    for a in np.radians(diagonals + [d + 180.0 for d in diagonals]):
        centre = (sizes.clamp_reach - CABLE_HOLE) * np.array([np.cos(a), np.sin(a)])
        hole = circle(centre, CABLE_HOLE / 2.0)
        hole.flags.writeable = False
        holes.append(hole)
    return outline, tuple(holes)


def singularity_joints(node: str, arm_angles_deg: list[float], sizes: HardwareSizes) -> list[Part]:
    """The two hexagonal star plates (top, bottom) of a singularity node, arms along its lamellas' tangents."""
    directions = [a % 180.0 for a in arm_angles_deg]
    outline = _star(tuple(directions), sizes.half_width, sizes.joint_reach)
    bolt_at = (sizes.joint_setback + sizes.joint_reach) / 2.0
    holes = [circle(bolt_at * np.array([np.cos(a), np.sin(a)]), sizes.bolt_hole / 2.0)
             for d in directions for a in np.radians([d, d + 180.0])]
    meta = {"node": node, "arm_angles_deg": [round(d, 2) for d in directions], "setback": round(sizes.joint_setback, 2)}
    return [Part(f"J-{node}-{side}", "joint", outline, holes=holes, label=f"J {node}", meta={**meta, "side": side})
            for side in ("T", "B")]


def checkerboard(nodes: list[str], neighbours: dict[str, list[str]]) -> set[str]:
    """Nodes of one colour of a two-colouring along the lamellas: in a quad grid, every second diagonal."""
    colour: dict[str, int] = {}
    for root in nodes:
        if root in colour:
            continue
        colour[root] = 0
        queue = [root]
        while queue:
            current = queue.pop()
            for other in neighbours.get(current, []):
                if other not in colour:
                    colour[other] = 1 - colour[current]
                    queue.append(other)
    return {n for n, c in colour.items() if c == 0}
