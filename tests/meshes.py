"""Meshes for the design and jobs tests: a saddle, a mesh writer, and the hard family a designer's mesh can be.

The hard family (`hard_meshes`) is irregular: jittered points Delaunay-triangulated in the plan, so no edge
follows a curvature or asymptotic line. Each height field is anticlastic somewhere and hard somewhere else:
a flat folded centre (a saddle blended into a plane with a crease across it: K >= 0 and noise-level curvature
there, a ring where the two asymptotic directions merge), a dome in a saddle, a saddle next to a dome, a hole, a thin neck, noise, a coarse mesh, the same in mm.
"""

from __future__ import annotations

import numpy as np
import trimesh
from scipy.spatial import Delaunay


def saddle(count=25, half=1.0):
    x, y = np.meshgrid(np.linspace(-half, half, count), np.linspace(-half, half, count), indexing="ij")
    vertices = np.c_[x.ravel(), y.ravel(), 0.3 * (x.ravel() ** 2 - y.ravel() ** 2)]
    index = np.arange(count * count).reshape(count, count)
    a, b, c, d = index[:-1, :-1].ravel(), index[1:, :-1].ravel(), index[1:, 1:].ravel(), index[:-1, 1:].ravel()
    return vertices, np.r_[np.c_[a, b, c], np.c_[a, c, d]]


def write_mesh(path, vertices, faces):
    trimesh.Trimesh(vertices, faces, process=False).export(path)
    return path


def plan_mesh(inside, bounds, vertices, seed=0):
    """About `vertices` jittered points where `inside(x, y)` holds in the box `bounds` (x0, x1, y0, y1), with the
    outline sampled as finely, Delaunay-triangulated; triangles whose centre is outside are dropped."""
    rng = np.random.default_rng(seed)
    x0, x1, y0, y1 = bounds
    probe = rng.uniform([x0, y0], [x1, y1], (20_000, 2))
    area = (x1 - x0) * (y1 - y0) * inside(probe[:, 0], probe[:, 1]).mean()
    cell = np.sqrt(area / vertices)
    gx, gy = np.meshgrid(np.arange(x0, x1 + cell, cell), np.arange(y0, y1 + cell, cell), indexing="ij")
    grid = np.c_[gx.ravel(), gy.ravel()] + rng.uniform(-0.4, 0.4, (gx.size, 2)) * cell
    fine = np.c_[[a.ravel() for a in np.meshgrid(np.arange(x0, x1 + cell, cell / 8), np.arange(y0, y1 + cell, cell / 8))]].T
    rim_mask = inside(fine[:, 0], fine[:, 1])
    # outline points: fine grid points inside with a neighbour outside, thinned to one per cell
    step = cell / 8
    outside_near = ~inside(fine[:, 0] + step, fine[:, 1]) | ~inside(fine[:, 0] - step, fine[:, 1]) | \
        ~inside(fine[:, 0], fine[:, 1] + step) | ~inside(fine[:, 0], fine[:, 1] - step)
    rim = fine[rim_mask & outside_near]
    keep_rim = []
    taken = set()
    for point in rim:
        key = tuple(np.floor(point / (0.7 * cell)).astype(int))
        if key not in taken:
            taken.add(key)
            keep_rim.append(point)
    rim = np.array(keep_rim)
    from scipy.spatial import cKDTree

    grid = grid[inside(grid[:, 0], grid[:, 1]) & (cKDTree(rim).query(grid)[0] > 0.5 * cell)]
    xy = np.vstack([rim, grid])
    faces = Delaunay(xy).simplices
    centre = xy[faces].mean(axis=1)
    long_edge = np.max([np.linalg.norm(xy[faces[:, i]] - xy[faces[:, (i + 1) % 3]], axis=1) for i in range(3)], axis=0)
    faces = faces[inside(centre[:, 0], centre[:, 1]) & (long_edge < 2.5 * cell)]
    mesh = trimesh.Trimesh(np.c_[xy, np.zeros(len(xy))], faces, process=False)
    labels = trimesh.graph.connected_component_labels(mesh.face_adjacency, node_count=len(faces))
    faces = faces[labels == np.argmax(np.bincount(labels))]  # one piece
    used = np.unique(faces)
    return xy[used], np.searchsorted(used, faces)


