"""DXF drawings of nested sheets for CAM and laser software: R2010, millimetres, one layer per operation.

Contours are closed LWPOLYLINEs whose arcs stay arcs (bulges); marks and text are open LWPOLYLINEs;
the sheet outline has its own layer. The geometry is the nested part geometry itself, not kerf-offset:
CAM software applies its own kerf. A drawing is made and serialised in one call (`drawing_text`), so the
export stage can run the drawings in worker processes while it computes the toolpaths.
"""

from __future__ import annotations

import io

import ezdxf
import numpy as np
from ezdxf import units
from ezdxf.entities.lwpolyline import LWPolylinePoints

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


def new_drawing() -> ezdxf.document.Drawing:
    """An empty R2010 drawing in millimetres with the operation layers and their colours."""
    doc = ezdxf.new("R2010", setup=False)
    doc.units = units.MM
    doc.header["$MEASUREMENT"] = 1
    for name, colour in LAYERS.items():
        doc.layers.add(name, color=colour)
    return doc


def add_sheet(doc: ezdxf.document.Drawing, sheet: Sheet, parts: dict[str, Part], dx: float = 0.0) -> None:
    """Draw one sheet's outline and every placed part, shifted by `dx` mm along x."""
    msp = doc.modelspace()
    msp.add_lwpolyline([(dx, 0), (dx + sheet.width, 0), (dx + sheet.width, sheet.height), (dx, sheet.height)],
                       close=True, dxfattribs={"layer": "SHEET"})
    shapes: dict[str, tuple[np.ndarray, list[tuple[str, bool, int, int]]]] = {}
    for placement in sheet.placements:
        part = parts[placement.part]
        if part.id not in shapes:
            shapes[part.id] = _part_shapes(part)
        rows, pieces = shapes[part.id]
        placed = place(rows, placement)
        placed[:, 0] += dx
        vertices = np.zeros((len(placed), 5))          # ezdxf's LWPOLYLINE vertex: x, y, start width, end width, bulge
        vertices[:, [0, 1, 4]] = np.round(placed, 6)
        for layer, closed, start, end in pieces:
            _add_polyline(msp, vertices[start:end], closed, layer)


def _add_polyline(layout, vertices: np.ndarray, closed: bool, layer: str) -> None:
    """An LWPOLYLINE from an (N, 5) vertex array at once: ezdxf's add_lwpolyline parses every vertex in Python,
    which is most of the time of a 40 000-contour drawing; the entity's vertex array is the same numpy layout."""
    polyline = layout.add_lwpolyline([], close=closed, dxfattribs={"layer": layer})
    points = LWPolylinePoints()
    points.values = vertices
    polyline.lwpoints = points


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


def sheets_drawing(sheets: list[Sheet], parts: dict[str, Part]) -> ezdxf.document.Drawing:
    """One drawing with the sheets side by side along x, SHEET_SPACING apart (one sheet: just that sheet)."""
    doc = new_drawing()
    dx = 0.0
    for sheet in sheets:
        add_sheet(doc, sheet, parts, dx)
        dx += sheet.width + SHEET_SPACING
    return doc


def drawing_text(sheets: list[Sheet], parts: dict[str, Part]) -> str:
    """The DXF text of `sheets_drawing`: what a worker process returns for the export stage to write."""
    stream = io.StringIO()
    sheets_drawing(sheets, parts).write(stream)
    return stream.getvalue()
