"""DXF drawings of nested sheets for CAM and laser software: R2010, millimetres, one layer per operation.

Contours are closed LWPOLYLINEs whose arcs stay arcs (bulges); marks and text are open LWPOLYLINEs;
every part is a block of its own (named after the part) inserted at its placement; the sheet outline
has its own layer, in LightBurn's tool-layer colour and not plotted. The geometry is the nested part geometry itself, not kerf-offset:
CAM software applies its own kerf. ezdxf makes the document (header, tables, layers, objects); the
LWPOLYLINEs, tens of thousands per drawing, are written as the same DXF tags ezdxf writes for them but
from whole vertex arrays at once, since ezdxf spends about 0.2 ms per entity serialising it tag by tag.
"""

from __future__ import annotations

import io
import re

import ezdxf
import numpy as np
from ezdxf import units

from fabline.export.contours import stack_contours
from fabline.nest.layout import Sheet, place
from fabline.shop.layers import LAYERS
from fabline.unroll.parts import Part

SHEET_SPACING = 200.0           # mm between sheets in the all-sheets drawing
ENTITIES_SECTION = "  2\nENTITIES\n"   # the tags that open sections and tables in ezdxf's output
BLOCKS_SECTION = "  2\nBLOCKS\n"
BLOCK_RECORD_SECTION = "  2\nBLOCK_RECORD\n"
ENDSEC = "  0\nENDSEC\n"
BLOCK_NAME_FORBIDDEN = re.compile(r'[<>/\\":;?*|=`,\s]')


def new_drawing() -> ezdxf.document.Drawing:
    """An empty R2010 drawing in millimetres with the operation layers and their colours."""
    doc = ezdxf.new("R2010", setup=False)
    doc.units = units.MM
    doc.header["$MEASUREMENT"] = 1
    for name, layer in LAYERS.items():
        entry = doc.layers.add(name, color=layer.aci, true_color=int(layer.rgb[1:], 16))
        entry.dxf.plot = int(layer.output)      # the sheet outline is for reference: not plotted
    return doc


def lwpolylines_text(vertices: np.ndarray, pieces: list[tuple[str, bool, int, int]], first_handle: int,
                     owner: str) -> str:
    """The DXF tags of polylines given as one [x, y, bulge] array and (layer, closed, first row, end row) per
    polyline, byte for byte as ezdxf writes LWPOLYLINEs (coordinates as Python's shortest float repr, a bulge
    tag only where it is not zero), handles counted up from `first_handle`, owned by the block record `owner`."""
    tags, offsets = _vertex_tags(vertices)
    return _polylines(tags, offsets, pieces, first_handle, owner)


def _polylines(tags: str, offsets: list[int], pieces: list[tuple[str, bool, int, int]], first_handle: int,
               owner: str) -> str:
    """The LWPOLYLINE entities of `pieces`, their vertex tags cut from `_vertex_tags`' text."""
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
    inner = part.inner_contours()
    layers = (["CUT-OUTER"] + ["CUT-INNER"] * len(inner) + ["ENGRAVE-MARK"] * len(part.marks)
              + ["ENGRAVE-TEXT"] * len(part.text))
    stacked, ends, closed = stack_contours([part.outline, *inner, *part.marks, *part.text])
    keep = np.ones(len(stacked), dtype=bool)
    keep[(ends - 1)[closed]] = False                       # a closed polyline does not repeat its first vertex
    kept_ends = (ends - np.cumsum(closed)).tolist()
    return np.round(stacked[keep], 6), list(zip(layers, closed.tolist(), [0] + kept_ends[:-1], kept_ends))


def block_name(part_id: str, taken: set[str] = frozenset()) -> str:
    """The DXF block name of a part: its id, with the characters a block name may not hold replaced by `_`, and
    `~2`, `~3`... added should that name be `taken` already."""
    name = BLOCK_NAME_FORBIDDEN.sub("_", part_id) or "part"
    candidate, count = name, 1
    while candidate in taken:
        count += 1
        candidate = f"{name}~{count}"
    return candidate


