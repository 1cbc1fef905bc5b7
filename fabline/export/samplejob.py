"""Synthetic parts of every kind and a pavilion-sized nested job, for tests and the export benchmark.

The pavilion job mimics the Asymptotic Gridshell's cutting list: about 700 lamella strips 0.5-3.9 m x
100 mm with a double slot notch pair every ~350 mm, screw holes at the splice ends, engraved node marks
and labels; 1400 star washers and 350 cross clamps; shelf-nested first-fit-decreasing on 4 x 2 m sheets
(the order a simple nester places parts in, which is the "plain" order the optimiser is measured against).
"""

from __future__ import annotations

import numpy as np

from fabline.nest.layout import Nesting, Placement, Sheet
from fabline.unroll.parts import Part, PartSet, Slot

STRIP_HEIGHT = 100.0
SLOT_WIDTH = 3.0            # twice the 1.5 mm lamella thickness
SLOT_PAIR_SPACING = 25.0    # two lamellas per direction, 25 mm apart
SLOT_DEPTH = 51.0           # h/2 plus clearance
HOLE_DIAMETER = 6.5         # splice screws
SQUARE_NECK = 8.5           # carriage bolt square neck

# seven-segment strokes for engraved digits, in a 6 x 10 mm cell
_SEGMENTS = {"a": [(0, 10), (6, 10)], "b": [(6, 10), (6, 5)], "c": [(6, 5), (6, 0)], "d": [(6, 0), (0, 0)],
             "e": [(0, 0), (0, 5)], "f": [(0, 5), (0, 10)], "g": [(0, 5), (6, 5)]}
_DIGITS = {"0": "abcdef", "1": "bc", "2": "abged", "3": "abgcd", "4": "fgbc", "5": "afgcd", "6": "afgedc",
           "7": "abc", "8": "abcdefg", "9": "abcfgd"}


def circle(cx: float, cy: float, radius: float) -> np.ndarray:
    """A closed circle as four quarter arcs (bulge tan(pi/8)), counter-clockwise, as the parts format wants 3+ vertices."""
    bulge = np.tan(np.pi / 8)
    return np.array([[cx + radius, cy, bulge], [cx, cy + radius, bulge], [cx - radius, cy, bulge],
                     [cx, cy - radius, bulge], [cx + radius, cy, 0.0]])


def digits_text(number: int, x: float, y: float) -> list[np.ndarray]:
    """Engrave strokes for the decimal digits of `number`, lower-left corner at (x, y)."""
    strokes = []
    for k, ch in enumerate(str(number)):
        for seg in _DIGITS[ch]:
            strokes.append(np.array(_SEGMENTS[seg], dtype=float) + [x + 9.0 * k, y])
    return strokes


def strip_part(pid: str, length: float, edge: str = "top", node_spacing: float = 350.0, label: int = 0) -> Part:
    """A straight lamella with a double edge-notch slot pair every `node_spacing`, splice holes, node marks, label."""
    h, w = STRIP_HEIGHT, SLOT_WIDTH
    centres = np.arange(node_spacing / 2, length - node_spacing / 4, node_spacing)
    slots_x = sorted(x for c in centres for x in (c - SLOT_PAIR_SPACING / 2, c + SLOT_PAIR_SPACING / 2))
    notch_y0 = h - SLOT_DEPTH if edge == "top" else SLOT_DEPTH
    edge_y = h if edge == "top" else 0.0
    bottom, top = [(0.0, 0.0)], [(length, h)]
    notches = [[(x - w / 2, edge_y), (x - w / 2, notch_y0), (x + w / 2, notch_y0), (x + w / 2, edge_y)] for x in slots_x]
    if edge == "top":       # counter-clockwise: bottom edge left to right, top edge right to left
        outline = [(0.0, 0.0), (length, 0.0), (length, h)]
        for notch in reversed(notches):
            outline += notch[::-1]
        outline += [(0.0, h), (0.0, 0.0)]
    else:
        outline = list(bottom)
        for notch in notches:
            outline += notch
        outline += [(length, 0.0)] + top + [(0.0, h), (0.0, 0.0)]
    slots = [Slot(f"{pid}-n{k // 2}", np.array(n + [n[0]]), edge) for k, n in enumerate(notches)]
    holes = [circle(x, y, HOLE_DIAMETER / 2) for x in (20.0, 45.0, length - 45.0, length - 20.0) for y in (25.0, 75.0)]
    mark_y = (5.0, 20.0) if edge == "top" else (80.0, 95.0)
    marks = [np.array([[c, mark_y[0]], [c, mark_y[1]]]) for c in centres]
    text = digits_text(label, 60.0, 45.0 if edge == "top" else 30.0)
    return Part(pid, "strip", np.array(outline), lamella=pid, holes=holes, slots=slots, marks=marks, text=text,
                label=str(label), grain=True)


