"""The diagonal bracing cables: one run along every diagonal of the grid through the cable clamps.

The clamps sit on every second node (one colour of the grid's two-colouring, `hardware.checkerboard`), so every
diagonal through a clamp node meets only clamp nodes: each such diagonal is one cable, and each clamp holds two,
one through each pair of opposite cable holes. A diagonal step is found from the lamellas alone: from node n one
interval along its A lamella to p and one along its B lamella to q, the diagonal node m is the B neighbour of p that
is also the A neighbour of q (the quad n-p-m-q); the run goes on straight, away from q along A and from p along B.
A run ends where no quad closes (the boundary) or at a node without a clamp (a singularity).

The cable passes through the clamps' bent-up cable holes: a clamp lies on the top washer (+n side) under the bolt
head, so a hole's centre is h/2 + 2t + (hole height above the plate) off the node along the surface normal. The
geometric length is the polyline through those points (the cable is straight between clamps); the cut length is
that, shortened by the pretension strain (the cable is cut short so that tensioning stretches it to fit), plus an
end allowance at each end: the cable runs on through the end clamp's outer hole to a swaged stop behind it.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from fabline.errors import FablineError
from fabline.model.network import Network
from fabline.unroll.hardware import CABLE_HOLE, FOLD_CLEARANCE, HardwareSizes


@dataclass(frozen=True)
class CableSettings:
    """Pretension strain (mm per m of geometric length) and the allowance beyond each end clamp's centre (mm)."""

    pretension_mm_per_m: float = 1.0
    end_allowance: float = 80.0


PRETENSION_FORMS = "a strain as '1 mm/m', '0.1 %' or a number in mm/m"


def parse_pretension(value: float | int | str, where: str) -> float:
    """A pretension strain in mm/m from a number (mm/m), 'N mm/m', 'N %' or 'N permille'; a one-line error otherwise."""
    if isinstance(value, bool):
        raise FablineError(f"{where}: expected {PRETENSION_FORMS}, got {value!r}")
    if isinstance(value, (int, float)):
        strain = float(value)
    else:
        match = re.fullmatch(r"\s*([0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)\s*(mm/m|%|permille)?\s*", str(value))
        if not match:
            raise FablineError(f"{where}: expected {PRETENSION_FORMS}, got {value!r}")
        strain = float(match[1]) * {"%": 10.0, "permille": 1.0}.get(match[2] or "mm/m", 1.0)
    if not 0.0 <= strain < 100.0:
        raise FablineError(f"{where}: {value!r} must be at least 0 and under 100 mm/m (10 %)")
    return strain


def clamp_lift(profile_h: float, profile_t: float, sizes: HardwareSizes) -> float:
    """How far off the node a clamp's cable holes sit along the normal (mm): half the lamella height, the top washer
    and the clamp plate (each t), and the hole's height above the plate once its arm tip is folded up."""
    hole_above_plate = sizes.clamp_reach - CABLE_HOLE - (sizes.washer_reach + FOLD_CLEARANCE)
    return profile_h / 2.0 + 2.0 * profile_t + hole_above_plate


def _neighbours(network: Network) -> dict[tuple[str, str], list[str]]:
    """(node, family) -> the node's neighbours along its lamella of that family (none where the node has two)."""
    found: dict[tuple[str, str], list[str]] = {}
    count: dict[tuple[str, str], int] = {}
    for lam in network.lamellas:
        for k, nid in enumerate(lam.nodes):
            key = (nid, lam.family)
            count[key] = count.get(key, 0) + 1
            found[key] = [lam.nodes[j] for j in (k - 1, k + 1) if 0 <= j < len(lam.nodes)]
    return {key: value for key, value in found.items() if count[key] == 1}


