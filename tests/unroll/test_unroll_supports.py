"""Support brackets: a fin in the tangent plane and a base plate at every support node, checked against the node's
normal by hand (incline, length, the footing below the bolt), shapely areas, and the plate sheets read back with
ezdxf."""

from __future__ import annotations

import copy
import math

import ezdxf
import numpy as np
import pytest
import shapely

from fabline.errors import FablineError
from fabline.export.dxf import drawing_text
from fabline.jobs.bom import bill_of_materials
from fabline.mechanics.materials import get_material
from fabline.nest.layout import Nesting
from fabline.nest.nester import NestOptions, nest
from fabline.shop.stock import StockItem
from fabline.unroll import UnrollOptions, unroll_network
from fabline.unroll.parts import flatten_contour, load_parts, save_parts
from fabline.unroll.supports import support_parts

H, T, PLATE, HEIGHT = 100.0, 1.5, 6.0, 150.0


@pytest.fixture(scope="module")
def pavilion(enneper):
    return unroll_network(enneper, UnrollOptions(supports=True, hardware=True))


def test_two_plates_at_every_support_node(enneper, pavilion):
    supports = sorted(nid for nid, node in enneper.nodes.items() if node.kind == "support")
    assert len(supports) == 18
    plates = pavilion.plates
    assert plates.profile["t"] == PLATE and plates.material == "steel-s235"
    assert sorted(p.id for p in plates.parts) == sorted(f"SP-{n}-{k}" for n in supports for k in "FB")
    assert not any(p.kind == "support" for p in pavilion.parts)  # the strips' sheets never see them


def test_fin_follows_the_tangent_plane_down_to_its_footing(enneper, pavilion):
    mm = enneper.in_mm()
    for fin in (p for p in pavilion.plates.parts if p.meta["plate"] == "fin"):
        node = mm.nodes[fin.meta["node"]]
        n = node.normal if node.normal[2] >= 0 else -node.normal
        incline = math.degrees(math.acos(abs(n[2])))          # the tangent plane's angle to level
        assert fin.meta["fin_angle_deg"] == pytest.approx(incline, abs=0.01)
        length = HEIGHT / math.sin(math.radians(incline))     # down the slope, 150 mm lower
        width = 1.2 * H
        outline = shapely.Polygon(flatten_contour(fin.outline)[:, :2])
        assert outline.bounds == pytest.approx((-width / 2, -length, width / 2, 30.0), abs=0.01)
        hole = shapely.Polygon(flatten_contour(fin.holes[0], 0.001)[:, :2])
        assert hole.centroid.distance(shapely.Point(0, 0)) < 1e-6
        assert hole.area == pytest.approx(math.pi * 4.25 ** 2, rel=1e-3)  # the node bolt's 8.5 mm hole
        # the bolt under the shell: h/2 + t + half the plate below the node along the normal
        bolt = np.array(fin.meta["bolt_xyz_mm"])
        assert bolt == pytest.approx(node.xyz - n * (H / 2 + T + PLATE / 2), abs=0.1)
    for base in (p for p in pavilion.plates.parts if p.meta["plate"] == "base"):
        fin = next(p for p in pavilion.plates.parts if p.id == base.id[:-1] + "F")
        foot = np.array(base.meta["footing_xyz_mm"])
        assert foot[2] == pytest.approx(fin.meta["bolt_xyz_mm"][2] - HEIGHT, abs=0.2)
        # the footing lies in the fin's plane: perpendicular to the normal through the bolt
        node = enneper.in_mm().nodes[base.meta["node"]]
        n = node.normal if node.normal[2] >= 0 else -node.normal
        assert abs(np.dot(foot - np.array(fin.meta["bolt_xyz_mm"]), n)) < 0.2
        assert len(base.holes) == 4 and shapely.Polygon(flatten_contour(base.outline)[:, :2]).area == pytest.approx(
            240.0 * 200.0)


