"""CAD specifics: Rhino .3dm curves and units, DXF splines, lines and layers, against closed-form crossings.

A semicircle of radius r crosses the line y = h at x = +/- sqrt(r^2 - h^2): the importer must find
those nodes from flattened NURBS (rhino3dm) and SPLINE (ezdxf) curves within 0.02 mm (0.01 mm sagitta
over a 66 degree crossing).
"""

from __future__ import annotations

import ezdxf
import numpy as np
import pytest
import trimesh

from fabline.errors import FablineError
from fabline.model.importers import import_model
from fabline.model.importers.curves import family_and_id
from fabline.model.writers import write_dxf
from test_import_roundtrip import assert_same_network, hypar_mesh, hypar_network

RADIUS, HEIGHTS = 0.5, (0.1, 0.2)


def expected_nodes() -> np.ndarray:
    return np.array([(s * np.sqrt(RADIUS**2 - h**2), h, 0.0) for h in HEIGHTS for s in (-1, 1)])


def plane_mesh() -> trimesh.Trimesh:
    return trimesh.Trimesh([(-2, -2, 0), (2, -2, 0), (2, 2, 0), (-2, 2, 0)], [(0, 1, 2), (0, 2, 3)])


def assert_semicircle_nodes(network) -> None:
    found = np.array(sorted((n.xyz for n in network.nodes.values()), key=lambda p: (p[1], p[0])))
    assert found.shape == (4, 3)
    assert np.abs(found - expected_nodes()).max() * network.mm_per_unit < 0.02
    assert all(np.allclose(n.normal, (0, 0, 1)) for n in network.nodes.values())


@pytest.mark.parametrize("names, family, lamella_id", [
    (["A"], "A", None), (["B-017"], "B", "B-017"), (["FAMILY-A"], "A", None), (["Family B"], "B", None),
    (["family_a-7"], "A", "family_a-7"), (["Arches"], None, None), (["Lamellas::B"], "B", None),
    (["A-3", "B"], "A", "A-3"), (["", "A"], "A", None), (["Curve", "B"], "B", None),
])
def test_family_names(names, family, lamella_id):
    assert family_and_id(names) == (family, lamella_id)


def test_dxf_spline_and_lines_cross_where_the_closed_form_says(tmp_path):
    doc = ezdxf.new()
    doc.header["$INSUNITS"] = 6  # metres
    msp = doc.modelspace()
    t = np.linspace(0, np.pi, 9)
    # a cubic spline through 9 points of the semicircle is not a circle: fit it densely instead
    fit = np.c_[RADIUS * np.cos(np.linspace(0, np.pi, 181)), RADIUS * np.sin(np.linspace(0, np.pi, 181)), 0 * t.repeat(1)[:1].repeat(181)]
    msp.add_spline(fit.tolist(), dxfattribs={"layer": "FAMILY-B"})
    for h in HEIGHTS:
        msp.add_line((-1, h, 0), (1, h, 0), dxfattribs={"layer": "FAMILY-A"})
    msp.add_line((-1, -1, 0), (1, -1, 0), dxfattribs={"layer": "Grid"})  # names no family: ignored with a note
    doc.saveas(tmp_path / "arc.dxf")
    plane_mesh().export(tmp_path / "plane.stl")
    network, report = import_model(tmp_path / "arc.dxf", surface=tmp_path / "plane.stl")
    assert network.units == "m"
    found = np.array(sorted((n.xyz for n in network.nodes.values()), key=lambda p: (p[1], p[0])))
    # the spline interpolates the circle to ~1e-9 m between fit points 1 degree apart
    assert np.abs(found - expected_nodes()).max() * 1000 < 0.02
    assert sorted(lam.id for lam in network.lamellas) == ["A-001", "A-002", "B-001"]
    assert any("ignored 1 curve(s) on layers that name no family (Grid)" in note for note in report.notes)


def test_dxf_polyline_in_millimetres_keeps_its_units(tmp_path):
    network = hypar_network(count=4).in_mm()
    write_dxf(network, tmp_path / "mm.dxf")
    mesh = hypar_mesh(count=41)
    mesh.vertices = mesh.vertices * 1000
    mesh.export(tmp_path / "surface.obj")
    imported, report = import_model(tmp_path / "mm.dxf", surface=tmp_path / "surface.obj")
    assert imported.units == "mm" and report.units == "mm"
    assert_same_network(network, imported)


rhino3dm = pytest.importorskip("rhino3dm", reason="rhino3dm (optional extra 'rhino') is not installed")


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
    assert_same_network(network, imported)


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
