"""The lamella pieces (strip parts between seams) and where each is built: its home segment and its site joints.

A piece belongs to every segment its nodes lie in; it is built into the one holding most of its nodes (its home;
a tie goes to the lower number). A crossing is made on site when the pieces through it have different homes, and a
seam is screwed on site when the pieces it joins have different homes: these are the joints between segments.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from fabline.unroll.parts import PartSet

STRIP_KINDS = ("strip", "curved-strip")


@dataclass
class Piece:
    """One strip part of a network lamella: its nodes and slots along it (mm from its start) and its segments."""

    id: str
    lamella: str
    strip: str
    family: str
    length: float
    start: float                    # where it begins along its strip (mm)
    nodes: list[tuple[str, float]]  # (node id, mm from the piece's start)
    slots: list[str]                # the node of each slot, in order (a paired lamella has two slots per node)
    seams: list[dict]               # its joins to the pieces before and after it ("seam" kind only)
    slot_edge: str | None = None    # the edge its slots open from ("top" or "bottom")
    segments: list[int] = field(default_factory=list)
    home: int = 0


def lamella_pieces(partset: PartSet, lamella_ids: set[str]) -> list[Piece]:
    """The strip parts of the network's lamellas (edge bars and hardware are not in the segments), in part order."""
    pieces = []
    for part in partset.parts:
        if part.kind not in STRIP_KINDS or part.lamella not in lamella_ids:
            continue
        meta = part.meta
        start, end = meta.get("strip_range_mm", [0.0, 0.0])
        joins = [join for join in (meta.get("joins") or {}).values() if join and join.get("kind") == "seam"]
        pieces.append(Piece(part.id, part.lamella, meta.get("strip", part.lamella), meta.get("family", ""),
                            float(end - start), float(start), [(n["id"], float(n["s"])) for n in part.nodes],
                            [slot.node for slot in part.slots], joins,
                            next((slot.edge for slot in part.slots if slot.edge), None)))
    return pieces


def place(pieces: list[Piece], segment_of: dict[str, int]) -> None:
    """Each piece's segments (in order along it) and its home segment."""
    for piece in pieces:
        along = [segment_of[nid] for nid, _ in piece.nodes if nid in segment_of]
        piece.segments = list(dict.fromkeys(along))
        piece.home = max(sorted(piece.segments), key=along.count) if along else 0


def site_joints(pieces: list[Piece]) -> tuple[list[dict], list[dict]]:
    """The crossings and the seams made on site: where pieces of different home segments meet."""
    homes: dict[str, dict[str, int]] = {}
    for piece in pieces:
        for nid in dict.fromkeys(piece.slots):
            homes.setdefault(nid, {})[piece.id] = piece.home
    crossings = [{"node": nid, "pieces": sorted(at), "segments": sorted(set(at.values()))}
                 for nid, at in sorted(homes.items()) if len(set(at.values())) > 1]
    home_of = {piece.id: piece.home for piece in pieces}
    seams = []
    for piece in pieces:
        for join in piece.seams:
            other = join.get("part")
            if other in home_of and piece.id < other and home_of[other] != piece.home:
                seams.append({"pieces": [piece.id, other], "between": join.get("between"),
                              "segments": sorted({piece.home, home_of[other]})})
    return crossings, seams
