"""Support brackets at the network's support nodes, cut from plate (6 mm by default, the thesis's, 6.2.4).

The thesis's supports were "fabricated individually following the incline and curvature of the grid": brackets
taking up the variable incline, welded onto a base plate. fabline's bracket per support node (node kind `support`:
the built-in designs' lamella ends in the lowest tenth of the height, an import's `--supports`):
- a fin (`SP-<node>-F`) lying in the node's tangent plane under the shell, on the node's bolt (the edge bolt, or the
  node bolt without edge members) below the bottom bar, so the bolt along the normal passes it square; it runs
  down the slope to a footing `support_height` below the bolt (vertically), where its lower edge is horizontal;
- a base plate (`SP-<node>-B`), horizontal on the footing, the fin welded on it along the engraved weld line at the
  tangent plane's incline (meta.fin_angle_deg), with four anchor holes for M12 bolts into the footing.
Both are flat parts of kind `support`; they are cut from plate of another thickness than the strips, so they are
kept apart from the strips' parts (`PartSet.plates`) and nested and drawn on plate sheets of their own.
"""

from __future__ import annotations

import numpy as np

from fabline.errors import FablineError
from fabline.model.network import Network
from fabline.unroll.flat import circle
from fabline.unroll.hardware import engraved_ids
from fabline.unroll.parts import Part, Polylines

FIN_TOP = 30.0           # fin above its bolt hole's centre (mm): a 2.5 d edge distance for M8 and more
ANCHOR_HOLE = 13.0       # M12 anchor bolts (ISO 273 fine clearance)
ANCHOR_EDGE = 30.0       # anchor hole centres from the base plate's edges
BASE_MARGIN = 60.0       # base plate beyond the fin on either side
BASE_DEPTH = 200.0       # base plate across the weld line
MIN_INCLINE_DEG = 15.0   # a tangent plane flatter than this would make a fin over 3.9 times the support height


def _rectangle(x0: float, y0: float, x1: float, y1: float) -> np.ndarray:
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]], dtype=float)


def _engraved(text: str, width: float, y: float, height: float) -> Polylines | list:
    """`text` engraved centred across a plate `width` wide, its middle at height y."""
    lines = engraved_ids([text], -width / 2.0 + 5.0, width / 2.0 - 5.0, height, height)[0]
    return Polylines(lines.points + np.array([0.0, y]), lines.starts) if len(lines) else []


def support_parts(network: Network, bolt_hole: float, profile_h: float, profile_t: float, thickness: float,
                  height: float, text_height: float) -> list[Part]:
    """Fin and base plate of every support node of `network` (mm), in node order; none without support nodes."""
    mm = network.in_mm()
    width = 1.2 * profile_h
    parts = []
    for nid, node in sorted(mm.nodes.items()):
        if node.kind != "support":
            continue
        n = np.asarray(node.normal, dtype=float)
        n = n if n[2] >= 0 else -n  # the fin lies below the shell: on the side the normal points away from
        incline = float(np.degrees(np.arccos(min(1.0, abs(n[2])))))
        if incline < MIN_INCLINE_DEG:
            longest = height / np.sin(np.radians(MIN_INCLINE_DEG))
            raise FablineError(f"support node {nid}: the surface is only {incline:.1f} degrees off level there (a fin "
                               f"in its tangent plane needs {MIN_INCLINE_DEG:g}, where reaching a footing {height:g} mm "
                               f"lower takes {longest:.0f} mm); leave supports off or support the shell where it is steeper")
        down = np.array([0.0, 0.0, -1.0]) + n[2] * n
        down /= np.linalg.norm(down)
        across = np.cross(n, down)
        length = height / np.sin(np.radians(incline))
        bolt_at = node.xyz - n * (profile_h / 2.0 + profile_t + thickness / 2.0)
        foot = bolt_at + length * down
        fin = Part(f"SP-{nid}-F", "support", _rectangle(-width / 2.0, -length, width / 2.0, FIN_TOP),
                   holes=[circle(np.zeros(2), bolt_hole / 2.0)],
                   text=_engraved(f"SP {nid} F", width, -length / 2.0, text_height),
                   label=f"SP-{nid}-F", meta={"node": nid, "plate": "fin", "fin_angle_deg": round(float(incline), 2),
                                               "length_mm": round(float(length + FIN_TOP), 1),
                                               "bolt_xyz_mm": np.round(bolt_at, 1).tolist()})
        base_w = width + 2.0 * BASE_MARGIN
        anchors = [circle(np.array([sx * (base_w / 2.0 - ANCHOR_EDGE), sy * (BASE_DEPTH / 2.0 - ANCHOR_EDGE)]),
                          ANCHOR_HOLE / 2.0) for sx in (-1, 1) for sy in (-1, 1)]
        weld = np.array([[-width / 2.0, 0.0], [width / 2.0, 0.0]])
        base = Part(f"SP-{nid}-B", "support", _rectangle(-base_w / 2.0, -BASE_DEPTH / 2.0, base_w / 2.0, BASE_DEPTH / 2.0),
                    holes=anchors, marks=[weld],
                    text=_engraved(f"SP {nid} B", width, -BASE_DEPTH / 4.0, text_height),
                    label=f"SP-{nid}-B",
                    meta={"node": nid, "plate": "base", "fin_angle_deg": round(float(incline), 2),
                          "weld_line": weld.tolist(), "footing_xyz_mm": np.round(foot, 1).tolist(),
                          "fin_across": np.round(across, 4).tolist()})
        parts.extend([fin, base])
    return parts
