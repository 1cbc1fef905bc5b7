"""The assembly plan of a network and its unrolled parts: segments, the pieces in each, their order, site joints."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fabline.assembly.order import family_order, steps
from fabline.assembly.pieces import Piece, lamella_pieces, place, site_joints
from fabline.assembly.segments import extent, node_graph, partition
from fabline.errors import FablineError
from fabline.model.network import Network
from fabline.unroll.parts import PartSet


@dataclass
class AssemblyPlan:
    """Everything the sheets and the report show; `segments[k]` is segment k + 1's node ids."""

    network: Network
    segments: list[list[str]]
    segment_of: dict[str, int]
    pieces: list[Piece]
    steps: dict[int, list[dict]]
    crossings: list[dict]
    seams: list[dict]
    families: list[str]
    plan: dict[str, np.ndarray]     # node id -> plan position x, y (mm)
    at: dict[str, list[str]]        # node id -> the lamellas through it (the network's)
    rule: str

    def crossing_lamellas(self, node: str, lamella: str) -> list[str]:
        """The other lamellas through a node (the network's, not the parts')."""
        return [lam for lam in self.at[node] if lam != lamella]

    def step_of(self, piece: str) -> tuple[int, int] | None:
        """(segment, step) in which a piece goes in."""
        for segment, listed in self.steps.items():
            for step in listed:
                if piece in step["pieces"]:
                    return segment, step["step"]
        return None

    def summary(self) -> dict:
        """The plan as plain data (the report's `assembly` section and the CLI's JSON)."""
        rows = []
        graph = node_graph(self.network)
        k_mm = self.network.mm_per_unit
        space = {n: np.asarray(node.xyz, dtype=float) * k_mm for n, node in self.network.nodes.items()}
        for k, nodes in enumerate(self.segments, start=1):
            xy = np.array([self.plan[n] for n in nodes])
            home = [p for p in self.pieces if p.home == k]
            rows.append({"segment": k, "nodes": len(nodes), "pieces": len(home),
                         "lamellas": len({p.lamella for p in home}),
                         "plan_mm": [round(float(v), 1) for v in np.ptp(xy, axis=0)],
                         "extent_mm": round(extent(nodes, space), 1),
                         "strip_length_m": round(sum(p.length for p in home) / 1000.0, 3),
                         "site_crossings": sum(k in c["segments"] for c in self.crossings),
                         "site_seams": sum(k in s["segments"] for s in self.seams),
                         "cut_intervals": sum(1 for a, b in graph.edges(nodes) if self.segment_of[b] != k),
                         "steps": self.steps.get(k, [])})
        return {"rule": self.rule, "segments": rows, "families_in_order": self.families,
                "site_crossings": self.crossings, "site_seams": self.seams,
                "pieces": [{"piece": p.id, "lamella": p.lamella, "length_mm": round(p.length, 3), "segments": p.segments,
                            "home": p.home} for p in self.pieces]}


def plan_assembly(network: Network, partset: PartSet, count: int | None = None,
                  max_size_mm: float | None = None) -> AssemblyPlan:
    """Segments (`count` of them, or of plan sides up to `max_size_mm`), the pieces placed and ordered."""
    ids = {lam.id for lam in network.lamellas}
    pieces = lamella_pieces(partset, ids)
    if not pieces:
        raise FablineError("assembly: the parts have no strips of the model's lamellas (is it the model they were "
                           "unrolled from?)")
    unknown = sorted({nid for p in pieces for nid, _ in p.nodes} - set(network.nodes))
    if unknown:
        raise FablineError(f"assembly: the parts name node {unknown[0]}, which the model has not "
                           f"({len(unknown)} such nodes): give the model they were unrolled from")
    segments = partition(network, count, max_size_mm)
    segment_of = {nid: k for k, nodes in enumerate(segments, start=1) for nid in nodes}
    place(pieces, segment_of)
    crossings, seams = site_joints(pieces)
    families = family_order(pieces)
    plan = {nid: np.asarray(node.xyz[:2], dtype=float) * network.mm_per_unit for nid, node in network.nodes.items()}
    ordered = {k: steps([p for p in pieces if p.home == k], plan, families) for k in range(1, len(segments) + 1)}
    asked = f"{count} segments" if count is not None else f"the fewest segments of at most {max_size_mm / 1000.0:g} m"
    rule = (f"{asked}: k-means on the lamellas' node graph (farthest-point seeds, every node with its nearest seed "
            f"along the lamellas, seeds moved to their cells' centres until they stay), so each segment is one "
            f"connected patch and cuts run between nodes; a piece is built into the segment holding most of its nodes; "
            f"family {' then '.join(families)} (slots opening from the top edge laid first), lamella by lamella "
            f"across the segment")
    return AssemblyPlan(network, segments, segment_of, pieces, ordered, crossings, seams, families, plan,
                        network.lamellas_at(), rule)
