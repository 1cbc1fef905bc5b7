"""Read lamella curves from Rhino .3dm files (rhino3dm, the optional extra `rhino`).

Units come from the model unit system. A curve's family and id come from its object name, else its
layer name (last part of the layer path). Curves are converted to NURBS and flattened within 0.01 mm
(ezdxf's B-spline); meshes, and breps and surfaces (their render meshes, else a grid sampled on each
face's surface), form the reference surface.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from ezdxf.math import BSpline

from fabline.errors import FablineError
from fabline.fileio import vet_input
from fabline.model.importers.curves import SAGITTA_MM, CurveSource, assign_ids, clean_points, family_and_id
from fabline.model.importers.surface import mesh_from_arrays
from fabline.model.network import UNIT_TO_MM

SURFACE_GRID = 64
"""Samples per direction when a brep face or surface has no render mesh stored in the file."""


def read_3dm(path: str | Path, units: str | None = None) -> CurveSource:
    """The curves of a .3dm file and its meshes, breps and surfaces as the surface; `units` only sets the
    flattening tolerance of a file without a model unit system."""
    rhino3dm = _rhino3dm()
    path = str(path)
    model = _read_model(rhino3dm, path)
    declared = _declared_units(rhino3dm, model, path)
    sagitta = SAGITTA_MM / UNIT_TO_MM.get(declared or units or "m", 1000.0)
    layers = {layer.Index: layer.FullPath or layer.Name for layer in model.Layers}
    found, unnamed = [], []
    meshes = []
    for number, item in enumerate(model.Objects):
        geometry, attributes = item.Geometry, item.Attributes
        if isinstance(geometry, rhino3dm.Curve):
            layer = layers.get(attributes.LayerIndex, "")
            where = f"object {number}" + (f" {attributes.Name!r}" if attributes.Name else "") + f" on layer {layer}"
            family, lamella_id = family_and_id([attributes.Name or "", layer])
            if family is None:
                unnamed.append(where)
                continue
            found.append((family, lamella_id, clean_points(_curve_points(geometry, sagitta, path, where), path, where),
                          where))
        else:
            meshes.extend(_meshes(rhino3dm, geometry))
    source = CurveSource(path, assign_ids(found, path), declared)
    if unnamed:
        source.notes.append(f"{path}: ignored {len(unnamed)} curve(s) whose name and layer name no family "
                            f"({unnamed[0]}{', ...' if len(unnamed) > 1 else ''})")
    source.mesh = _join(meshes, path)
    return source


def read_3dm_surface(path: str | Path) -> tuple:
    """The meshes, breps and surfaces of a .3dm file as one reference mesh, and the units it declares."""
    rhino3dm = _rhino3dm()
    model = _read_model(rhino3dm, str(path))
    meshes = [m for item in model.Objects for m in _meshes(rhino3dm, item.Geometry)]
    mesh = _join(meshes, str(path))
    if mesh is None:
        raise FablineError(f"{path}: no mesh, brep or surface to use as the surface")
    return mesh, _declared_units(rhino3dm, model, str(path))


def _rhino3dm():
    try:
        import rhino3dm
    except ImportError:
        raise FablineError("reading .3dm files needs rhino3dm: pip install 'fabline[rhino]'") from None
    return rhino3dm


def _read_model(rhino3dm, path: str):
    model = rhino3dm.File3dm.Read(str(vet_input(path, "model")))
    if model is None:
        raise FablineError(f"{path}: not a readable Rhino .3dm file")
    return model


def _declared_units(rhino3dm, model, path: str) -> str | None:
    system = model.Settings.ModelUnitSystem
    names = {rhino3dm.UnitSystem.Millimeters: "mm", rhino3dm.UnitSystem.Centimeters: "cm",
             rhino3dm.UnitSystem.Meters: "m", rhino3dm.UnitSystem.Inches: "in", rhino3dm.UnitSystem.Feet: "ft"}
    if system in names:
        return names[system]
    if system in (getattr(rhino3dm.UnitSystem, "None"), rhino3dm.UnitSystem.Unset):
        return None
    raise FablineError(f"{path}: model units {system.name} are not supported (use mm, cm, m, in or ft)")


def _curve_points(curve, sagitta: float, path: str, where: str) -> np.ndarray:
    """A Rhino curve as polyline points: a degree-1 NURBS by its control points, others flattened."""
    nurbs = curve.ToNurbsCurve()
    if nurbs is None:
        raise FablineError(f"{path}: {where}: the curve has no NURBS form")
    homogeneous = np.array([(p.X, p.Y, p.Z, p.W) for p in nurbs.Points], dtype=float)
    weights = homogeneous[:, 3]
    if np.any(weights <= 0):
        raise FablineError(f"{path}: {where}: the curve has non-positive weights")
    points = homogeneous[:, :3] / weights[:, None]
    if nurbs.Degree == 1:
        return points
    knots = list(nurbs.Knots)
    spline = BSpline(points, order=nurbs.Degree + 1, knots=[knots[0], *knots, knots[-1]],
                     weights=weights.tolist() if nurbs.IsRational else None)
    return np.asarray(list(spline.flattening(sagitta)), dtype=float)


def _meshes(rhino3dm, geometry) -> list[tuple[np.ndarray, np.ndarray]]:
    """(vertices, triangles) for a mesh, or for each face of a brep or a surface."""
    if isinstance(geometry, rhino3dm.Mesh):
        return [_mesh_arrays(geometry)]
    if isinstance(geometry, rhino3dm.Brep):
        result = []
        for face in geometry.Faces:
            render = face.GetMesh(rhino3dm.MeshType.Any)
            result.append(_mesh_arrays(render) if render is not None else _sampled(face.UnderlyingSurface()))
        return result
    if isinstance(geometry, rhino3dm.Surface):
        return [_sampled(geometry)]
    return []


def _mesh_arrays(mesh) -> tuple[np.ndarray, np.ndarray]:
    vertices = np.array([(v.X, v.Y, v.Z) for v in mesh.Vertices], dtype=float).reshape(-1, 3)
    quads = np.array([tuple(mesh.Faces[i]) for i in range(len(mesh.Faces))], dtype=np.int64).reshape(-1, 4)
    return vertices, np.r_[quads[:, [0, 1, 2]], quads[quads[:, 2] != quads[:, 3]][:, [0, 2, 3]]]


def _sampled(surface) -> tuple[np.ndarray, np.ndarray]:
    """A SURFACE_GRID x SURFACE_GRID triangle grid on a surface's parameter domain."""
    u_domain, v_domain = surface.Domain(0), surface.Domain(1)
    us = np.linspace(u_domain.T0, u_domain.T1, SURFACE_GRID)
    vs = np.linspace(v_domain.T0, v_domain.T1, SURFACE_GRID)
    vertices = np.array([(p.X, p.Y, p.Z) for p in (surface.PointAt(u, v) for u in us for v in vs)], dtype=float)
    index = np.arange(SURFACE_GRID * SURFACE_GRID).reshape(SURFACE_GRID, SURFACE_GRID)
    a, b, c, d = index[:-1, :-1].ravel(), index[1:, :-1].ravel(), index[1:, 1:].ravel(), index[:-1, 1:].ravel()
    return vertices, np.r_[np.c_[a, b, c], np.c_[a, c, d]]


def _join(meshes: list[tuple[np.ndarray, np.ndarray]], path: str):
    if not meshes:
        return None
    offsets = np.cumsum([0] + [len(v) for v, _ in meshes[:-1]])
    vertices = np.concatenate([v for v, _ in meshes])
    faces = np.concatenate([f + offset for (_, f), offset in zip(meshes, offsets)])
    return mesh_from_arrays(vertices, faces, path)