def drawing_text(sheets: list[Sheet], parts: dict[str, Part]) -> str:
    """The DXF text of the sheets side by side along x, SHEET_SPACING apart (one sheet: just that sheet), what a
    worker process returns for the export stage to write.

    Each sheet's outline is a polyline in model space; each placed part is a block named after it (its contours
    in the part's own frame, on the operation layers) inserted at its placement (x, y, rotation), so CAM software
    can move, re-nest or re-order whole parts. ezdxf makes the document; the block records, blocks, polylines and
    inserts are written here as the same tags ezdxf writes for them (`test_export_dxf` compares the bytes), with
    handles counted up from ezdxf's next one in the order ezdxf would give them."""
    doc = new_drawing()
    handle = int(str(doc.entitydb.handles), 16)
    model, table_handle = doc.modelspace().layout_key, doc.block_records.head.dxf.handle
    shapes: dict[str, tuple[np.ndarray, list[tuple[str, bool, int, int]]]] = {}
    rows, plan, row, dx = [], [], 0, 0.0
    for sheet in sheets:
        rows.append(np.array([[dx, 0.0, 0.0], [dx + sheet.width, 0.0, 0.0], [dx + sheet.width, sheet.height, 0.0],
                              [dx, sheet.height, 0.0]]))
        outline, placed, row = ("SHEET", True, row, row + 4), [], row + 4
        for placement in sheet.placements:
            if placement.part not in shapes:
                shapes[placement.part] = _part_shapes(parts[placement.part])
            local, pieces = shapes[placement.part]
            rows.append(local)
            placed.append((placement, dx, [(layer, closed, row + start, row + end) for layer, closed, start, end in pieces]))
            row += len(local)
        plan.append((outline, placed))
        dx += sheet.width + SHEET_SPACING
    tags, offsets = _vertex_tags(np.vstack(rows))
    records, blocks, entities, names = [], [], [], set()
    for outline, placed in plan:
        entities.append(_polylines(tags, offsets, [outline], handle, model))
        handle += 1
        for placement, dx, pieces in placed:
            name, record = block_name(placement.part, names), f"{handle:X}"
            names.add(name)
            records.append(f"  0\nBLOCK_RECORD\n  5\n{record}\n330\n{table_handle}\n100\nAcDbSymbolTableRecord\n"
                           f"100\nAcDbBlockTableRecord\n  2\n{name}\n340\n0\n 70\n0\n280\n1\n281\n0\n")
            blocks.append(f"  0\nBLOCK\n  5\n{handle + 1:X}\n330\n{record}\n100\nAcDbEntity\n  8\n0\n100\nAcDbBlockBegin\n"
                          f"  2\n{name}\n 70\n0\n 10\n0.0\n 20\n0.0\n 30\n0.0\n  3\n{name}\n  1\n\n"
                          + _polylines(tags, offsets, pieces, handle + 3, record)
                          + f"  0\nENDBLK\n  5\n{handle + 2:X}\n330\n{record}\n100\nAcDbEntity\n  8\n0\n100\nAcDbBlockEnd\n")
            handle += 3 + len(pieces)
            rotation = f" 50\n{float(placement.rotation)!r}\n" if placement.rotation else ""
            entities.append(f"  0\nINSERT\n  5\n{handle:X}\n330\n{model}\n100\nAcDbEntity\n  8\n0\n"
                            f"100\nAcDbBlockReference\n  2\n{name}\n 10\n{float(placement.x + dx)!r}\n"
                            f" 20\n{float(placement.y)!r}\n 30\n0.0\n{rotation}")
            handle += 2                                 # and one for the SEQEND ezdxf keeps (unwritten) with an insert
    doc.entitydb.handles.reset(f"{handle:X}")      # $HANDSEED counts everything written here in
    stream = io.StringIO()
    doc.write(stream)
    text = stream.getvalue()
    table = text.index(BLOCK_RECORD_SECTION)
    count = text.index(" 70\n", table) + 4
    count_end = text.index("\n", count)
    table_end = text.index("  0\nENDTAB\n", table)
    text = (text[:count] + str(int(text[count:count_end]) + len(records)) + text[count_end:table_end]
            + "".join(records) + text[table_end:])
    at = text.index(ENDSEC, text.index(BLOCKS_SECTION))
    text = text[:at] + "".join(blocks) + text[at:]
    at = text.index(ENTITIES_SECTION) + len(ENTITIES_SECTION)
    return text[:at] + "".join(entities) + text[at:]
