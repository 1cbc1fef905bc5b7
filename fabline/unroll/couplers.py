"""Shear couplings between the two strips of a lamella pair near the supports (thesis 6.2.1, 6.2.4).

The pair is coupled at every joint; near the supports, where self-weight raises the normal force, the thesis adds
shear blocks between the joints (its 25 mm square tubes proved too narrow for enough screws and were replaced by
wider timber blocks). fabline's coupler: a hardwood block filling the pair's gap (d - t thick), COUPLER_LENGTH long
and h/2 high, midway between two nodes, bolted through both strips by two bolts COUPLER_PITCH apart, in the strips'
slotted half (at h/4 from the centre line: clear of the slots, which sit at the nodes, and of the label and node ids
in the free half). The strips get the bolt holes (cut with them); the blocks are sawn, not cut from the sheets.
`couplers` intervals from each support node along its lamellas are coupled; an interval holding a seam is skipped.
"""

from __future__ import annotations

import numpy as np

from fabline.model.network import Network
from fabline.unroll.flat import circle
from fabline.unroll.parts import Part

COUPLER_LENGTH = 120.0  # along the strips
COUPLER_PITCH = 60.0    # between its two bolts


def coupler_intervals(network: Network, count: int) -> list[tuple[str, str, str]]:
    """(lamella, node, next node) of the first `count` node intervals from every support node at a lamella's end."""
    out = []
    for lam in network.lamellas:
        for nodes in (lam.nodes, lam.nodes[::-1]):
            if network.nodes[nodes[0]].kind == "support":
                out.extend((lam.id, *sorted((a, b), key=lam.nodes.index))
                           for a, b in list(zip(nodes[:-1], nodes[1:]))[:count])
    return sorted(set(out))


def add_couplers(parts: list[Part], network: Network, count: int, bolt_hole: float, profile_h: float,
                 pair_spacing: float, profile_t: float) -> tuple[list[dict], list[list[str]]]:
    """Drill the coupler bolt holes into both strips of each coupled interval (the strip parts get them in place);
    return one record per coupler (lamella, nodes, the strip parts and the holes' x in each part's frame, block
    size) and the intervals skipped (lamella, node, node: a seam in them, or too short for a block)."""
    if count <= 0 or pair_spacing <= 0:
        return [], []
    by_lamella: dict[str, list[Part]] = {}
    for part in parts:
        if part.kind in ("strip", "curved-strip") and part.lamella and part.meta.get("member") != "edge":
            by_lamella.setdefault(part.lamella, []).append(part)
    records, skipped = [], []
    for lamella, a, b in coupler_intervals(network, count):
        placed = []
        for side in ("L", "R"):
            strip = [p for p in by_lamella.get(lamella, []) if p.meta.get("side") == side]
            holding = [p for p in strip if {n["id"] for n in p.nodes} & {a, b}]
            if len(holding) != 1 or {n["id"] for n in holding[0].nodes} < {a, b}:
                break  # a seam in the interval (or a node on two segments): no block there
            part = holding[0]
            s = {n["id"]: float(n["s"]) for n in part.nodes}
            middle = (s[a] + s[b]) / 2.0
            if abs(s[b] - s[a]) < COUPLER_LENGTH + bolt_hole:
                break
            edge = next((slot.edge for slot in part.slots if slot.edge), "top")
            y = profile_h / 4.0 if edge == "top" else -profile_h / 4.0
            xs = [middle - COUPLER_PITCH / 2.0, middle + COUPLER_PITCH / 2.0]
            placed.append((part, xs, y))
        if len(placed) != 2:
            skipped.append([lamella, a, b])
            continue
        for part, xs, y in placed:
            part.holes = list(part.holes) + [circle(np.array([x, y]), bolt_hole / 2.0) for x in xs]
        records.append({"id": f"SB-{lamella}-{a}-{b}", "lamella": lamella, "nodes": [a, b],
                        "parts": [p.id for p, _, _ in placed],
                        "holes_x_mm": [[round(x, 2) for x in xs] for _, xs, _ in placed],
                        "hole_y_mm": [round(y, 2) for _, _, y in placed],
                        "block_mm": [COUPLER_LENGTH, profile_h / 2.0, round(pair_spacing - profile_t, 2)],
                        "bolts": 2, "bolt_hole_mm": bolt_hole})
    return records, skipped
