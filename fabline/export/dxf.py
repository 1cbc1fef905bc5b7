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

from fabline.export.contours import stack_contours
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
    tags, offsets = _vertex_tags(vertices)
    out = []
    for handle, (layer, closed, start, end) in enumerate(pieces, first_handle):
        out.append(f"  0\nLWPOLYLINE\n  5\n{handle:X}\n330\n{owner}\n100\nAcDbEntity\n  8\n{layer}\n"
                   f"100\nAcDbPolyline\n 90\n{end - start}\n 70\n{int(closed)}\n")
        out.append(tags[offsets[start]:offsets[end]])
    return "".join(out)


def _vertex_tags(vertices: np.ndarray) -> tuple[str, list[int]]:
    """The vertex tags of every row of `vertices` (x, y rounded to 1e-6 mm, bulge) in one string, and where each
    row's tags start in it (one more offset for the end).

    The text is laid out as a character matrix, one row per vertex and a fixed column for every character a
    tag may need, and the unused columns are dropped: the coordinates are whole numbers of 1e-6 mm, so their
    shortest repr is their decimal digits without trailing zeros, worked out with integer arithmetic. Bulges
    (any float) and other coordinates get Python's repr.
    """
    count = len(vertices)
    columns = [_fixed(b" 10\n", count), *_coordinate(vertices[:, 0]), _fixed(b"\n 20\n", count),
               *_coordinate(vertices[:, 1]), _fixed(b"\n", count)]
    bulged = vertices[:, 2] != 0
    if bulged.any():
        columns += [_fixed(b" 42\n", count, bulged), _text_column(vertices[:, 2], bulged), _fixed(b"\n", count, bulged)]
    width = sum(chars.shape[1] for chars, _ in columns)
    matrix, keep = np.empty((count, width), dtype=np.uint8), np.empty((count, width), dtype=bool)
    at = 0
    for chars, mask in columns:
        matrix[:, at:at + chars.shape[1]], keep[:, at:at + chars.shape[1]] = chars, mask
        at += chars.shape[1]
    lengths = keep.sum(axis=1)
    return matrix[keep].tobytes().decode("ascii"), np.concatenate([[0], np.cumsum(lengths)]).tolist()


def _fixed(text: bytes, count: int, where: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The same characters in every row (or only in the rows `where` says), as (characters, keep mask)."""
    chars = np.broadcast_to(np.frombuffer(text, dtype=np.uint8), (count, len(text)))
    return chars, np.broadcast_to(True if where is None else where[:, None], (count, len(text)))


INTEGER_DIGITS = 9      # coordinates below 1e9 mm are written from their digits


def _coordinate(values: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """repr() of every value as character columns with keep masks: sign, integer digits, point, decimals.

    A value that is a whole number of 1e-6 (what `sheet_polylines` makes) below 1e9 is that decimal number
    (15 significant digits at most, so nothing shorter reads back as it), written without trailing zeros;
    anything else, and values below 1e-4 where repr switches to an exponent, gets repr itself."""
    count = len(values)
    magnitude = np.abs(values)
    micro = np.rint(np.minimum(magnitude, 10.0 ** INTEGER_DIGITS) * 1e6).astype(np.int64)
    odd = (micro / 1e6 != magnitude) | (magnitude >= 10.0 ** INTEGER_DIGITS) | ((micro < 100) & (micro > 0))
    micro[odd] = 0
    whole, fraction = np.divmod(micro, 10 ** 6)
    powers = 10 ** np.arange(len(str(int(whole.max(initial=0)))) - 1, -1, -1, dtype=np.int64)
    integer = ((whole[:, None] // powers) % 10 + ord("0")).astype(np.uint8)
    integer_keep = ((whole[:, None] >= powers) | (powers == 1)) & ~odd[:, None]
    decimals = ((fraction[:, None] // 10 ** np.arange(5, -1, -1, dtype=np.int64)) % 10).astype(np.uint8)
    trailing_zeros = np.cumprod(decimals[:, ::-1] == 0, axis=1).sum(axis=1)
    decimal_keep = (np.arange(6) < np.maximum(6 - trailing_zeros, 1)[:, None]) & ~odd[:, None]
    decimals += ord("0")
    columns = [_fixed(b"-", count, np.signbit(values) & ~odd), (integer, integer_keep), _fixed(b".", count, ~odd),
               (decimals, decimal_keep)]
    if odd.any():
        columns.append(_text_column(values, odd))
    return columns


def _text_column(values: np.ndarray, where: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """repr() of the values `where` says, as characters and keep mask (nothing in the other rows)."""
    texts = np.zeros(len(values), dtype="S32")
    texts[where] = [repr(value).encode() for value in values[where].tolist()]
    chars = texts.view(np.uint8).reshape(len(values), 32)
    return chars, chars != 0


def _part_shapes(part: Part) -> tuple[np.ndarray, list[tuple[str, bool, int, int]]]:
    """All contours of a part stacked into one [x, y, bulge] array (closed ones without the repeated last vertex),
    and (layer, closed, first row, end row) for each, so a placement transforms the whole part at once."""
    inner = inner_contours(part)
    layers = (["CUT-OUTER"] + ["CUT-INNER"] * len(inner) + ["ENGRAVE-MARK"] * len(part.marks)
              + ["ENGRAVE-TEXT"] * len(part.text))
    stacked, ends, closed = stack_contours([part.outline, *inner, *part.marks, *part.text])
    keep = np.ones(len(stacked), dtype=bool)
    keep[(ends - 1)[closed]] = False                       # a closed polyline does not repeat its first vertex
    kept_ends = (ends - np.cumsum(closed)).tolist()
    return stacked[keep], list(zip(layers, closed.tolist(), [0] + kept_ends[:-1], kept_ends))


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
