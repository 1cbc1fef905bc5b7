"""A seeded part set shaped like the Asymptotic Gridshell's cut list, for tests and benchmarks of nesting.

Until the unroll stage produces the real pavilion parts, this mimics them: about 1000 m of straight
100 mm strips in segments of 0.5-3.9 m with double slots open to alternate edges at every joint,
curved edge strips (arcs of radius 2-10 m with DXF bulges), star washers with a square 8.5 mm hole,
cross-shaped cable clamps and two hexagonal singularity joints. `scale` multiplies every count.
"""

from __future__ import annotations

import math

import numpy as np

from fabline.unroll.parts import Part, PartSet

STRIP_HEIGHT = 100.0
MAX_SEGMENT = 3900.0
MIN_SEGMENT = 500.0
SLOT_WIDTH = 3.0
SLOT_DEPTH = 52.0
SLOT_PAIR_SPACING = 25.0


def _square(cx: float, cy: float, side: float) -> np.ndarray:
    h = side / 2.0
    return np.array([[cx - h, cy - h], [cx + h, cy - h], [cx + h, cy + h], [cx - h, cy + h], [cx - h, cy - h]])


def straight_strip(pid: str, length: float, joints: list[float], first_edge_bottom: bool) -> Part:
    """A straight strip with a double slot open to the bottom or top edge at each joint position."""
    bottom, top = [(0.0, 0.0)], []
    for k, x in enumerate(joints):
        notch_x = [x - SLOT_PAIR_SPACING / 2 - SLOT_WIDTH / 2, x + SLOT_PAIR_SPACING / 2 - SLOT_WIDTH / 2]
        on_bottom = (k % 2 == 0) == first_edge_bottom
        for nx in notch_x:
            if on_bottom:
                bottom += [(nx, 0.0), (nx, SLOT_DEPTH), (nx + SLOT_WIDTH, SLOT_DEPTH), (nx + SLOT_WIDTH, 0.0)]
            else:
                top += [(nx, STRIP_HEIGHT), (nx, STRIP_HEIGHT - SLOT_DEPTH), (nx + SLOT_WIDTH, STRIP_HEIGHT - SLOT_DEPTH),
                        (nx + SLOT_WIDTH, STRIP_HEIGHT)]
    outline = bottom + [(length, 0.0), (length, STRIP_HEIGHT)] + top[::-1] + [(0.0, STRIP_HEIGHT), (0.0, 0.0)]
    return Part(pid, "strip", np.array(outline), label=pid, grain=True)


def curved_strip(pid: str, radius: float, length: float, width: float = STRIP_HEIGHT) -> Part:
    """An arc-shaped strip (edge lamella): outer and inner arcs as DXF bulges, radial ends, chord along x."""
    angle = length / radius
    bulge = math.tan(angle / 4.0)
    half = angle / 2.0
    inner = radius - width

    def at(r: float, a: float) -> tuple[float, float]:
        return (r * math.sin(a), r * math.cos(a) - inner * math.cos(half))

    p0, p1 = at(inner, -half), at(inner, half)
    p2, p3 = at(radius, half), at(radius, -half)
    # Inner arc from left to right runs clockwise about the centre below: negative bulge; outer back: positive.
    outline = np.array([[*p0, -bulge], [*p1, 0.0], [*p2, bulge], [*p3, 0.0], [*p0, 0.0]])
    return Part(pid, "curved-strip", outline, label=pid, grain=True)


def star_washer(pid: str, points: int = 8, outer: float = 35.0, inner: float = 24.0, hole: float = 8.5) -> Part:
    """A star washer with a square hole for the carriage bolt's neck."""
    angles = np.arange(2 * points) * math.pi / points
    radii = np.where(np.arange(2 * points) % 2 == 0, outer, inner)
    ring = np.column_stack([radii * np.cos(angles), radii * np.sin(angles)])
    return Part(pid, "washer", np.vstack([ring, ring[:1]]), holes=[_square(0.0, 0.0, hole)], label=pid)


def cross_clamp(pid: str, span: float = 90.0, arm: float = 30.0, hole: float = 8.5) -> Part:
    """A cross-shaped cable clamp with a central square hole."""
    a, h = arm / 2.0, span / 2.0
    outline = [(-a, -h), (a, -h), (a, -a), (h, -a), (h, a), (a, a), (a, h), (-a, h), (-a, a), (-h, a), (-h, -a),
               (-a, -a), (-a, -h)]
    return Part(pid, "clamp", np.array(outline), holes=[_square(0.0, 0.0, hole)], label=pid)


def hexagonal_joint(pid: str, across: float = 300.0, hole_radius: float = 70.0) -> Part:
    """A hexagonal singularity joint with a round central hole (four quarter-circle bulges)."""
    angles = np.arange(7) * math.pi / 3.0
    outline = np.column_stack([across / 2 * np.cos(angles), across / 2 * np.sin(angles)])
    quarter = math.tan(math.pi / 8.0)
    hole = np.array([[hole_radius, 0.0, quarter], [0.0, hole_radius, quarter], [-hole_radius, 0.0, quarter],
                     [0.0, -hole_radius, quarter], [hole_radius, 0.0, 0.0]])
    return Part(pid, "joint", outline, holes=[hole], label=pid)


def pavilion_like_parts(scale: int = 1, seed: int = 2017, strip_metres: float = 1000.0, curved: int = 12,
                        washers: int = 1400, clamps: int = 350, joints: int = 2) -> PartSet:
    """The synthetic pavilion cut list (`scale` times every count), deterministic for a given seed.

    The counts default to the pavilion's; tests pass smaller ones for quick instances of the same kind.
    """
    rng = np.random.default_rng(seed)
    parts: list[Part] = []
    total, target = 0.0, 1000.0 * strip_metres * scale
    lamella = 0
    while total < target:
        lamella += 1
        remaining = float(rng.uniform(2000.0, 16000.0))
        joint_spacing = float(rng.uniform(450.0, 800.0))
        segment = 0
        while remaining >= MIN_SEGMENT and total < target:
            segment += 1
            length = min(MAX_SEGMENT, remaining) if remaining - MAX_SEGMENT >= MIN_SEGMENT or remaining <= MAX_SEGMENT \
                else remaining - MIN_SEGMENT
            offset = float(rng.uniform(100.0, joint_spacing))
            joint_positions = list(np.arange(offset, length - 60.0, joint_spacing))
            pid = f"L{lamella:04d}-S{segment}"
            parts.append(straight_strip(pid, round(length, 1), joint_positions, bool(rng.integers(2))))
            total += length
            remaining -= length
    for k in range(curved * scale):
        parts.append(curved_strip(f"E{k + 1:03d}", float(rng.uniform(2000.0, 10000.0)),
                                  float(rng.uniform(2000.0, MAX_SEGMENT))))
    parts += [star_washer(f"W{k + 1:05d}") for k in range(washers * scale)]
    parts += [cross_clamp(f"C{k + 1:04d}") for k in range(clamps * scale)]
    parts += [hexagonal_joint(f"J{k + 1:02d}") for k in range(joints * scale)]
    return PartSet(parts, profile={"height": STRIP_HEIGHT, "thickness": 1.5}, material="stainless 1.4301 t=1.5",
                   source=f"synthetic pavilion-like cut list (scale {scale}, seed {seed})")
