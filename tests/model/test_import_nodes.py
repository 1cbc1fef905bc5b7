"""CAD import keeps every node (named node points), gives node kinds (edge-end, support from --supports), and
catches unit mistakes by the size of the model."""

from __future__ import annotations

import ezdxf
import numpy as np
import pytest

from fabline.errors import FablineError
from fabline.model.designs import enneper_network
from fabline.model.importers import import_model
from fabline.model.writers import write_dxf, write_obj
from .test_import_roundtrip import assert_same_network, enneper_mesh, hypar_mesh, hypar_network


@pytest.fixture(scope="module")
def pavilion():
    return enneper_network()


@pytest.mark.parametrize("suffix", ["obj", "dxf"])
def test_the_pavilion_written_and_imported_again_keeps_every_node(tmp_path, pavilion, suffix):
    """N000-012 and N034-012 end lamella A-012 and cross nothing: a curves-only import lost them."""
    path = tmp_path / f"pavilion.{suffix}"
    (write_obj if suffix == "obj" else write_dxf)(pavilion, path, mesh=enneper_mesh(pavilion))
    imported, report = import_model(path, units="m" if suffix == "obj" else None)
    assert_same_network(pavilion, imported)
    assert {"N000-012", "N034-012"} <= set(imported.nodes)
    assert imported.nodes["N000-012"].kind == pavilion.nodes["N000-012"].kind


def _curves_only(network, path):
    """The network's curves without node points, as CAD users draw them."""
    write_obj(network, path)
    kept = []
    skip = False
    for line in path.read_text().splitlines():
        if line.startswith("o N"):
            skip = True
        elif line.startswith("o "):
            skip = False
        if not skip:
            kept.append(line)
    path.write_text("\n".join(kept) + "\n")


def test_curves_only_import_marks_lamella_ends_and_supports_by_level(tmp_path):
    network = hypar_network()
    _curves_only(network, tmp_path / "curves.obj")
    hypar_mesh().export(tmp_path / "surface.obj")
    imported, report = import_model(tmp_path / "curves.obj", surface=tmp_path / "surface.obj", units="m")
    ends = {lam.nodes[0] for lam in imported.lamellas} | {lam.nodes[-1] for lam in imported.lamellas}
    assert {n.id for n in imported.nodes.values() if n.kind == "edge-end"} == ends
    assert all(n.kind == "grid" for n in imported.nodes.values() if n.id not in ends)
    # z = x y / 4 on the hypar: the two low corners (x = -y = +-1.5) lie at z = -0.5625
    imported, report = import_model(tmp_path / "curves.obj", surface=tmp_path / "surface.obj", units="m",
                                    supports="z<-0.3")
    supports = [n for n in imported.nodes.values() if n.kind == "support"]
    expected = [n for n in network.nodes.values() if n.xyz[2] < -0.3]
    assert len(supports) == len(expected) >= 3
    assert any("support" in line for line in report.summary())


def test_supports_inside_a_plan_polygon_or_at_named_points(tmp_path):
    network = hypar_network()
    # a DXF of curves only, plus three POINTs on a layer SUPPORTS at three corner nodes
    write_dxf(network, tmp_path / "curves.dxf", mesh=hypar_mesh())
    doc = ezdxf.readfile(tmp_path / "curves.dxf")
    for entity in list(doc.modelspace().query("POINT")):
        doc.modelspace().delete_entity(entity)
    doc.layers.add("SUPPORTS")
    corners = [network.nodes[n].xyz for n in ("N0-0", "N6-0", "N0-6")]
    for xyz in corners:
        doc.modelspace().add_point(xyz.tolist(), dxfattribs={"layer": "SUPPORTS"})
    doc.saveas(tmp_path / "marked.dxf")
    imported, _ = import_model(tmp_path / "marked.dxf", supports="SUPPORTS")
    picked = sorted(tuple(np.round(n.xyz, 6)) for n in imported.nodes.values() if n.kind == "support")
    assert picked == sorted(tuple(np.round(xyz, 6)) for xyz in corners)
    imported, _ = import_model(tmp_path / "marked.dxf", supports="1.2,1.2 2,1.2 2,2 1.2,2")
    assert [tuple(np.round(n.xyz[:2], 6)) for n in imported.nodes.values() if n.kind == "support"] == [(1.5, 1.5)]
    with pytest.raises(FablineError, match="no point objects of that layer, group or name"):
        import_model(tmp_path / "marked.dxf", supports="FOOTINGS")
    with pytest.raises(FablineError, match="no node of .* lies below z -5"):
        import_model(tmp_path / "marked.dxf", supports="z<-5")


def test_an_obj_in_millimetres_without_units_is_refused_with_the_extent(tmp_path, pavilion):
    """9 x 12 m written in millimetres and read as metres would be 12 km wide."""
    mm = pavilion.in_mm()
    write_obj(mm, tmp_path / "mm.obj", mesh=None)
    mesh = enneper_mesh(pavilion)
    mesh.vertices *= 1000.0
    mesh.export(tmp_path / "surface.obj")
    with pytest.raises(FablineError) as error:
        import_model(tmp_path / "mm.obj", surface=tmp_path / "surface.obj")
    message = str(error.value)
    assert "declares no units" in message and "give --units" in message and "--units mm makes it" in message
    imported, report = import_model(tmp_path / "mm.obj", surface=tmp_path / "surface.obj", units="mm")
    lines = report.summary()
    extent = next(line for line in lines if line.startswith("extent"))
    x, y = (float(v) for v in extent.split()[1:4:2])
    assert x == pytest.approx(np.ptp([n.xyz[0] for n in pavilion.nodes.values()]), abs=0.05)
    assert y == pytest.approx(np.ptp([n.xyz[1] for n in pavilion.nodes.values()]), abs=0.05)


def test_import_cli_prints_the_extent_and_kinds(cli, tmp_path):
    network = hypar_network()
    write_obj(network, tmp_path / "both.obj", mesh=hypar_mesh())
    code, out, err = cli("import", tmp_path / "both.obj", "--units", "m", "--supports", "z<-0.3",
                         "-o", tmp_path / "model.network.json")
    assert code == 0, err
    assert "extent 3.000 x 3.000 x" in out and "support" in out
