"""The order the strips go into a segment: one family laid first, the other slotted across it, each from one side.

The family whose slots open from the top edge is laid first (its slots face up); the other family's slots open
from the bottom edge and are pushed down over them. Within a family the lamellas go in from one side of the
segment to the other: sorted by where their pieces lie across the family's mean direction in plan. One step per
lamella: its pieces built into this segment (both strips of a pair together).
"""

from __future__ import annotations

import numpy as np

from fabline.assembly.pieces import Piece


def family_order(pieces: list[Piece]) -> list[str]:
    """The families in laying order: slots opening from the top first, then by name."""
    families = sorted({piece.family for piece in pieces})
    return sorted(families, key=lambda f: (not any(p.slot_edge == "top" for p in pieces if p.family == f), f))


def steps(pieces: list[Piece], plan: dict[str, np.ndarray], families: list[str]) -> list[dict]:
    """The numbered steps of one segment's pieces: per family in `families` order, lamella by lamella across."""
    out = []
    for family in families:
        mine = [piece for piece in pieces if piece.family == family]
        if not mine:
            continue
        across = _across(mine, plan)
        by_lamella: dict[str, list[Piece]] = {}
        for piece in mine:
            by_lamella.setdefault(piece.lamella, []).append(piece)
        key = {lam: float(np.mean([across(p) for p in group])) for lam, group in by_lamella.items()}
        for lamella in sorted(by_lamella, key=lambda lam: (round(key[lam], 3), lam)):
            out.append({"step": len(out) + 1, "family": family, "lamella": lamella,
                        "pieces": [piece.id for piece in by_lamella[lamella]]})
    return out


def _across(pieces: list[Piece], plan: dict[str, np.ndarray]):
    """A piece's position across its family's mean plan direction (mm): its nodes' centre on the perpendicular."""
    total = np.zeros(2)
    for piece in pieces:
        ends = [plan[nid] for nid, _ in piece.nodes if nid in plan]
        if len(ends) >= 2:
            d = ends[-1] - ends[0]
            total += d if total @ d >= 0 else -d
    norm = np.linalg.norm(total)
    direction = total / norm if norm > 0 else np.array([1.0, 0.0])
    normal = np.array([-direction[1], direction[0]])

    def position(piece: Piece) -> float:
        points = [plan[nid] for nid, _ in piece.nodes if nid in plan]
        return float(np.mean(points, axis=0) @ normal) if points else 0.0

    return position
