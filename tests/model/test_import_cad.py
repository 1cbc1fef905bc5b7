"""CAD specifics: family names, OBJ groups, DXF splines, lines, layers and units, against closed-form crossings.

A semicircle of radius r crosses the line y = h at x = +/- sqrt(r^2 - h^2): the importer must find
those nodes from flattened NURBS (rhino3dm, in test_import_rhino.py) and SPLINE (ezdxf) curves within
0.02 mm (0.01 mm sagitta over a 66 degree crossing).
"""

from __future__ import annotations

import sys

import ezdxf
import numpy as np
import pytest
import trimesh

from fabline.errors import FablineError
from fabline.model.importers import import_model
from fabline.model.importers.curves import family_and_id
from fabline.model.importers.dxf import _bulk_3d_polylines, read_dxf
from fabline.model.writers import write_dxf
from .test_import_roundtrip import assert_same_network, hypar_mesh, hypar_network

RADIUS, HEIGHTS = 0.5, (0.1, 0.2)


def expected_nodes() -> np.ndarray:
    return np.array([(s * np.sqrt(RADIUS**2 - h**2), h, 0.0) for h in HEIGHTS for s in (-1, 1)])


def plane_mesh() -> trimesh.Trimesh:
    return trimesh.Trimesh([(-2, -2, 0), (2, -2, 0), (2, 2, 0), (-2, 2, 0)], [(0, 1, 2), (0, 2, 3)])


def assert_semicircle_nodes(network) -> None:
    found = np.array(sorted((n.xyz for n in network.nodes.values()), key=lambda p: (round(p[1], 6), p[0])))
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
    angle = np.linspace(0, np.pi, 181)  # a cubic through fit points 1 degree apart stays within ~1e-9 m of the circle
    msp.add_spline(np.c_[RADIUS * np.cos(angle), RADIUS * np.sin(angle), 0 * angle].tolist(), dxfattribs={"layer": "FAMILY-B"})
    for h in HEIGHTS:
        msp.add_line((-1, h, 0), (1, h, 0), dxfattribs={"layer": "FAMILY-A"})
    msp.add_line((-1, -1, 0), (1, -1, 0), dxfattribs={"layer": "Grid"})  # names no family: ignored with a note
    doc.saveas(tmp_path / "arc.dxf")
    plane_mesh().export(tmp_path / "plane.stl")
    network, report = import_model(tmp_path / "arc.dxf", surface=tmp_path / "plane.stl")
    assert network.units == "m"
    assert_semicircle_nodes(network)
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


def test_obj_groups_name_families_and_continued_lines_join(tmp_path):
    """Rhino-style OBJ: `g` per family layer, unnamed lines numbered, `l` runs that continue one another joined."""
    text = """# two A lines in one group, one of them split over two `l` elements and a continuation line
v -1 0.1 0
v 0 0.1 0
v 1 0.1 0
v -1 0.2 0
v 1 0.2 0
g Family A
l 1 2
l 2 \\
  3
l 4 5
g B
o B-arc
"""
    angle = np.linspace(0, np.pi, 721)
    text += "".join(f"v {RADIUS * np.cos(a):.15g} {RADIUS * np.sin(a):.15g} 0\n" for a in angle)
    text += "l " + " ".join(str(6 + k) for k in range(len(angle))) + "\n"
    (tmp_path / "arc.obj").write_text(text)
    plane_mesh().export(tmp_path / "plane.obj")
    network, report = import_model(tmp_path / "arc.obj", surface=tmp_path / "plane.obj", units="m")
    assert sorted(lam.id for lam in network.lamellas) == ["A-001", "A-002", "B-arc"]
    # a polyline with 721 vertices is within 0.0012 mm of the circle: nodes within 0.02 mm
    found = np.array(sorted((n.xyz for n in network.nodes.values()), key=lambda p: (round(p[1], 6), p[0])))
    assert np.abs(found - expected_nodes()).max() * 1000 < 0.02
    assert len(network.lamellas[0].curve) == 3