def curved_strip_part(pid: str, radius: float = 1500.0, angle_deg: float = 40.0) -> Part:
    """An edge lamella cut curved in plane: an annular sector 100 mm wide with arcs as bulges, two holes."""
    a = np.radians(angle_deg)
    b = np.tan(a / 4)
    r0, r1 = radius, radius + STRIP_HEIGHT
    outline = np.array([[r0, 0, 0], [r1, 0, b], [r1 * np.cos(a), r1 * np.sin(a), 0],
                        [r0 * np.cos(a), r0 * np.sin(a), -b], [r0, 0, 0]])
    mid = (r0 + r1) / 2
    holes = [circle(mid * np.cos(t), mid * np.sin(t), HOLE_DIAMETER / 2) for t in (0.05, a - 0.05)]
    marks = [np.array([[(r0 + 5) * np.cos(a / 2), (r0 + 5) * np.sin(a / 2)],
                       [(r0 + 20) * np.cos(a / 2), (r0 + 20) * np.sin(a / 2)]])]
    return Part(pid, "curved-strip", outline, lamella=pid, holes=holes, marks=marks)


def washer_part(pid: str, arms: int = 4, outer: float = 30.0, inner: float = 14.0) -> Part:
    """A star-shaped washer with a square hole for the carriage bolt's neck."""
    angles = np.arange(2 * arms) * np.pi / arms
    radii = np.where(np.arange(2 * arms) % 2 == 0, outer, inner)
    star = np.column_stack([radii * np.cos(angles), radii * np.sin(angles)]) + outer
    s = SQUARE_NECK / 2
    square = np.array([[-s, -s], [s, -s], [s, s], [-s, s], [-s, -s]]) + outer
    return Part(pid, "washer", np.vstack([star, star[:1]]), holes=[square])


def clamp_part(pid: str, size: float = 90.0, arm: float = 30.0) -> Part:
    """A cross-shaped cable clamp: a plus outline with a bolt hole and one cable hole per arm."""
    a, b = (size - arm) / 2, (size + arm) / 2
    outline = np.array([[a, 0], [b, 0], [b, a], [size, a], [size, b], [b, b], [b, size], [a, size], [a, b],
                        [0, b], [0, a], [a, a], [a, 0]], dtype=float)
    c = size / 2
    holes = [circle(c, c, 4.25)] + [circle(x, y, 2.5) for x, y in ((c, 8), (size - 8, c), (c, size - 8), (8, c))]
    return Part(pid, "clamp", outline, holes=holes)


def joint_part(pid: str, radius: float = 150.0, width: float = 40.0) -> Part:
    """The singularity joint: a regular six-armed star (hexagonal), closed slots along the arms, a central hole."""
    outline, slots = [], []
    for k in range(6):
        t = np.radians(60 * k)
        direction, side = np.array([np.cos(t), np.sin(t)]), np.array([-np.sin(t), np.cos(t)])
        half = width / 2
        root = half / np.tan(np.radians(30))
        outline += [tuple(root * direction - half * side), tuple(radius * direction - half * side),
                    tuple(radius * direction + half * side)]
        p = [radius * 0.55 * direction - SLOT_WIDTH / 2 * side, radius * 0.85 * direction - SLOT_WIDTH / 2 * side,
             radius * 0.85 * direction + SLOT_WIDTH / 2 * side, radius * 0.55 * direction + SLOT_WIDTH / 2 * side]
        slots.append(Slot(f"{pid}-s{k}", np.array(p + [p[0]]), None))
    outline = np.array(outline + [outline[0]]) + radius
    for slot in slots:
        slot.outline = slot.outline + radius
    return Part(pid, "joint", outline, holes=[circle(radius, radius, 8.5)], slots=slots)


def pavilion_job(seed: int = 1, strips: int = 700, washers: int = 1400, clamps: int = 350,
                 sheet_size: tuple[float, float] = (4000.0, 2000.0), margin: float = 10.0,
                 gap: float = 6.0) -> tuple[Nesting, PartSet]:
    """A pavilion-sized cutting job shelf-nested first-fit-decreasing; returns the nesting and its parts."""
    rng = np.random.default_rng(seed)
    parts: list[Part] = []
    lengths = 500.0 + 3400.0 * rng.random(strips) ** 1.6
    for k, length in enumerate(lengths):
        parts.append(strip_part(f"L{k:04d}", float(round(length)), "top" if k % 2 == 0 else "bottom", label=k))
    parts += [clamp_part(f"C{k:04d}") for k in range(clamps)]
    parts += [washer_part(f"W{k:04d}") for k in range(washers)]
    widths = {p.id: float(np.ptp(p.outline[:, 0])) for p in parts}
    order = sorted(parts, key=lambda p: -widths[p.id])
    width, height = sheet_size
    row_pitch = STRIP_HEIGHT + gap
    rows_per_sheet = int((height - 2 * margin + gap) // row_pitch)
    rows: list[list[float]] = []          # [sheet index, row index, x used]
    sheets: list[Sheet] = []
    for part in order:
        w = widths[part.id]
        row = next((r for r in rows if r[2] + w <= width - margin), None)
        if row is None:
            count = len(rows)
            sheet_index, row_index = divmod(count, rows_per_sheet)
            if sheet_index == len(sheets):
                sheets.append(Sheet(f"S{sheet_index + 1:02d}", width, height, stock="1.5 mm stainless 4000 x 2000"))
            row = [sheet_index, row_index, margin]
            rows.append(row)
        sheets[int(row[0])].placements.append(Placement(part.id, row[2], margin + row[1] * row_pitch))
        row[2] += w + gap
    nesting = Nesting(sheets, "parts.json", kerf=0.2, gap=gap, margin=margin)
    return nesting, PartSet(parts, material="1.4301 stainless 1.5 mm", source="fabline.export.samplejob")
