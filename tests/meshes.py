"""A saddle mesh and a mesh writer (shared by the design and jobs tests)."""

from __future__ import annotations

import numpy as np
import trimesh


def saddle(count=25, half=1.0):
    x, y = np.meshgrid(np.linspace(-half, half, count), np.linspace(-half, half, count), indexing="ij")
    vertices = np.c_[x.ravel(), y.ravel(), 0.3 * (x.ravel() ** 2 - y.ravel() ** 2)]
    index = np.arange(count * count).reshape(count, count)
    a, b, c, d = index[:-1, :-1].ravel(), index[1:, :-1].ravel(), index[1:, 1:].ravel(), index[:-1, 1:].ravel()
    return vertices, np.r_[np.c_[a, b, c], np.c_[a, c, d]]


def write_mesh(path, vertices, faces):
    trimesh.Trimesh(vertices, faces, process=False).export(path)
    return path
