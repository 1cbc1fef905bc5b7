"""Surface normals for imported curves, from a reference mesh.

The normal at a point is the mesh's vertex normals interpolated at the closest point on the mesh (found
with libigl's AABB tree: exact, and fast enough for hundreds of thousands of curve samples), so it
varies smoothly along a lamella. Face winding is first made consistent (trimesh), so all normals of a
connected surface lie on one side: the side most of its faces faced in the file.
"""

from __future__ import annotations

from pathlib import Path

import igl
import numpy as np
import trimesh

from fabline.errors import FablineError
from fabline.fileio import vet_input


def mesh_from_arrays(vertices: np.ndarray, faces: np.ndarray, source: str) -> trimesh.Trimesh:
    """A welded triangle mesh without degenerate faces, its winding made consistent.

    trimesh makes neighbouring faces agree; each connected piece is then turned to the side that most of
    its faces (by area) faced as given, so a mesh with a few flipped faces keeps its author's orientation.
    """
    if not np.all(np.isfinite(np.asarray(vertices, dtype=float))):
        raise FablineError(f"{source}: the surface has NaN or infinite vertex coordinates")
    mesh = trimesh.Trimesh(np.asarray(vertices, dtype=float), np.asarray(faces, dtype=np.int64), process=True)
    mesh.update_faces(mesh.nondegenerate_faces())
    mesh.remove_unreferenced_vertices()
    if len(mesh.faces) == 0:
        raise FablineError(f"{source}: the surface has no faces of non-zero area")
    given = mesh.face_normals.copy()
    trimesh.repair.fix_winding(mesh)
    piece = trimesh.graph.connected_component_labels(mesh.face_adjacency, node_count=len(mesh.faces))
    agreement = np.bincount(piece, np.einsum("ij,ij->i", given, mesh.face_normals) * mesh.area_faces)
    flip = agreement[piece] < 0
    if flip.any():
        faces = mesh.faces.copy()
        faces[flip] = faces[flip][:, ::-1]
        mesh.faces = faces
    return mesh


def load_mesh_file(path: str | Path) -> trimesh.Trimesh:
    """Read a mesh file that trimesh understands (OBJ, STL, PLY, OFF, GLB...)."""
    return mesh_from_arrays(*read_mesh_arrays(path), str(path))


def read_mesh_arrays(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """A mesh file's vertices and triangles as written (not welded, degenerate faces kept)."""
    vet_input(path, "model")
    try:
        loaded = trimesh.load(str(path), force="mesh", process=False)
    except ImportError:  # trimesh guesses a broken file's text encoding with an optional module
        raise FablineError(f"{path}: cannot read as a mesh: neither a binary nor a text mesh file") from None
    except Exception as exc:  # trimesh raises many types for a broken file
        raise FablineError(f"{path}: cannot read as a mesh: {exc}".splitlines()[0]) from None
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise FablineError(f"{path}: no mesh faces found")
    return loaded.vertices, loaded.faces

class SurfaceNormals:
    """Closest points (libigl's AABB tree, exact) and interpolated vertex normals on one mesh."""

    def __init__(self, mesh: trimesh.Trimesh):
        self.mesh = mesh
        self.vertices = np.ascontiguousarray(mesh.vertices, dtype=float)
        self.faces = np.ascontiguousarray(mesh.faces, dtype=np.int64)
        self.vertex_normals = np.asarray(mesh.vertex_normals)

    def at(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Unit normals (n, 3) at the points' closest mesh points, and the distances (n,) to the mesh."""
        points = np.ascontiguousarray(np.asarray(points, dtype=float).reshape(-1, 3))
        squared, face, closest = igl.point_mesh_squared_distance(points, self.vertices, self.faces)
        face = np.asarray(face, dtype=np.int64)
        barycentric = trimesh.triangles.points_to_barycentric(self.mesh.triangles[face], closest)
        normals = np.einsum("ij,ijk->ik", barycentric, self.vertex_normals[self.faces[face]])
        length = np.linalg.norm(normals, axis=1)
        flat = length < 1e-9
        normals[flat] = self.mesh.face_normals[face[flat]]
        normals[~flat] /= length[~flat, None]
        return normals, np.sqrt(np.maximum(squared, 0.0))