def test_3dm_without_rhino3dm_says_how_to_install_it(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "rhino3dm", None)  # makes `import rhino3dm` raise ImportError
    (tmp_path / "model.3dm").write_bytes(b"")
    with pytest.raises(FablineError, match=r"reading .3dm files needs rhino3dm: pip install 'fabline\[rhino\]'"):
        import_model(tmp_path / "model.3dm")


@pytest.mark.parametrize("version", ["R12", "R2000", "R2018"])
def test_dxf_bulk_polyline_reader_agrees_with_ezdxf(tmp_path, version):
    """3D polylines are read in bulk from the group codes; ezdxf's own reading of the same file is the truth.

    The file mixes what the bulk reader must take (model-space 3D polylines, one closed) with what it must
    leave to ezdxf (a 2D polyline, a polyface mesh, a 3D polyline in paper space, lines).
    """
    doc = ezdxf.new(version)
    doc.header["$INSUNITS"] = 6
    msp = doc.modelspace()
    rng = np.random.default_rng(7)
    for k in range(3):
        points = np.c_[np.linspace(0, 1, 6 + k), rng.uniform(-1, 1, 6 + k), rng.uniform(-1, 1, 6 + k)]
        msp.add_polyline3d(points.tolist(), close=(k == 1), dxfattribs={"layer": f"A-{k}"})
    msp.add_polyline2d([(0, 0), (1, 1), (2, 0)], dxfattribs={"layer": "B-2d"})
    msp.add_line((0, 0, 0), (1, 0, 0), dxfattribs={"layer": "B-line"})
    face = msp.add_polyface()
    face.append_face([(0, 0, 0), (1, 0, 0), (1, 1, 0)])
    doc.paperspace().add_polyline3d([(0, 0, 0), (5, 5, 5)], dxfattribs={"layer": "A-paper"})
    doc.saveas(tmp_path / "mixed.dxf")

    bulk = _bulk_3d_polylines(str(tmp_path / "mixed.dxf"))
    assert bulk is not None and len(bulk.polylines) == 3  # the fast path took the three model-space 3D polylines
    source = read_dxf(tmp_path / "mixed.dxf")
    truth = ezdxf.readfile(tmp_path / "mixed.dxf")
    expected = {}
    for entity in truth.modelspace().query("POLYLINE"):
        if entity.is_3d_polyline:
            points = [tuple(v.dxf.location) for v in entity.vertices]
            expected[entity.dxf.layer] = np.array(points + points[:1] if entity.is_closed else points)
    got = {curve.id: curve.points for curve in source.curves}
    assert sorted(got) == ["A-0", "A-1", "A-2", "B-2d", "B-line"]
    for layer, points in expected.items():
        assert np.array_equal(got[layer], points)
    assert np.array_equal(got["B-2d"], [(0, 0, 0), (1, 1, 0), (2, 0, 0)])
    assert source.declared_units == (None if version == "R12" else "m")  # R12 has no $INSUNITS
    assert source.mesh is not None and len(source.mesh.faces) == 1


def test_dxf_with_windows_line_breaks_reads_the_same(tmp_path):
    network = hypar_network(count=3)
    write_dxf(network, tmp_path / "unix.dxf")
    text = (tmp_path / "unix.dxf").read_bytes()
    (tmp_path / "windows.dxf").write_bytes(text.replace(b"\n", b"\r\n"))
    assert len(_bulk_3d_polylines(str(tmp_path / "windows.dxf")).polylines) == len(network.lamellas)
    unix, windows = read_dxf(tmp_path / "unix.dxf"), read_dxf(tmp_path / "windows.dxf")
    assert [c.id for c in windows.curves] == [c.id for c in unix.curves] == [lam.id for lam in network.lamellas]
    for a, b in zip(unix.curves, windows.curves):
        assert np.array_equal(a.points, b.points)