def diagonal_chains(network: Network, clamped: set[str]) -> list[list[str]]:
    """Every diagonal of the grid through the clamp nodes, as its node chain (at least two clamps), in a stable order."""
    along = _neighbours(network)

    def close(p: str, q: str, n: str) -> str | None:
        """The fourth node of the quad n-p-?-q: a B neighbour of p that is an A neighbour of q."""
        common = set(along.get((p, "B"), ())) & set(along.get((q, "A"), ())) - {n}
        return common.pop() if len(common) == 1 else None

    def steps(n: str) -> list[tuple[str, str, str]]:
        """The up to four diagonal steps from n: (p, q, m) with p its A neighbour, q its B neighbour, m the quad's."""
        out = []
        for p in along.get((n, "A"), ()):
            for q in along.get((n, "B"), ()):
                m = close(p, q, n)
                if m is not None:
                    out.append((p, q, m))
        return out

    def walk(n: str, p: str, q: str, m: str) -> list[str]:
        """Nodes after n going straight on through m: from m away from q along A and away from p along B."""
        chain = []
        while m in clamped and m not in chain and m != n:
            chain.append(m)
            p2 = [x for x in along.get((m, "A"), ()) if x != q]
            q2 = [x for x in along.get((m, "B"), ()) if x != p]
            if len(p2) != 1 or len(q2) != 1:
                break
            nxt = close(p2[0], q2[0], m)
            if nxt is None:
                break
            n, p, q, m = m, p2[0], q2[0], nxt
        return chain

    chains, used = [], set()
    for start in sorted(clamped):
        for p, q, m in steps(start):
            if frozenset((start, m)) in used or m not in clamped:
                continue
            forward = walk(start, p, q, m)
            # backwards: the step from start opposite to (p, q) goes through its other A and B neighbours
            back_p = [x for x in along.get((start, "A"), ()) if x != p]
            back_q = [x for x in along.get((start, "B"), ()) if x != q]
            backward: list[str] = []
            if len(back_p) == 1 and len(back_q) == 1:
                behind = close(back_p[0], back_q[0], start)
                if behind is not None:
                    backward = walk(start, back_p[0], back_q[0], behind)
            chain = backward[::-1] + [start] + forward
            used.update(frozenset(pair) for pair in zip(chain[:-1], chain[1:]))
            if len(chain) >= 2:
                chains.append(chain if chain[0] <= chain[-1] else chain[::-1])
    return sorted(chains, key=lambda c: (c[0], c[-1]))


def cable_runs(network: Network, clamped: set[str], lift: float, settings: CableSettings) -> list[dict]:
    """One record per cable (mm): its clamp nodes and clamp parts, the clamp positions along it (arc length of the
    polyline through the clamp points), geometric and cut length, and the end anchors."""
    mm = network.in_mm()
    ends = {lam.nodes[0] for lam in mm.lamellas} | {lam.nodes[-1] for lam in mm.lamellas}
    runs = []
    for k, chain in enumerate(diagonal_chains(mm, clamped)):
        points = np.array([mm.nodes[n].xyz + lift * mm.nodes[n].normal for n in chain], dtype=float)
        at = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
        geometric = float(at[-1])
        cut = geometric * (1.0 - settings.pretension_mm_per_m / 1000.0) + 2.0 * settings.end_allowance
        anchors = [{"node": n, "part": f"C-{n}", "node_kind": mm.nodes[n].kind, "on_boundary": n in ends}
                   for n in (chain[0], chain[-1])]
        runs.append({"id": f"CB{k + 1:02d}", "nodes": chain, "clamps": [f"C-{n}" for n in chain],
                     "clamp_positions_mm": [round(float(s), 1) for s in at],
                     "points_mm": np.round(points, 1).tolist(),
                     "geometric_length_mm": round(geometric, 1), "cut_length_mm": round(cut, 1),
                     "anchors": anchors})
    return runs


def cable_summary(runs: list[dict], options, lift: float) -> dict:
    """The report's cable entry: how many runs, their total geometric and cut length (m), and the settings."""
    return {"runs": len(runs), "clamps": len({c for run in runs for c in run["clamps"]}),
            "geometric_length_m": round(sum(r["geometric_length_mm"] for r in runs) / 1000.0, 3),
            "cut_length_m": round(sum(r["cut_length_mm"] for r in runs) / 1000.0, 3),
            "pretension_mm_per_m": options.cable_pretension, "end_allowance_mm": options.cable_end_allowance,
            "clamp_lift_mm": round(lift, 2)}
