"""Isotropic remeshing with a fixed boundary: edges split, collapsed and flipped towards a target length.

Botsch and Kobbelt's passes ("A remeshing approach to multiresolution modeling", 2004), for
`design minimal`: interior edges longer than 4/3 of the target are split at their midpoint, those
shorter than 4/5 collapsed (onto a boundary vertex when they touch one, so the boundary never moves,
and only when the result stays manifold, unfolded and free of long edges), and edges flipped where
that brings the valences closer to 6 (4 on the boundary). Boundary vertices and edges are never
moved, split or removed; tangential smoothing is the caller's (the minimiser relaxes every step).
"""

from __future__ import annotations

import numpy as np

SPLIT_ABOVE = 4.0 / 3.0  # of the target length
COLLAPSE_BELOW = 4.0 / 5.0
SPLIT_PASSES = 6  # a pass splits at most one edge per face; an edge 2^k too long needs k passes
MIN_FOLD_COSINE = 0.2  # a collapse or flip must leave every changed face's normal within ~78 degrees of the old one


def remesh(vertices: np.ndarray, faces: np.ndarray, fixed: np.ndarray, target: float
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """One round of splits, collapses and flips; the new vertices, faces, fixed mask and the number of changes."""
    changes = 0
    for _ in range(SPLIT_PASSES):
        vertices, faces, fixed, split = _split_long(vertices, faces, fixed, target)
        changes += split
        if not split:
            break
    vertices, faces, fixed, collapsed = _collapse_short(vertices, faces, fixed, target)
    faces, flipped = _flip_to_valence(vertices, faces, fixed)
    return vertices, faces, fixed, changes + collapsed + flipped


def _interior_edges(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Edges with two faces: (E, 2) vertices a, b with face 0 holding a -> b; (E, 2) the two faces; (E, 2) their third vertices."""
    half = np.stack([faces, np.roll(faces, -1, axis=1)], axis=-1).reshape(-1, 2)
    third = np.roll(faces, -2, axis=1).reshape(-1)
    key = half.min(axis=1).astype(np.int64) * (int(faces.max()) + 1) + half.max(axis=1)
    order = np.argsort(key, kind="stable")
    pairs = np.flatnonzero(key[order][1:] == key[order][:-1])
    first, second = order[pairs], order[pairs + 1]
    return half[first], np.c_[first // 3, second // 3], np.c_[third[first], third[second]]


def _split_long(vertices: np.ndarray, faces: np.ndarray, fixed: np.ndarray, target: float
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Split the longest interior edges above SPLIT_ABOVE * target, at most one per face, at their midpoints."""
    edges, sides, thirds = _interior_edges(faces)
    length = np.linalg.norm(vertices[edges[:, 0]] - vertices[edges[:, 1]], axis=1)
    used = np.zeros(len(faces), dtype=bool)
    chosen = []
    for e in np.argsort(-length):
        if length[e] <= SPLIT_ABOVE * target:
            break
        if not used[sides[e]].any():
            used[sides[e]] = True
            chosen.append(e)
    if not chosen:
        return vertices, faces, fixed, 0
    chosen = np.array(chosen)
    a, b = edges[chosen].T
    c, d = thirds[chosen].T
    middle = len(vertices) + np.arange(len(chosen))
    faces = faces.copy()
    faces[sides[chosen, 0]] = np.c_[a, middle, c]
    faces[sides[chosen, 1]] = np.c_[b, middle, d]
    added = np.r_[np.c_[middle, b, c], np.c_[middle, a, d]]
    vertices = np.vstack([vertices, 0.5 * (vertices[a] + vertices[b])])
    return vertices, np.vstack([faces, added]), np.r_[fixed, np.zeros(len(chosen), dtype=bool)], len(chosen)


def _collapse_short(vertices: np.ndarray, faces: np.ndarray, fixed: np.ndarray, target: float
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Collapse interior edges below COLLAPSE_BELOW * target, shortest first, where the mesh stays manifold and unfolded."""
    edges, _, _ = _interior_edges(faces)
    length = np.linalg.norm(vertices[edges[:, 0]] - vertices[edges[:, 1]], axis=1)
    short = np.argsort(length)[: int(np.searchsorted(np.sort(length), COLLAPSE_BELOW * target))]
    if not len(short):
        return vertices, faces, fixed, 0
    vertices, faces = vertices.copy(), faces.copy()
    around: list[set[int]] = [set() for _ in range(len(vertices))]
    for f, corners in enumerate(faces.tolist()):
        for v in corners:
            around[v].add(f)
    alive = np.ones(len(faces), dtype=bool)
    gone = np.zeros(len(vertices), dtype=bool)
    collapsed = 0
    for a, b in edges[short].tolist():
        if gone[a] or gone[b] or (fixed[a] and fixed[b]):
            continue
        keep, drop = (a, b) if fixed[a] else (b, a)
        shared = around[a] & around[b]
        ring_keep = {v for f in around[keep] for v in faces[f]} - {keep}
        ring_drop = {v for f in around[drop] for v in faces[f]} - {drop}
        if len(shared) != 2 or len(ring_keep & ring_drop) != 2:
            continue  # not an interior edge any more, or the collapse would pinch the surface (link condition)
        point = vertices[keep] if fixed[keep] else 0.5 * (vertices[a] + vertices[b])
        if np.linalg.norm(vertices[list(ring_keep | ring_drop)] - point, axis=1).max() > SPLIT_ABOVE * target:
            continue
        changed = list((around[a] | around[b]) - shared)
        old = faces[changed]
        new = np.where(old == drop, keep, old)
        before = _normals(vertices, old)
        saved = vertices[keep].copy()
        vertices[keep] = point
        after = _normals(vertices, new)
        if (np.einsum("ij,ij->i", before, after) < MIN_FOLD_COSINE).any():
            vertices[keep] = saved
            continue
        faces[changed] = new
        for f in shared:
            alive[f] = False
            for v in faces[f]:
                around[v].discard(f)
        around[keep] |= around[drop]
        around[drop] = set()
        gone[drop] = True
        collapsed += 1
    keep_vertices = np.flatnonzero(~gone)
    remap = np.full(len(vertices), -1, dtype=np.int64)
    remap[keep_vertices] = np.arange(len(keep_vertices))
    return vertices[keep_vertices], remap[faces[alive]], fixed[keep_vertices], collapsed


def _flip_to_valence(vertices: np.ndarray, faces: np.ndarray, fixed: np.ndarray) -> tuple[np.ndarray, int]:
    """Flip interior edges where that lowers the squared deviation of the four valences from 6 (4 on the boundary).

    Flips in one pass touch disjoint vertex sets, so each decision holds when they are applied together.
    """
    edges, sides, thirds = _interior_edges(faces)
    valence = np.bincount(np.r_[edges.ravel(), _boundary_edges(faces).ravel()], minlength=len(vertices))
    ideal = np.where(fixed, 4, 6)
    a, b = edges.T
    c, d = thirds.T
    quad = np.c_[a, b, c, d]
    deviation = valence[quad] - ideal[quad]
    gain = (deviation ** 2).sum(axis=1) - ((deviation + [-1, -1, 1, 1]) ** 2).sum(axis=1)
    before = _normals(vertices, np.c_[a, b, c]) + _normals(vertices, np.c_[b, a, d])
    first, second = _normals(vertices, np.c_[a, d, c]), _normals(vertices, np.c_[d, b, c])
    unit = before / np.linalg.norm(before, axis=1, keepdims=True)
    flat = (np.einsum("ij,ij->i", first, unit) > MIN_FOLD_COSINE) & (np.einsum("ij,ij->i", second, unit) > MIN_FOLD_COSINE)
    existing = set(map(tuple, np.sort(edges, axis=1).tolist()))
    used = np.zeros(len(vertices), dtype=bool)
    chosen = []
    for e in np.flatnonzero((gain > 0) & flat)[np.argsort(-gain[(gain > 0) & flat], kind="stable")]:
        if used[quad[e]].any() or (min(c[e], d[e]), max(c[e], d[e])) in existing:
            continue
        used[quad[e]] = True
        chosen.append(e)
    if not chosen:
        return faces, 0
    chosen = np.array(chosen)
    faces = faces.copy()
    faces[sides[chosen, 0]] = np.c_[a[chosen], d[chosen], c[chosen]]
    faces[sides[chosen, 1]] = np.c_[d[chosen], b[chosen], c[chosen]]
    return faces, len(chosen)


def _boundary_edges(faces: np.ndarray) -> np.ndarray:
    """(B, 2) edges with one face."""
    half = np.sort(np.stack([faces, np.roll(faces, -1, axis=1)], axis=-1).reshape(-1, 2), axis=1)
    unique, counts = np.unique(half, axis=0, return_counts=True)
    return unique[counts == 1]


def _normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unit normals of triangles (zero for a degenerate one)."""
    normal = np.cross(vertices[faces[:, 1]] - vertices[faces[:, 0]], vertices[faces[:, 2]] - vertices[faces[:, 0]])
    size = np.linalg.norm(normal, axis=1, keepdims=True)
    return np.divide(normal, size, out=np.zeros_like(normal), where=size > 0)
