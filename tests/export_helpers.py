"""Test helpers for the export tests: a small job with every part kind, and an independent G-code reader.

The reader uses gcodeparser (not fabline's writer nor the pygcode-based checker) and plain trigonometry
to turn a program back into tool-on polylines, so tests compare the output against truth computed
without the code under test.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import shapely

from fabline.export import samplejob
from fabline.nest.layout import Nesting, Placement, Sheet, place
from fabline.unroll.parts import PartSet, flatten_contour

import gcodeparser  # the test extra's independent G-code reader


def every_kind_partset() -> PartSet:
    """One part of every kind: straight strips (notches on either edge), curved strip, washer, clamp, joint."""
    return PartSet([samplejob.strip_part("A", 1200.0, "top", label=17), samplejob.strip_part("B", 900.0, "bottom", label=4),
                    samplejob.curved_strip_part("C"), samplejob.washer_part("W"), samplejob.clamp_part("K"),
                    samplejob.joint_part("J")], material="test")


def every_kind_nesting() -> Nesting:
    """The parts above placed on one 4 x 2 m sheet, some rotated."""
    sheet = Sheet("S1", 4000.0, 2000.0, [Placement("A", 20, 20), Placement("B", 920, 260, 180.0),
                                         Placement("C", 1500, 300, 30), Placement("W", 3000, 100, 15),
                                         Placement("K", 3100, 100), Placement("J", 3300, 600, 10)])
    return Nesting([sheet], "parts.json", kerf=0.2)


def placed_contours(nesting: Nesting, partset: PartSet) -> list[tuple[str, str, np.ndarray]]:
    """(part, role, placed contour with bulges) for every outer and inner cut contour of the nesting's first sheet."""
    parts = {p.id: p for p in partset.parts}
    out = []
    for placement in nesting.sheets[0].placements:
        part = parts[placement.part]
        out.append((part.id, "outer", place(_bulged(part.outline), placement)))
        inner = list(part.holes) + [s.outline for s in part.slots if s.edge is None]
        out.extend((part.id, "inner", place(_bulged(c), placement)) for c in inner)
    return out


def truth_ring(contour: np.ndarray, half_kerf: float, role: str) -> shapely.Polygon:
    """What a cut contour should be: shapely's mitre buffer of the nested contour, outwards for outer, inwards for inner."""
    polygon = shapely.Polygon(flatten_contour(contour, 0.0005))
    distance = half_kerf if role == "outer" else -half_kerf
    return polygon.buffer(distance, join_style="mitre", mitre_limit=5.0) if distance else polygon


def read_toolpaths(text: str) -> list[dict]:
    """Tool-on runs of a program: [{"points": (N, 2), "comment": the last `;` comment, "power": S}], arcs flattened."""
    runs, current, position, comment, motion = [], None, (0.0, 0.0), "", None
    power, tool = 0.0, False
    for line in gcodeparser.parse_gcode_lines(text, include_comments=True):
        letter, number = line.command
        if letter == ";":
            comment = line.comment
            continue
        params = {k: float(v) for k, v in line.params.items()}
        if letter == "M" and number in (3, 4):
            tool, power = True, params.get("S", power)
        elif letter == "M" and number == 5:
            tool = False
        if letter == "G" and number in (0, 1, 2, 3):
            motion = number
        if "S" in params:
            power = params["S"]
        if letter == "G" and number in (0, 1, 2, 3) and ("X" in params or "Y" in params):
            target = (params.get("X", position[0]), params.get("Y", position[1]))
            cutting = tool and motion != 0
            if cutting:
                if current is None:
                    current = {"points": [position], "comment": comment, "power": power}
                    runs.append(current)
                if motion in (2, 3):
                    current["points"].extend(_arc_points(position, target, params.get("I", 0.0), params.get("J", 0.0),
                                                         motion == 2))
                else:
                    current["points"].append(target)
            position = target
        if not (tool and motion != 0) or (letter == "G" and number == 0) or (letter == "M" and number == 5):
            current = None
    for run in runs:
        run["points"] = np.array(run["points"])
    return runs


def _arc_points(start, end, i, j, clockwise: bool, step: float = 0.0005) -> list[tuple[float, float]]:
    """Points along a G2/G3 arc every few degrees so the sagitta stays below `step` mm."""
    cx, cy = start[0] + i, start[1] + j
    radius = math.hypot(i, j)
    a0 = math.atan2(start[1] - cy, start[0] - cx)
    a1 = math.atan2(end[1] - cy, end[0] - cx)
    sweep = (a0 - a1) % (2 * math.pi) if clockwise else (a1 - a0) % (2 * math.pi)
    sweep = sweep or 2 * math.pi
    count = max(2, int(math.ceil(sweep / (2 * math.acos(max(-1.0, 1 - step / radius))))))
    sign = -1.0 if clockwise else 1.0
    points = [(cx + radius * math.cos(a0 + sign * sweep * k / count), cy + radius * math.sin(a0 + sign * sweep * k / count))
              for k in range(1, count)]
    return points + [tuple(end)]


def _bulged(contour: np.ndarray) -> np.ndarray:
    contour = np.asarray(contour, dtype=float)
    return contour if contour.shape[1] == 3 else np.column_stack([contour, np.zeros(len(contour))])
