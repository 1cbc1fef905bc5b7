"""The erected gridshell as a Frame: every lamella's pair of strips as chains of beams between its nodes and stations
between them (the section's height along the surface normal), each strip locked to its design curvature (weak-axis
k_g and twist tau_g: it was cut flat and straight, or curved in plane by k_n, so k_n locks nothing); at every node
the strips of one lamella held together by the washers (rigid links to the lamella's joint point) and the lamellas
joined by the bolt as a scissor hinge about the normal; the bracing cables tension-only from clamp to clamp; the
network's support nodes fixed or pinned."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fabline.analysis.frame import SUPPORT_KINDS, Frame, Section
from fabline.geometry.darboux import NetworkGeometry
from fabline.mechanics.hardware import Cable

CABLE_E = 120000.0   # N/mm2 on the metallic area: a 1x19 stainless strand (EN 12385-4 gives 100-130 kN/mm2)


@dataclass(frozen=True)
class ModelOptions:
    """What shapes the frame: beams per node interval, the pair's centre distance (0: single strips), the supports'
    kind, the cables' node runs, strand and pretension strain, and the shear blocks' intervals (lamella, node, next
    node: `fabline.unroll.couplers`), each a link between the pair's strips at the interval's middle station."""

    stations: int = 2
    pair_spacing: float = 25.0
    supports: str = "pinned"
    cables: tuple[tuple[str, ...], ...] = ()
    cable: Cable | None = None
    cable_prestrain: float = 0.0
    couplers: tuple[tuple[str, str, str], ...] = ()


@dataclass
class GridshellFrame:
    """The Frame and where the gridshell is in it: each network node's joint point (frame node index), each beam's
    lamella and node interval, and each beam's design curvature (k_g, tau_g) the geometric check reads."""

    frame: Frame
    joints: dict[str, int]
    beam_lamella: list[str]
    beam_interval: np.ndarray
    design: np.ndarray


def build(geometry: NetworkGeometry, section: Section, options: ModelOptions) -> GridshellFrame:
    """The frame of a millimetre network's geometry (`fabline.geometry.analyse`)."""
    network = geometry.network
    xyz, names, beams, beam_z, strains, tags = [], [], [], [], [], []
    beam_lamella, beam_interval, design = [], [], []
    links, hinges, supports = [], [], {}
    joints: dict[str, int] = {}

    def add(point, name):
        xyz.append(point)
        names.append(name)
        return len(xyz) - 1

    sides = ((1.0, "L"), (-1.0, "R")) if options.pair_spacing > 0 else ((0.0, ""),)
    for geo in geometry.lamellas.values():
        lam = geo.lamella
        m = options.stations
        fractions = np.arange(m) / m
        s = np.append((geo.node_s[:-1, None] + np.diff(geo.node_s)[:, None] * fractions[None, :]).ravel(),
                      geo.node_s[-1])
        frame_at = geo.fit.frame(geo.fit.parameter_at(s))
        centre = geo.fit.curve(geo.fit.parameter_at(s))
        mid = geo.fit.frame(geo.fit.parameter_at((s[1:] + s[:-1]) / 2.0))
        at_node = np.arange(0, len(s), m)
        centres = {}
        for k, nid in zip(at_node, lam.nodes):
            point = add(np.asarray(network.nodes[nid].xyz, dtype=float), f"{nid}/{lam.id}")
            centres[k] = point
            if nid in joints:
                hinges.append((joints[nid], point, np.asarray(network.nodes[nid].normal, dtype=float)))
            else:
                joints[nid] = point
                if network.nodes[nid].kind == "support":
                    supports[point] = SUPPORT_KINDS[options.supports]
        coupled = [at_node[lam.nodes.index(a)] + m // 2 for lamella, a, b in options.couplers
                   if lamella == lam.id and m > 1 and len(sides) == 2]
        middles = []
        for offset, side in sides:
            strip = f"{lam.id}-{side}" if side else lam.id
            points = centre + offset * options.pair_spacing / 2.0 * frame_at["u"]
            index = [centres[k] if not offset and k in centres else add(p, f"{strip}:{k}") for k, p in enumerate(points)]
            links += [(point, index[k]) for k, point in centres.items() if offset]
            middles.append([index[k] for k in coupled])
            for e in range(len(s) - 1):
                beams.append((index[e], index[e + 1]))
                beam_z.append(mid["n"][e])
                strains.append((mid["tau_g"][e], 0.0, mid["k_g"][e]))
                tags.append((strip, e))
                beam_lamella.append(lam.id)
                beam_interval.append(e // m)
                design.append((mid["k_g"][e], mid["tau_g"][e]))
        if coupled:
            links += list(zip(*middles))
    frame = Frame(np.array(xyz), names, np.array(beams, dtype=int), np.array(beam_z), section, np.array(strains),
                  tags, links, hinges, supports=supports)
    runs = [[joints[nid] for nid in run if nid in joints] for run in options.cables]
    if runs and options.cable is not None:
        frame.cables = np.array([(a, b) for run in runs for a, b in zip(run[:-1], run[1:])], dtype=int).reshape(-1, 2)
        frame.cable_area = options.cable.fill_factor * math.pi * options.cable.diameter ** 2 / 4.0
        frame.cable_E = CABLE_E
        frame.cable_prestrain = options.cable_prestrain
    return GridshellFrame(frame, joints, beam_lamella, np.array(beam_interval), np.array(design))


def bracing(network) -> tuple[tuple[str, ...], ...]:
    """The bracing cables' node runs as the unroll places them (every diagonal through the clamp nodes, one colour of
    the grid's two-colouring), for a network analysed without its parts.json."""
    from fabline.unroll.cables import diagonal_chains
    from fabline.unroll.hardware import checkerboard

    neighbours: dict[str, list[str]] = {}
    for lam in network.lamellas:
        for a, b in zip(lam.nodes[:-1], lam.nodes[1:]):
            neighbours.setdefault(a, []).append(b)
            neighbours.setdefault(b, []).append(a)
    clamped = checkerboard(sorted(neighbours), neighbours)
    return tuple(tuple(chain) for chain in diagonal_chains(network.in_mm(), clamped))
