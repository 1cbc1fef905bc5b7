"""Prefabricated segments: the network's nodes cut into connected patches of about equal size (thesis 6.3: nine).

The rule, deterministic and simple: k-means on the node graph (consecutive nodes of a lamella are its edges,
weighted by their distance in space: the shell's true size, which a plan view shrinks where it is steep). n seed
nodes by farthest-point sampling (the first the farthest from the node nearest the centre, each next the farthest from those taken; ties by node id); every node joins its
nearest seed along the lamellas (a graph Voronoi cell, connected by construction: the shortest path to a node
runs through nodes of the same seed); each seed then moves to its cell's node nearest the cell's centre, and
again, until the seeds stay (Lloyd's iteration, which evens out the cells' surface areas). Cuts run between
nodes, never through one. For a size limit (`max_segment`) n is the fewest whose segments all fit in a box of
that side (their nodes' extent along x, y and z).
"""

from __future__ import annotations

import math

import networkx as nx
import numpy as np

from fabline.errors import FablineError
from fabline.model.network import Network

MAX_SEGMENTS = 1000


def node_graph(network: Network) -> nx.Graph:
    """The network's nodes, joined where they follow each other along a lamella."""
    graph = nx.Graph()
    graph.add_nodes_from(network.nodes)
    for lamella in network.lamellas:
        graph.add_edges_from(zip(lamella.nodes[:-1], lamella.nodes[1:]))
    return graph


def partition(network: Network, count: int | None = None, max_size_mm: float | None = None) -> list[list[str]]:
    """The segments (lists of node ids, numbered from 1 in plan order: by the centre's y, then x) for `count`
    segments or for extents of at most `max_size_mm` (mm); exactly one of the two."""
    if (count is None) == (max_size_mm is None):
        raise FablineError("assembly: give the number of segments or the largest segment size, not both")
    ids = sorted(network.nodes)
    most = min(len(ids), MAX_SEGMENTS)
    if count is not None and not 1 <= count <= most:
        raise FablineError(f"assembly: {count} segments for {len(ids)} nodes: use 1 to {most}")
    if max_size_mm is not None and not 0 < max_size_mm < math.inf:
        raise FablineError(f"assembly: max_segment: must be a positive length, got {max_size_mm:g} mm")
    space = {nid: np.asarray(network.nodes[nid].xyz, dtype=float) * network.mm_per_unit for nid in ids}
    graph = node_graph(network)
    for a, b in graph.edges:
        graph.edges[a, b]["weight"] = float(np.linalg.norm(space[a] - space[b]))
    if count is not None:
        return _numbered(graph_kmeans(graph, count, space), space)
    for n in range(1, most + 1):
        segments = graph_kmeans(graph, n, space)
        if all(extent(seg, space) <= max_size_mm for seg in segments):
            return _numbered(segments, space)
    raise FablineError(f"assembly: max_segment: {max_size_mm / 1000.0:g} m is smaller than any connected patch of "
                       f"{MAX_SEGMENTS} segments or fewer: give a larger size")


def extent(nodes: list[str], space: dict[str, np.ndarray]) -> float:
    """The largest side of the nodes' bounding box (mm): the size a segment takes on the ground and on a truck."""
    return float(np.ptp([space[n] for n in nodes], axis=0).max()) if len(nodes) > 1 else 0.0


def _numbered(segments: list[list[str]], plan: dict[str, np.ndarray]) -> list[list[str]]:
    """The segments in plan order (their centres by y, then x), each's nodes sorted."""
    centre = [np.mean([plan[n] for n in seg], axis=0) for seg in segments]
    order = sorted(range(len(segments)), key=lambda k: (round(float(centre[k][1]), 3), round(float(centre[k][0]), 3)))
    return [sorted(segments[k]) for k in order]


def graph_kmeans(graph: nx.Graph, count: int, space: dict[str, np.ndarray], rounds: int = 50) -> list[list[str]]:
    """`count` connected cells of the graph (see the module): farthest-point seeds, then Lloyd's iteration."""
    ids = sorted(graph)
    xy = np.array([space[n] for n in ids])
    centre = ids[int(np.argmin(np.linalg.norm(xy - xy.mean(axis=0), axis=1)))]
    seeds: list[str] = []
    distance = nx.single_source_dijkstra_path_length(graph, centre)  # from the centre, then from the seeds taken
    for _ in range(count):
        seeds.append(centre if count == 1 else max(ids, key=lambda n: (distance.get(n, math.inf), n)))
        reach = nx.single_source_dijkstra_path_length(graph, seeds[-1])
        distance = {n: min(reach.get(n, math.inf), distance[n] if len(seeds) > 1 else math.inf) for n in ids}
    cells = _cells(graph, seeds, ids)
    for _ in range(rounds):
        moved = [_middle(cell, space) for cell in cells]
        if moved == seeds or len(set(moved)) < len(moved):
            break
        seeds, cells = moved, _cells(graph, moved, ids)
    return cells


def _cells(graph: nx.Graph, seeds: list[str], ids: list[str]) -> list[list[str]]:
    """Every node with its nearest seed along the graph (ties: the first seed); a node no seed reaches goes with
    the first (the network in pieces)."""
    _, paths = nx.multi_source_dijkstra(graph, seeds)
    index = {seed: k for k, seed in enumerate(seeds)}
    cells: list[list[str]] = [[] for _ in seeds]
    for n in ids:
        cells[index[paths[n][0]] if n in paths else 0].append(n)
    return cells


def _middle(cell: list[str], space: dict[str, np.ndarray]) -> str:
    """The cell's node nearest its centre (ties by id)."""
    mid = np.mean([space[n] for n in cell], axis=0)
    return min(cell, key=lambda n: (round(float(np.linalg.norm(space[n] - mid)), 6), n))
