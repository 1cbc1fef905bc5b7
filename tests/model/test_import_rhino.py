"""Rhino .3dm import (rhino3dm, the optional extra `rhino`): NURBS curves, layers and object names, units, meshes."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from fabline.errors import FablineError
from fabline.model.importers import import_model
from .test_import_cad import HEIGHTS, RADIUS, assert_semicircle_nodes, plane_mesh
from .test_import_roundtrip import assert_same_crossings, hypar_mesh, hypar_network

import rhino3dm  # in the test extra: a fresh `pip install -e '.[test]'` has it, so a missing one fails


def rhino_model(unit_system) -> "rhino3dm.File3dm":
    model = rhino3dm.File3dm()
    model.Settings.ModelUnitSystem = unit_system
    return model


def add_layer(model, name: str) -> int:
    layer = rhino3dm.Layer()
    layer.Name = name
    return model.Layers.Add(layer)


def add_curve(model, curve, layer: int, name: str = "") -> None:
    attributes = rhino3dm.ObjectAttributes()
    attributes.LayerIndex = layer
    if name:
        attributes.Name = name
    model.Objects.AddCurve(curve, attributes)


def polyline(points) -> "rhino3dm.PolylineCurve":
    point_list = rhino3dm.Point3dList()
    for x, y, z in points:
        point_list.Add(float(x), float(y), float(z))
    return rhino3dm.PolylineCurve(point_list)


def rhino_mesh(mesh: trimesh.Trimesh) -> "rhino3dm.Mesh":
    result = rhino3dm.Mesh()
    for x, y, z in mesh.vertices.tolist():
        result.Vertices.Add(x, y, z)
    for a, b, c in mesh.faces.tolist():
        result.Faces.AddFace(a, b, c)
    return result


def test_3dm_nurbs_arc_and_polylines_with_a_mesh_in_the_file(tmp_path):
    model = rhino_model(rhino3dm.UnitSystem.Meters)
    layer_a, layer_b = add_layer(model, "A"), add_layer(model, "B")
    add_curve(model, rhino3dm.NurbsCurve.CreateFromArc(rhino3dm.Arc(rhino3dm.Point3d(0, 0, 0), RADIUS, np.pi)),
              layer_b, "B-arc")
    for k, h in enumerate(HEIGHTS):
        add_curve(model, polyline([(-1, h, 0), (0, h, 0), (1, h, 0)]), layer_a, f"A-{k}")
    model.Objects.AddMesh(rhino_mesh(plane_mesh()))
    model.Write(str(tmp_path / "arc.3dm"), 7)
    network, report = import_model(tmp_path / "arc.3dm")
    assert network.units == "m" and report.format == "3dm"
    assert sorted(lam.id for lam in network.lamellas) == ["A-0", "A-1", "B-arc"]
    assert_semicircle_nodes(network)


def test_3dm_hypar_round_trip_in_millimetres_with_a_separate_surface(tmp_path):
    network = hypar_network(count=4).in_mm()
    model = rhino_model(rhino3dm.UnitSystem.Millimeters)
    layers = {"A": add_layer(model, "Lamellas A"), "B": add_layer(model, "Lamellas B")}
    for lam in network.lamellas:  # names by object name, families by layer
        add_curve(model, polyline(lam.curve), layers[lam.family], lam.id)
    model.Write(str(tmp_path / "curves.3dm"), 7)
    mesh = hypar_mesh(count=41)
    mesh.vertices = mesh.vertices * 1000
    surface = rhino_model(rhino3dm.UnitSystem.Millimeters)
    surface.Objects.AddMesh(rhino_mesh(mesh))
    surface.Write(str(tmp_path / "surface.3dm"), 7)
    imported, report = import_model(tmp_path / "curves.3dm", surface=tmp_path / "surface.3dm")
    assert imported.units == "mm"
    assert_same_crossings(network, imported)


def test_3dm_surface_in_other_units_is_refused(tmp_path):
    network = hypar_network(count=3)
    model = rhino_model(rhino3dm.UnitSystem.Meters)
    layer_a, layer_b = add_layer(model, "A"), add_layer(model, "B")
    for lam in network.lamellas:
        add_curve(model, polyline(lam.curve), layer_a if lam.family == "A" else layer_b, lam.id)
    model.Write(str(tmp_path / "curves.3dm"), 7)
    surface = rhino_model(rhino3dm.UnitSystem.Millimeters)
    surface.Objects.AddMesh(rhino_mesh(hypar_mesh(count=11)))
    surface.Write(str(tmp_path / "surface.3dm"), 7)
    with pytest.raises(FablineError, match=r"mixed units: .*curves.3dm is in m but .*surface.3dm is in mm"):
        import_model(tmp_path / "curves.3dm", surface=tmp_path / "surface.3dm")


def test_3dm_garbage_is_named(tmp_path):
    (tmp_path / "bad.3dm").write_bytes(b"not a rhino file at all")
    with pytest.raises(FablineError, match="bad.3dm: not a readable Rhino .3dm file"):
        import_model(tmp_path / "bad.3dm")


def test_3dm_brep_without_a_render_mesh_is_sampled_for_the_normals(tmp_path):
    """A sphere brep (no render mesh in a file rhino3dm writes): normals at a meridian-equator crossing are radial."""
    model = rhino_model(rhino3dm.UnitSystem.Meters)
    layer_a, layer_b = add_layer(model, "A"), add_layer(model, "B")
    t = np.radians(np.linspace(-60, 60, 121))
    add_curve(model, polyline(np.c_[np.cos(t), 0 * t, np.sin(t)]), layer_a, "A-meridian")
    add_curve(model, polyline(np.c_[np.cos(t), np.sin(t), 0 * t]), layer_b, "B-equator")
    model.Objects.AddBrep(rhino3dm.Sphere(rhino3dm.Point3d(0, 0, 0), 1.0).ToBrep())
    model.Write(str(tmp_path / "sphere.3dm"), 7)
    network, _ = import_model(tmp_path / "sphere.3dm")
    (node,) = network.nodes.values()
    assert np.allclose(node.xyz, (1, 0, 0), atol=1e-9)
    assert abs(node.normal[0]) > np.cos(np.radians(0.5))  # radial, within half a degree
    for lamella in network.lamellas:  # one side all along: the normals never flip
        radial = np.einsum("ij,ij->i", lamella.normals, lamella.curve)
        assert np.all(np.sign(radial) == np.sign(node.normal[0])) and np.abs(radial).min() > 0.99