def _disk(radius):
    return lambda x, y: x * x + y * y <= radius * radius


def flat_centre(x, y, fold=0.0):
    """A saddle (0.3 (x^2 - y^2), 1.5 m across) blended flat within 0.15 m of the centre (a smoothstep out to
    0.4 m: K >= 0 in parts of the blend ring, where the asymptotic directions merge); `fold` m is the height of a
    crease (a tanh step 30 mm wide) across the flat centre."""
    blend = np.clip((np.hypot(x, y) - 0.15) / 0.25, 0.0, 1.0)
    smooth = blend * blend * (3 - 2 * blend)
    return 0.3 * (x * x - y * y) * smooth + fold * (1 - smooth) * np.tanh((x - 0.5 * y) / 0.03)


def folded_centre(x, y):
    """The designer's failure: the flat centre with a 4 mm fold across it."""
    return flat_centre(x, y, 0.004)


def dome_centre(x, y):
    """A saddle with a dome bump in its centre (K > 0 within about 0.1 m, a parabolic ring around it)."""
    return 0.3 * (x * x - y * y) + 0.02 * np.exp(-(x * x + y * y) / 0.15 ** 2)


def saddle_and_dome(x, y):
    """A saddle for x < 0.4 joined (C1) to a dome beyond: half anticlastic, half synclastic."""
    return np.where(x < 0.4, 0.3 * (x * x - y * y), 0.3 * (0.16 - y * y) + 0.24 * (x - 0.4) - 0.5 * (x - 0.4) ** 2)


def hypar(x, y):
    return 0.3 * (x * x - y * y)


HARD_MESHES = {
    # name: (height, plan inside, plan bounds, vertices, noise m, scale)
    "folded-centre": (folded_centre, _disk(0.75), (-0.75, 0.75, -0.75, 0.75), 2400, 0.0, 1.0),
    "folded-centre-noisy": (folded_centre, _disk(0.75), (-0.75, 0.75, -0.75, 0.75), 2400, 0.0003, 1.0),
    "folded-centre-mm": (folded_centre, _disk(0.75), (-0.75, 0.75, -0.75, 0.75), 2400, 0.0, 1000.0),
    "flat-centre": (flat_centre, _disk(0.75), (-0.75, 0.75, -0.75, 0.75), 2400, 0.0, 1.0),
    "dome-centre": (dome_centre, _disk(0.75), (-0.75, 0.75, -0.75, 0.75), 2400, 0.0, 1.0),
    "saddle-dome": (saddle_and_dome, lambda x, y: (np.abs(x) <= 1) & (np.abs(y) <= 0.8), (-1, 1.2, -0.8, 0.8), 2400, 0.0, 1.0),
    "hole": (hypar, lambda x, y: (x * x + y * y <= 0.75 ** 2) & ((x - 0.2) ** 2 + y * y >= 0.2 ** 2),
             (-0.75, 0.75, -0.75, 0.75), 2400, 0.0, 1.0),
    "neck": (hypar, lambda x, y: ((x + 0.5) ** 2 + y * y <= 0.4 ** 2) | ((x - 0.5) ** 2 + y * y <= 0.4 ** 2)
             | ((np.abs(x) <= 0.3) & (np.abs(y) <= 0.05)), (-0.9, 0.9, -0.4, 0.4), 2400, 0.0, 1.0),
    "coarse": (hypar, _disk(0.75), (-0.75, 0.75, -0.75, 0.75), 300, 0.0, 1.0),
}


def hard_mesh(name, seed=0):
    """One of the hard family as (vertices, faces, units) in its scale's units (m, or mm for scale 1000)."""
    height, inside, bounds, count, noise, scale = HARD_MESHES[name]
    xy, faces = plan_mesh(inside, bounds, count, seed)
    vertices = np.c_[xy, height(xy[:, 0], xy[:, 1])]
    if noise:
        vertices[:, 2] += np.random.default_rng(seed + 1).normal(0.0, noise, len(vertices))
    return vertices * scale, faces, "mm" if scale == 1000.0 else "m"