def test_plates_go_through_parts_json_nest_on_their_own_sheets_and_read_back_from_dxf(pavilion, tmp_path):
    save_parts(pavilion, tmp_path / "parts.json")
    plates = load_parts(tmp_path / "parts.json").plates
    assert [p.id for p in plates.parts] == [p.id for p in pavilion.plates.parts]
    nesting = nest(plates, [StockItem("4000x2000", 4000.0, 2000.0)], NestOptions(time_limit=2.0)).nesting
    (tmp_path / "plates.dxf").write_text(drawing_text(nesting.sheets, {p.id: p for p in plates.parts}))
    doc = ezdxf.readfile(tmp_path / "plates.dxf")
    assert not doc.audit().has_errors
    inserts = doc.modelspace().query("INSERT")
    assert sorted(i.dxf.name for i in inserts) == sorted(p.id for p in plates.parts)
    # a base plate's block: its outline and four anchor holes, closed polylines on the cut layers
    base = next(i for i in inserts if i.dxf.name.endswith("-B"))
    cuts = [e.dxf.layer for e in doc.blocks[base.dxf.name] if e.dxftype() == "LWPOLYLINE" and e.closed
            and e.dxf.layer.startswith("CUT")]
    assert sorted(cuts) == ["CUT-INNER"] * 4 + ["CUT-OUTER"]
    # the bill: plate sheets of 6 mm S235 beside the strips' 1.5 mm ones, and the plates' mass by shapely's areas
    bom = bill_of_materials(Nesting([], "p.json"), pavilion, get_material("stainless"), nesting,
                            get_material("steel-s235"))
    area = sum(shapely.Polygon(flatten_contour(p.outline)[:, :2]).area
               - sum(shapely.Polygon(flatten_contour(h, 0.001)[:, :2]).area for h in p.holes) for p in plates.parts)
    rows = [i for i in bom["items"] if i["item"].startswith("support ")]
    assert sum(r["total_mass_kg"] for r in rows) == pytest.approx(area * PLATE * 7850e-9, rel=2e-3)
    assert bom["plates"]["thickness_mm"] == PLATE and bom["plates"]["supports"] == 18
    anchors = next(i for i in bom["items"] if i["item"].startswith("anchor bolt"))
    assert anchors["size"] == "M12" and anchors["count"] == 4 * 18


def test_a_support_fin_is_on_its_node_s_carriage_bolt_sized_for_it(enneper):
    # the lamellas run on past their end nodes to the edge, so a support node is a crossing node: its carriage bolt
    # passes the fin too. Grip washer + h + washer + fin = 1.5 + 100 + 1.5 + 6 = 109 (+1.5 under a clamp):
    # + nut 6.8 + two pitches 2.5 = 118.3 (119.8) -> the standard 120
    partset = unroll_network(enneper, UnrollOptions(supports=True, edge_members=True))
    bom = bill_of_materials(Nesting([], "p.json"), partset, get_material("stainless"))
    carriage = [i for i in bom["items"] if i["item"].startswith("carriage bolt")]
    on_fins = [(row, part) for row in carriage for part in row["per"].split("; ") if "support fin" in part]
    assert sum(int(part.split(": ")[-1].split()[0]) for _, part in on_fins) == 18
    assert {row["length_mm"] for row, _ in on_fins} == {120.0}
    assert not any("support fin" in i["per"] for i in bom["items"] if i["item"].startswith("edge bolt"))


def test_supports_need_support_nodes_and_a_sloping_surface(enneper):
    flat = copy.deepcopy(enneper)
    for node in flat.nodes.values():
        node.kind = "grid" if node.kind == "support" else node.kind
    with pytest.raises(FablineError, match="marks no node as a support"):
        unroll_network(flat, UnrollOptions(supports=True, hardware=False))
    level = copy.deepcopy(enneper)
    nid = next(n for n, node in level.nodes.items() if node.kind == "support")
    level.nodes[nid].normal = np.array([0.0, 0.0, 1.0])
    with pytest.raises(FablineError, match=rf"support node {nid}: the surface is only 0.0 degrees off level"):
        support_parts(level, 8.5, H, T, PLATE, HEIGHT, 6.0)
