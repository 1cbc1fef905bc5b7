"""DXF output read back with ezdxf: audit clean, R2010 in mm, layers and colours, arcs kept as bulges, exact geometry."""

from __future__ import annotations

import io
import re

import ezdxf
import numpy as np
import pytest

from fabline.export import ToolpathOptions, export_job
from fabline.export.dxf import LAYERS, _part_shapes, block_name, drawing_text, lwpolylines_text, new_drawing
from fabline.machine import load_machine
from fabline.nest.layout import place

from export_helpers import every_kind_nesting, every_kind_partset


@pytest.fixture(scope="module")
def drawings(tmp_path_factory):
    folder = tmp_path_factory.mktemp("dxf")
    nesting, partset = every_kind_nesting(), every_kind_partset()
    export_job(nesting, {p.id: p for p in partset.parts}, load_machine("grbl-laser"), ToolpathOptions(kerf=0.2),
               dxf_dir=folder, name="job")
    return folder, nesting, partset


def test_every_file_passes_the_audit_in_r2010_millimetres(drawings):
    folder, _, _ = drawings
    files = sorted(folder.glob("*.dxf"))
    assert [f.name for f in files] == ["job_S1.dxf", "job_all-sheets.dxf"]
    for path in files:
        doc = ezdxf.readfile(path)
        auditor = doc.audit()
        assert not auditor.has_errors, [str(e) for e in auditor.errors]
        assert doc.dxfversion >= "AC1024"                       # R2010 or later
        assert doc.header["$INSUNITS"] == 4                     # millimetres
        for name, layer in LAYERS.items():
            entry = doc.layers.get(name)
            assert entry.color == layer.aci and entry.rgb == _rgb(layer.rgb)
            assert entry.dxf.plot == (name != "SHEET")
        assert ezdxf.colors.aci2rgb(LAYERS["CUT-OUTER"].aci) == _rgb(LAYERS["CUT-OUTER"].rgb)


def _rgb(text):
    return tuple(int(text[k:k + 2], 16) for k in (1, 3, 5))


def _placed_entities(msp):
    """Per INSERT: its block name and the polylines it places on the sheet (ezdxf's own block transform)."""
    return {insert.dxf.name: list(insert.virtual_entities()) for insert in msp.query("INSERT")}


def test_every_part_is_a_block_of_its_own_inserted_at_its_placement(drawings):
    folder, nesting, partset = drawings
    doc = ezdxf.readfile(folder / "job_S1.dxf")
    msp = doc.modelspace()
    inserts = list(msp.query("INSERT"))
    sheet = nesting.sheets[0]
    assert [i.dxf.name for i in inserts] == [block_name(p.part) for p in sheet.placements]
    for insert, placement in zip(inserts, sheet.placements):
        assert (insert.dxf.insert.x, insert.dxf.insert.y) == pytest.approx((placement.x, placement.y))
        assert insert.dxf.rotation == pytest.approx(placement.rotation)
    parts = {p.id: p for p in partset.parts}
    for name, entities in _placed_entities(msp).items():
        part = next(parts[p.part] for p in sheet.placements if block_name(p.part) == name)
        layers = [e.dxf.layer for e in entities]
        assert layers.count("CUT-OUTER") == 1
        assert layers.count("CUT-INNER") == len(part.holes) + sum(s.edge is None for s in part.slots)
        assert layers.count("ENGRAVE-MARK") == len(part.marks)
        assert layers.count("ENGRAVE-TEXT") == len(part.text)
        assert all(e.closed for e in entities if e.dxf.layer.startswith("CUT"))
    sheets = msp.query('LWPOLYLINE[layer=="SHEET"]')
    assert len(sheets) == 1 and sheets[0].closed and len(msp) == 1 + len(inserts)
    corners = np.array([p[:2] for p in sheets[0].get_points("xy")])
    assert np.allclose(corners.max(axis=0) - corners.min(axis=0), [sheet.width, sheet.height])


def test_block_names_are_valid_and_distinct():
    assert block_name("A-013-R.4") == "A-013-R.4"
    assert block_name("W<1>/2 x") == "W_1__2_x"
    assert block_name("*U1") == "_U1"
    assert block_name("a b", {"a_b"}) == "a_b~2"


def test_outlines_read_back_exactly_with_arcs_as_bulges(drawings):
    folder, nesting, partset = drawings
    placed = _placed_entities(ezdxf.readfile(folder / "job_S1.dxf").modelspace())
    parts = {p.id: p for p in partset.parts}
    for placement in nesting.sheets[0].placements:
        part = parts[placement.part]
        outline = part.outline if part.outline.shape[1] == 3 else np.column_stack([part.outline, np.zeros(len(part.outline))])
        expected = place(outline, placement)[:-1]
        outer = next(e for e in placed[block_name(part.id)] if e.dxf.layer == "CUT-OUTER")
        assert np.allclose(np.array(outer.get_points("xyb")), expected, atol=1e-5), part.id
        assert outer.has_arc == bool(np.any(outline[:, 2]))
    curved = next(e for entities in placed.values() for e in entities if e.dxf.layer == "CUT-OUTER" and e.has_arc)
    assert sorted(np.round(np.abs(np.array(curved.get_points("xyb"))[:, 2]), 6).tolist())[-1] == pytest.approx(
        np.tan(np.radians(40) / 4), abs=1e-6)


