"""DXF output read back with ezdxf: audit clean, R2010 in mm, layers and colours, arcs kept as bulges, exact geometry."""

from __future__ import annotations

import io
import re

import ezdxf
import numpy as np
import pytest

from fabline.export import ToolpathOptions, export_job, load_machine
from fabline.export.dxf import LAYERS, drawing_text, lwpolylines_text, new_drawing, sheet_polylines
from fabline.nest.layout import place

from test_export_helpers import every_kind_nesting, every_kind_partset


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
        for name, colour in LAYERS.items():
            assert doc.layers.get(name).color == colour


def test_layers_hold_closed_contours_marks_text_and_the_sheet(drawings):
    folder, nesting, partset = drawings
    msp = ezdxf.readfile(folder / "job_S1.dxf").modelspace()
    by_layer = {name: msp.query(f'LWPOLYLINE[layer=="{name}"]') for name in LAYERS}
    parts = partset.parts
    assert len(by_layer["CUT-OUTER"]) == len(parts)
    assert len(by_layer["CUT-INNER"]) == sum(len(p.holes) + sum(s.edge is None for s in p.slots) for p in parts)
    assert len(by_layer["ENGRAVE-MARK"]) == sum(len(p.marks) for p in parts)
    assert len(by_layer["ENGRAVE-TEXT"]) == sum(len(p.text) for p in parts)
    assert len(by_layer["SHEET"]) == 1
    assert all(e.closed for name in ("CUT-OUTER", "CUT-INNER", "SHEET") for e in by_layer[name])
    sheet = nesting.sheets[0]
    corners = np.array([p[:2] for p in by_layer["SHEET"][0].get_points("xy")])
    assert np.allclose(corners.max(axis=0) - corners.min(axis=0), [sheet.width, sheet.height])


def test_outlines_read_back_exactly_with_arcs_as_bulges(drawings):
    folder, nesting, partset = drawings
    msp = ezdxf.readfile(folder / "job_S1.dxf").modelspace()
    outers = list(msp.query('LWPOLYLINE[layer=="CUT-OUTER"]'))
    parts = {p.id: p for p in partset.parts}
    for placement in nesting.sheets[0].placements:
        part = parts[placement.part]
        outline = part.outline if part.outline.shape[1] == 3 else np.column_stack([part.outline, np.zeros(len(part.outline))])
        expected = place(outline, placement)[:-1]
        match = [e for e in outers if len(e) == len(expected)
                 and np.allclose(np.array(e.get_points("xyb")), expected, atol=1e-5)]
        assert len(match) == 1, part.id
        assert match[0].has_arc == bool(np.any(outline[:, 2]))
    curved = next(e for e in outers if e.has_arc)
    assert sorted(np.round(np.abs(np.array(curved.get_points("xyb"))[:, 2]), 6).tolist())[-1] == pytest.approx(
        np.tan(np.radians(40) / 4), abs=1e-6)


def test_all_sheets_drawing_lays_sheets_side_by_side(tmp_path):
    nesting, partset = every_kind_nesting(), every_kind_partset()
    second = type(nesting.sheets[0])("S2", 3000.0, 1500.0, nesting.sheets[0].placements[3:])
    nesting.sheets.append(second)
    export_job(nesting, {p.id: p for p in partset.parts}, load_machine("grbl-laser"), ToolpathOptions(),
               dxf_dir=tmp_path, name="two")
    msp = ezdxf.readfile(tmp_path / "two_all-sheets.dxf").modelspace()
    sheets = msp.query('LWPOLYLINE[layer=="SHEET"]')
    assert len(sheets) == 2
    xs = sorted(min(p[0] for p in s.get_points("xy")) for s in sheets)
    assert xs[1] > xs[0] + 4000.0
    assert len(msp.query('LWPOLYLINE[layer=="CUT-OUTER"]')) == 6 + 3


def test_polylines_are_written_byte_for_byte_as_ezdxf_writes_them():
    """The bulk LWPOLYLINE writer against ezdxf's own entity serialisation of the same polylines, on two sheets
    with arcs (both ways), open strokes and rotated parts: the ENTITIES sections and handle seeds agree."""
    nesting, partset = every_kind_nesting(), every_kind_partset()
    parts = {p.id: p for p in partset.parts}
    sheets = nesting.sheets + [type(nesting.sheets[0])("S2", 3000.0, 1500.0, nesting.sheets[0].placements[2:])]
    ours = drawing_text(sheets, parts)
    vertices, pieces = sheet_polylines(sheets, parts)
    doc = new_drawing()
    for layer, closed, start, end in pieces:
        doc.modelspace().add_lwpolyline(vertices[start:end].tolist(), format="xyb", close=closed,
                                        dxfattribs={"layer": layer})
    stream = io.StringIO()
    doc.write(stream)
    theirs = stream.getvalue()

    def entities(text):
        return text[text.index("  2\nENTITIES\n"):text.index("ENDSEC", text.index("  2\nENTITIES\n"))]

    def seed(text):
        return re.search(r"\$HANDSEED\n  5\n(\w+)\n", text).group(1)

    assert len(pieces) > 60 and any(vertices[:, 2] != 0) and any(not closed for _, closed, _, _ in pieces)
    assert entities(ours) == entities(theirs)
    assert seed(ours) == seed(theirs)
    doc = ezdxf.read(io.StringIO(ours))
    assert not doc.audit().has_errors
    assert len(doc.modelspace()) == len(pieces)


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
