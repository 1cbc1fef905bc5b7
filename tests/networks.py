"""Small test networks from explicit curves (shared by the unroll, mechanics and cli tests)."""

from __future__ import annotations

import numpy as np

from fabline.model import Lamella, Network, Node


def network_of(curves: list[tuple[str, str, np.ndarray, np.ndarray, list[int]]], name: str = "test") -> Network:
    """Lamellas (id, family, points mm, normals, indices of their node samples); nodes named by rounded position.

    Nodes at the same place (within 1e-6 mm) on several curves become one node.
    """
    nodes: dict[str, Node] = {}
    lamellas = []
    for lam_id, family, points, normals, node_index in curves:
        ids = []
        for k in node_index:
            key = "N" + "_".join(f"{v:.0f}" for v in np.round(points[k], 3) + 0.0)  # + 0.0 turns -0 into 0
            nodes.setdefault(key, Node(key, points[k].copy(), normals[k].copy()))
            ids.append(key)
        lamellas.append(Lamella(lam_id, family, ids, points, normals))
    counts: dict[str, int] = {}
    for lam in lamellas:
        for nid in lam.nodes:
            counts[nid] = counts.get(nid, 0) + 1
    for nid, node in nodes.items():
        node.kind = "singularity" if counts[nid] >= 3 else "grid"
    return Network("mm", nodes, lamellas, name)


def polar_grid(radii: np.ndarray, angles: np.ndarray) -> Network:
    """Concentric circles (family A, counter-clockwise) and radial lines (family B) in the plane z = 0."""
    curves = []
    for i, r in enumerate(radii):
        per = int(np.ceil((angles[1] - angles[0]) * r / 20.0))
        phi = np.linspace(angles[0], angles[-1], per * (len(angles) - 1) + 1)
        points = r * np.column_stack([np.cos(phi), np.sin(phi), np.zeros_like(phi)])
        curves.append((f"A-{i:03d}", "A", points, np.tile([0.0, 0.0, 1.0], (len(phi), 1)), list(range(0, len(phi), per))))
    for j, phi in enumerate(angles):
        per = int(np.ceil((radii[1] - radii[0]) / 20.0))
        r = np.linspace(radii[0], radii[-1], per * (len(radii) - 1) + 1)
        points = np.column_stack([r * np.cos(phi), r * np.sin(phi), np.zeros_like(r)])
        curves.append((f"B-{j:03d}", "B", points, np.tile([0.0, 0.0, 1.0], (len(r), 1)), list(range(0, len(r), per))))
    return network_of(curves, "polar")
