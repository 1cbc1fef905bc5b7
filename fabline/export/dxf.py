"""DXF drawings of nested sheets for CAM and laser software: R2010, millimetres, one layer per operation.

Contours are closed LWPOLYLINEs whose arcs stay arcs (bulges); marks and text are open LWPOLYLINEs;
the sheet outline has its own layer. The geometry is the nested part geometry itself, not kerf-offset:
CAM software applies its own kerf. ezdxf makes the document (header, tables, layers, objects); the
LWPOLYLINEs, tens of thousands per drawing, are written as the same DXF tags ezdxf writes for them but
from whole vertex arrays at once, since ezdxf spends about 0.2 ms per entity serialising it tag by tag.
"""

from __future__ import annotations

import io

import ezdxf
import numpy as np
from ezdxf import units

from fabline.export.contours import is_closed, with_bulges
from fabline.export.toolpath import inner_contours
from fabline.nest.layout import Sheet, place
from fabline.unroll.parts import Part

LAYERS = {                      # name: AutoCAD colour index
    "CUT-OUTER": 1,             # red
    "CUT-INNER": 5,             # blue
    "ENGRAVE-MARK": 3,          # green
    "ENGRAVE-TEXT": 6,          # magenta
    "SHEET": 8,                 # grey
}
SHEET_SPACING = 200.0           # mm between sheets in the all-sheets drawing
ENTITIES_SECTION = "  2\nENTITIES\n"   # the tag that opens the ENTITIES section of ezdxf's output


def new_drawing() -> ezdxf.document.Drawing:
    """An empty R2010 drawing in millimetres with the operation layers and their colours."""
    doc = ezdxf.new("R2010", setup=False)
    doc.units = units.MM
    doc.header["$MEASUREMENT"] = 1
    for name, colour in LAYERS.items():
        doc.layers.add(name, color=colour)
    return doc


def sheet_polylines(sheets: list[Sheet], parts: dict[str, Part]) -> tuple[np.ndarray, list[tuple[str, bool, int, int]]]:
    """Every polyline of a drawing with the sheets side by side along x, SHEET_SPACING apart: one [x, y, bulge]
    array (closed polylines without the repeated last vertex; part vertices rounded to 1e-6 mm) and
    (layer, closed, first row, end row) per polyline, each sheet's outline first and then its parts'."""
    shapes: dict[str, tuple[np.ndarray, list[tuple[str, bool, int, int]]]] = {}
    blocks, pieces, row, dx = [], [], 0, 0.0
    for sheet in sheets:
        blocks.append(np.array([[dx, 0.0, 0.0], [dx + sheet.width, 0.0, 0.0], [dx + sheet.width, sheet.height, 0.0],
                                [dx, sheet.height, 0.0]]))
        pieces.append(("SHEET", True, row, row + 4))
        row += 4
        for placement in sheet.placements:
            part = parts[placement.part]
            if part.id not in shapes:
                shapes[part.id] = _part_shapes(part)
            rows, part_pieces = shapes[part.id]
            placed = place(rows, placement)
            placed[:, 0] += dx
            blocks.append(np.round(placed, 6))
            pieces.extend((layer, closed, row + start, row + end) for layer, closed, start, end in part_pieces)
            row += len(placed)
        dx += sheet.width + SHEET_SPACING
    return np.vstack(blocks), pieces


def lwpolylines_text(vertices: np.ndarray, pieces: list[tuple[str, bool, int, int]], first_handle: int,
                     owner: str) -> str:
    """The DXF tags of the polylines `sheet_polylines` describes, byte for byte as ezdxf writes LWPOLYLINEs
    (coordinates as Python's shortest float repr, a bulge tag only where it is not zero), handles counted up
    from `first_handle`, owned by the block record `owner`."""
    vertex_tags = [f" 10\n{x!r}\n 20\n{y!r}\n 42\n{b!r}\n" if b else f" 10\n{x!r}\n 20\n{y!r}\n"
                   for x, y, b in vertices.tolist()]
    out = []
    for handle, (layer, closed, start, end) in enumerate(pieces, first_handle):
        out.append(f"  0\nLWPOLYLINE\n  5\n{handle:X}\n330\n{owner}\n100\nAcDbEntity\n  8\n{layer}\n"
                   f"100\nAcDbPolyline\n 90\n{end - start}\n 70\n{int(closed)}\n")
        out.extend(vertex_tags[start:end])
    return "".join(out)


def _part_shapes(part: Part) -> tuple[np.ndarray, list[tuple[str, bool, int, int]]]:
    """All contours of a part stacked into one [x, y, bulge] array (closed ones without the repeated last vertex),
    and (layer, closed, first row, end row) for each, so a placement transforms the whole part at once."""
    shapes = ([(part.outline, "CUT-OUTER")] + [(c, "CUT-INNER") for c in inner_contours(part)]
              + [(m, "ENGRAVE-MARK") for m in part.marks] + [(t, "ENGRAVE-TEXT") for t in part.text])
    blocks, pieces, row = [], [], 0
    for contour, layer in shapes:
        contour = with_bulges(contour)
        closed = is_closed(contour)
        block = contour[:-1] if closed else contour
        blocks.append(block)
        pieces.append((layer, closed, row, row + len(block)))
        row += len(block)
    return np.vstack(blocks), pieces


def drawing_text(sheets: list[Sheet], parts: dict[str, Part]) -> str:
    """The DXF text of the sheets side by side (one sheet: just that sheet), what a worker process returns for
    the export stage to write: ezdxf's document with the polylines' handles reserved, the polylines put into
    its (otherwise empty) ENTITIES section."""
    vertices, pieces = sheet_polylines(sheets, parts)
    doc = new_drawing()
    first_handle = int(str(doc.entitydb.handles), 16)
    doc.entitydb.handles.reset(f"{first_handle + len(pieces):X}")      # $HANDSEED counts the polylines in
    stream = io.StringIO()
    doc.write(stream)
    text = stream.getvalue()
    at = text.index(ENTITIES_SECTION) + len(ENTITIES_SECTION)
    return text[:at] + lwpolylines_text(vertices, pieces, first_handle, doc.modelspace().layout_key) + text[at:]