def test_all_sheets_drawing_lays_sheets_side_by_side(tmp_path):
    nesting, partset = every_kind_nesting(), every_kind_partset()
    second = type(nesting.sheets[0])("S2", 3000.0, 1500.0, nesting.sheets[0].placements[3:])
    nesting.sheets.append(second)
    parts = {p.id: p for p in partset.parts}
    for part_id in [p.part for p in second.placements]:        # a part id appears once in a nesting
        parts[part_id + "'"] = parts[part_id]
    second.placements = [type(p)(p.part + "'", p.x, p.y, p.rotation) for p in second.placements]
    export_job(nesting, parts, load_machine("grbl-laser"), ToolpathOptions(), dxf_dir=tmp_path, name="two")
    doc = ezdxf.readfile(tmp_path / "two_all-sheets.dxf")
    assert not doc.audit().has_errors
    msp = doc.modelspace()
    sheets = msp.query('LWPOLYLINE[layer=="SHEET"]')
    assert len(sheets) == 2
    xs = sorted(min(p[0] for p in s.get_points("xy")) for s in sheets)
    assert xs[1] > xs[0] + 4000.0
    placed = _placed_entities(msp)
    assert len(placed) == 6 + 3
    assert min(min(x for x, _ in e.get_points("xy")) for name, es in placed.items() if name.endswith("'")
               for e in es) > xs[1]


def test_drawings_are_written_byte_for_byte_as_ezdxf_writes_them():
    """The bulk writer against ezdxf's own serialisation of the same drawing (sheet outlines, a block per part with
    its polylines, an insert per placement), on two sheets with arcs (both ways), open strokes and rotated parts:
    the whole texts agree."""
    nesting, partset = every_kind_nesting(), every_kind_partset()
    parts = {p.id: p for p in partset.parts}
    second = type(nesting.sheets[0])("S2", 3000.0, 1500.0, [type(p)(p.part, p.x, p.y, p.rotation)
                                                             for p in nesting.sheets[0].placements[2:]])
    for placement in second.placements:
        parts[placement.part + "-2"] = parts[placement.part]
        placement.part += "-2"
    sheets = nesting.sheets + [second]
    ours = drawing_text(sheets, parts)
    doc = new_drawing()
    msp, dx = doc.modelspace(), 0.0
    for sheet in sheets:
        msp.add_lwpolyline([(dx, 0), (dx + sheet.width, 0), (dx + sheet.width, sheet.height), (dx, sheet.height)],
                           format="xy", close=True, dxfattribs={"layer": "SHEET"})
        for placement in sheet.placements:
            block = doc.blocks.new(block_name(placement.part))
            vertices, pieces = _part_shapes(parts[placement.part])
            for layer, closed, start, end in pieces:
                block.add_lwpolyline(vertices[start:end].tolist(), format="xyb", close=closed, dxfattribs={"layer": layer})
            msp.add_blockref(block.name, (placement.x + dx, placement.y),
                             dxfattribs={"rotation": placement.rotation} if placement.rotation else {})
        dx += sheet.width + 200.0
    stream = io.StringIO()
    doc.write(stream)
    theirs = stream.getvalue()
    assert sum(len(s.placements) for s in sheets) > 8 and any(p.rotation for s in sheets for p in s.placements)

    def written_here(text):
        """The block records, the BLOCKS section and the ENTITIES section (the rest is ezdxf's own output,
        which differs between two documents in time stamps, GUIDs and the order of CLASSES)."""
        spans = []
        for opening, closing in (("  2\nBLOCK_RECORD\n", "ENDTAB"), ("  2\nBLOCKS\n", "ENDSEC"),
                                 ("  2\nENTITIES\n", "ENDSEC")):
            start = text.index(opening)
            spans.append(text[start:text.index(closing, start)])
        return spans

    def seed(text):
        return re.search(r"\$HANDSEED\n  5\n(\w+)\n", text).group(1)

    assert written_here(ours) == written_here(theirs)
    assert seed(ours) == seed(theirs)
    doc = ezdxf.read(io.StringIO(ours))
    assert not doc.audit().has_errors


def test_coordinates_that_repr_writes_otherwise_are_still_written_as_ezdxf_writes_them():
    """The digit-by-digit writer covers whole numbers of 1e-6; the rest (exponent notation below 1e-4, huge or
    unrounded values, negative zero) must still come out as ezdxf's own serialisation writes them."""
    vertices = np.array([[0.0, -0.0, 0.0], [5e-05, -1e-06, 0.25], [1e-4, 0.000123, -1e-07], [123456789012.5, 7.0, 0.0],
                         [1234.5678901234, -99.000001, 0.4142135623730951], [4000.0, 2000.5, 0.0]])
    ours = lwpolylines_text(vertices, [("CUT-OUTER", True, 0, 3), ("ENGRAVE-TEXT", False, 3, 6)], 0x30, "1F")
    doc = new_drawing()
    for layer, closed, rows in (("CUT-OUTER", True, vertices[:3]), ("ENGRAVE-TEXT", False, vertices[3:])):
        doc.modelspace().add_lwpolyline(rows.tolist(), format="xyb", close=closed, dxfattribs={"layer": layer})
    stream = io.StringIO()
    doc.write(stream)
    theirs = stream.getvalue()
    body = theirs[theirs.index("  0\nLWPOLYLINE\n"):theirs.index("  0\nENDSEC", theirs.index("  2\nENTITIES\n"))]
    assert re.sub(r"  5\n\w+\n330\n\w+\n", "", ours) == re.sub(r"  5\n\w+\n330\n\w+\n", "", body)
    assert "\n5e-05\n" in ours and "\n-0.0\n" in ours and "\n123456789012.5\n" in ours
