"""Read lamella curves from DXF (ezdxf): 3D polylines, polylines, lines and splines, one layer per family.

Units come from the header's $INSUNITS. A curve's family comes from its layer name ("A", "B", "A-017",
"FAMILY-A"); its id from fabline's XDATA (written by `fabline.model.writers`), else from a layer that
holds that one curve only and names more than the family, else it is numbered. Splines, arcs and
bulged polylines are flattened to polylines within 0.01 mm. MESH, POLYFACE and 3DFACE entities, if
any, form the surface. Model-space 3D polylines, the bulk of a large network, are read straight from
the group codes with numpy; ezdxf reads everything else.
"""

from __future__ import annotations

import io
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import ezdxf
import numpy as np
from ezdxf import path as dxf_path
from ezdxf.filemanagement import dxf_file_info
from ezdxf.lldxf.validator import is_binary_dxf_file
from ezdxf.render import MeshBuilder

from fabline.errors import FablineError
from fabline.fileio import read_bytes, vet_input
from fabline.model.importers.curves import (SAGITTA_MM, CurveSource, NamedPoint, assign_ids, check_flattening, clean_points,
                                            family_and_id)
from fabline.model.importers.surface import mesh_from_arrays
from fabline.model.network import UNIT_TO_MM

INSUNITS = {1: "in", 2: "ft", 4: "mm", 5: "cm", 6: "m"}
"""DXF $INSUNITS codes fabline reads; 0 means unitless."""
XDATA_APP = "FABLINE"
"""XDATA application name under which fabline stores a curve's lamella id."""
CURVE_TYPES = ("LINE", "LWPOLYLINE", "POLYLINE", "SPLINE", "ARC")


def read_dxf(path: str | Path, units: str | None = None) -> CurveSource:
    """The curves of a DXF file and its mesh entities as a surface; `units` only sets the flattening tolerance
    of a file that declares none."""
    path = str(path)
    vet_input(path, "model")
    bulk = _bulk_3d_polylines(path)
    doc = _read_document(path, bulk.rest if bulk else None)
    declared = _declared_units(doc, path)
    sagitta = SAGITTA_MM / UNIT_TO_MM.get(declared or units or "m", 1000.0)
    modelspace = doc.modelspace()
    curve_entities = [e for e in modelspace.query(" ".join(CURVE_TYPES)) if not _is_mesh(e)]
    # (entity type, handle, layer, XDATA id, points, or the ezdxf entity to flatten)
    curves = [("POLYLINE", *polyline) for polyline in (bulk.polylines if bulk else [])]
    curves += [(e.dxftype(), e.dxf.handle, e.dxf.layer, _xdata_id(e), e) for e in curve_entities]
    per_layer = Counter(curve[2] for curve in curves)
    found, unnamed = [], []
    for kind, handle, layer, xdata_id, geometry in curves:
        where = f"{kind} #{handle} on layer {layer}"
        family, layer_id = family_and_id([layer])
        if family is None:
            unnamed.append(layer)
            continue
        lamella_id = xdata_id or (layer_id if per_layer[layer] == 1 else None)
        if not isinstance(geometry, np.ndarray):
            check_flattening(geometry, sagitta, path, where)
        try:
            points = geometry if isinstance(geometry, np.ndarray) else _points(geometry, sagitta)
        except (ValueError, ZeroDivisionError, IndexError, ezdxf.DXFError) as exc:
            raise FablineError(f"{path}: {where}: cannot read the curve: {exc}") from None
        found.append((family, lamella_id, clean_points(points, path, where), where))
    source = CurveSource(path, assign_ids(found, path), declared)
    if unnamed:
        layers = sorted(set(unnamed))
        source.notes.append(f"{path}: ignored {len(unnamed)} curve(s) on layers that name no family "
                            f"({', '.join(layers[:5])}{', ...' if len(layers) > 5 else ''})")
    source.mesh = _surface(modelspace, path)
    source.points = [NamedPoint([e.dxf.layer, *_xdata_values(e)], np.array(e.dxf.location, dtype=float),
                                f"POINT #{e.dxf.handle} on layer {e.dxf.layer}") for e in modelspace.query("POINT")]
    return source


def read_dxf_surface(path: str | Path) -> tuple:
    """The mesh entities of a DXF file used as a reference surface, and the units the file declares."""
    doc = _read_document(str(path))
    mesh = _surface(doc.modelspace(), str(path))
    if mesh is None:
        raise FablineError(f"{path}: no MESH, POLYFACE or 3DFACE entities to use as the surface")
    return mesh, _declared_units(doc, str(path))


def _read_document(path: str, text: str | None = None):
    """The DXF document of `path`, or of `text` (the file with its bulk 3D polylines taken out) if given."""
    if text is None:
        vet_input(path, "model")
    try:
        return ezdxf.readfile(path) if text is None else ezdxf.read(io.StringIO(text))
    except FileNotFoundError:
        raise FablineError(f"{path}: file not found") from None
    except (OSError, UnicodeDecodeError, ValueError, StopIteration, ezdxf.DXFError) as exc:
        message = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise FablineError(f"{path}: malformed DXF: {message}") from None


@dataclass
class _BulkPolylines:
    """The 3D polylines of a DXF file's ENTITIES section, read in bulk, and the file's text without them."""

    polylines: list[tuple[str, str, str | None, np.ndarray]]
    """(handle, layer, fabline XDATA id or None, vertices (n, 3)) per 3D polyline, in file order."""
    rest: str


def _bulk_3d_polylines(path: str) -> _BulkPolylines | None:
    """Read every model-space 3D POLYLINE's vertices from the group codes with numpy, or None to leave all to ezdxf.

    ezdxf builds a Python object per VERTEX (~0.1 ms each), so a 20,000-node network of 200,000 curve
    samples would take half a minute; here the file's lines are located and its group codes parsed as
    byte arrays, only the values needed are converted, and ezdxf reads what is left. Anything unusual
    (binary DXF, a group code that is not a number, odd structure) returns None: the slow path.
    """
    try:
        if is_binary_dxf_file(path):
            return None
        encoding = dxf_file_info(path).encoding
        "".encode(encoding)  # an encoding Python does not know raises LookupError here
        raw = read_bytes(path, "model")
    except (OSError, LookupError, StopIteration, ezdxf.DXFError, FablineError):  # StopIteration: an empty file
        return None
    tags = _tag_lines(raw)
    if tags is None:
        return None
    codes, value_begin, value_end, next_begin = tags

    def values(at: np.ndarray) -> list[bytes]:
        return [raw[b:e] for b, e in zip(value_begin[at].tolist(), value_end[at].tolist())]

    starts = np.flatnonzero(codes == 0)
    names = np.array(values(starts), dtype=object)
    section = [i for i in np.flatnonzero(names == b"SECTION").tolist()
               if starts[i] + 1 < len(codes) and values(starts[i:i + 1] + 1) == [b"ENTITIES"]]
    if len(section) != 1:
        return None
    first = section[0] + 1
    end = first + int(np.argmax(names[first:] == b"ENDSEC"))
    if names[end] != b"ENDSEC" or end == first:
        return None
    entity_start, kind = starts[first:end], names[first:end]
    entity_stop = starts[first + 1:end + 1]
    # each VERTEX and SEQEND belongs to the POLYLINE before it; any other entity ends that run
    polyline = kind == b"POLYLINE"
    marker = np.where(polyline, np.arange(len(kind)), np.where(np.isin(kind, [b"VERTEX", b"SEQEND"]), -2, -1))
    if marker[0] == -2:
        return None
    owner = marker[np.maximum.accumulate(np.where(marker != -2, np.arange(len(kind)), 0))]
    offset = int(entity_start[0])
    tag_entity = np.repeat(np.arange(len(kind)), entity_stop - entity_start)
    tag_code = codes[offset:entity_stop[-1]]

    def value_of(code: int, default: bytes, among: np.ndarray) -> np.ndarray:
        """The first value for `code` of each entity `among` marks, or `default`."""
        result = np.full(len(kind), default, dtype=object)
        at = np.flatnonzero((tag_code == code) & among[tag_entity])
        entity, first_at = np.unique(tag_entity[at], return_index=True)
        result[entity] = values(at[first_at] + offset)
        return result

    try:
        flags = np.array([int(v) for v in value_of(70, b"0", polyline | (kind == b"VERTEX"))], dtype=np.int64)
        paperspace = np.array([int(v) for v in value_of(67, b"0", polyline)], dtype=np.int64)
    except ValueError:
        return None
    is_3d = polyline & ((flags & 8) != 0) & ((flags & (16 | 64)) == 0) & (paperspace == 0)
    taken = is_3d[np.maximum(owner, 0)] & (owner >= 0)
    vertex = taken & (kind == b"VERTEX") & ((flags & 16) == 0)  # 16: a spline frame control point, not on the curve
    coordinates = []
    for code in (10, 20, 30):
        at = np.flatnonzero((tag_code == code) & vertex[tag_entity])
        if not np.array_equal(tag_entity[at], np.flatnonzero(vertex)):
            return None
        try:
            coordinates.append(np.array([float(v) for v in values(at + offset)]))
        except ValueError:
            return None
    points = np.stack(coordinates, axis=1).reshape(-1, 3)
    handle, layer = value_of(5, b"?", is_3d), value_of(8, b"0", is_3d)
    xdata = {}  # entity -> lamella id from fabline's XDATA: 1001 FABLINE, then 1000 id
    for at in np.flatnonzero(tag_code == 1001).tolist():
        entity = int(tag_entity[at])
        if (is_3d[entity] and at + 1 < len(tag_code) and tag_code[at + 1] == 1000 and tag_entity[at + 1] == entity
                and values(np.array([at + offset])) == [XDATA_APP.encode()]):
            xdata[entity] = values(np.array([at + 1 + offset]))[0].decode(encoding, "replace").strip()
    polylines = []
    vertex_owner = owner[vertex]
    bounds = np.searchsorted(vertex_owner, np.flatnonzero(is_3d), side="left").tolist() + [len(vertex_owner)]
    for k, (lo, hi) in zip(np.flatnonzero(is_3d), zip(bounds[:-1], bounds[1:])):
        curve = points[lo:hi]
        if flags[k] & 1 and len(curve):
            curve = np.vstack([curve, curve[:1]])
        polylines.append((handle[k].decode(encoding, "replace").strip(), layer[k].decode(encoding, "replace").strip(),
                          xdata.get(int(k)), curve))
    # the file without the taken entities: runs of kept tags, each copied as one slice of bytes
    keep = np.ones(len(codes), dtype=bool)
    keep[offset:entity_stop[-1]] = ~taken[tag_entity]
    edges = np.flatnonzero(np.diff(np.r_[False, keep, False].astype(np.int8)))
    line_begin = np.r_[0, next_begin[:-1]]
    pieces = [raw[line_begin[lo]:next_begin[hi - 1]] for lo, hi in zip(edges[0::2].tolist(), edges[1::2].tolist())]
    try:
        rest = b"".join(pieces).decode(encoding)
    except UnicodeDecodeError:
        return None
    return _BulkPolylines(polylines, rest)


def _tag_lines(raw: bytes) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """Per (code, value) line pair of an ASCII DXF: the group code, where its value's text begins and ends
    (without the line break), and where the next pair begins; None if a group code is not a number."""
    data = np.frombuffer(raw, dtype=np.uint8)
    breaks = np.flatnonzero(data == 10)
    if len(raw) and raw[-1:] != b"\n":
        breaks = np.r_[breaks, len(raw)]
    if len(breaks) == 0 or len(breaks) % 2:
        return None
    begin = np.r_[0, breaks[:-1] + 1]
    end = breaks - ((breaks > begin) & (data[np.maximum(breaks - 1, 0)] == 13))  # without a "\r"
    code_begin, code_end = begin[0::2], end[0::2]
    width = code_end - code_begin
    if width.min() < 1 or width.max() > 6:
        return None
    # read right to left: digits, then only leading spaces ("  0", " 10", "1001")
    codes = np.zeros(len(code_begin), dtype=np.int64)
    in_number = np.ones(len(code_begin), dtype=bool)
    for place in range(6):
        present = place < width
        char = np.where(present, data[np.maximum(code_end - 1 - place, 0)], 32)
        digit = (char >= 48) & (char <= 57)
        if np.any(present & ~digit & (char != 32)) or np.any(digit & ~in_number):
            return None
        in_number &= digit
        codes += np.where(digit, (char.astype(np.int64) - 48) * 10 ** place, 0)
        if place == 0 and not in_number.all():
            return None
    return codes, begin[1::2], end[1::2], np.minimum(breaks[1::2] + 1, len(raw))


def _declared_units(doc, path: str) -> str | None:
    code = int(doc.header.get("$INSUNITS", 0))
    if code == 0:
        return None
    if code not in INSUNITS:
        raise FablineError(f"{path}: $INSUNITS {code} is not supported (use mm, cm, m, in or ft)")
    return INSUNITS[code]


def _is_mesh(entity) -> bool:
    return entity.dxftype() == "POLYLINE" and (entity.is_poly_face_mesh or entity.is_polygon_mesh)


def _xdata_values(entity) -> list[str]:
    """The strings fabline stored in an entity's XDATA (a node's id and kind)."""
    return [str(value) for code, value in entity.get_xdata(XDATA_APP) if code == 1000] if entity.has_xdata(XDATA_APP) else []


def _xdata_id(entity) -> str | None:
    if entity.has_xdata(XDATA_APP):
        for code, value in entity.get_xdata(XDATA_APP):
            if code == 1000:
                return str(value)
    return None


def _points(entity, sagitta: float) -> np.ndarray:
    """The entity as polyline points in world coordinates."""
    kind = entity.dxftype()
    if kind == "POLYLINE" and entity.is_3d_polyline:
        points = [tuple(vertex.dxf.location) for vertex in entity.vertices]
        if entity.is_closed:
            points.append(points[0])
        return np.asarray(points, dtype=float)
    if kind == "SPLINE":
        if entity.dxf.degree == 1 and entity.control_point_count() and not entity.weights:
            return np.asarray(entity.control_points, dtype=float)
        return np.asarray(list(entity.construction_tool().flattening(sagitta)), dtype=float)
    return np.asarray(list(dxf_path.make_path(entity).flattening(sagitta)), dtype=float)


def _surface(modelspace, path: str):
    """All MESH, POLYFACE, polygon-mesh and 3DFACE entities as one triangle mesh, or None."""
    builders = [MeshBuilder.from_mesh(e) for e in modelspace.query("MESH")]
    builders += [MeshBuilder.from_polyface(e) for e in modelspace.query("POLYLINE") if _is_mesh(e)]
    vertices: list = []
    faces: list[list[int]] = []
    for builder in builders:
        base = len(vertices)
        vertices.extend(tuple(v) for v in builder.vertices)
        for face in builder.faces:
            faces.extend([base + face[0], base + face[i], base + face[i + 1]] for i in range(1, len(face) - 1))
    for face in modelspace.query("3DFACE"):
        corners = [tuple(v) for v in face.wcs_vertices()]
        base = len(vertices)
        vertices.extend(corners)
        faces.extend([base, base + i, base + i + 1] for i in range(1, len(corners) - 1))
    if not faces:
        return None
    return mesh_from_arrays(np.asarray(vertices, dtype=float), np.asarray(faces), path)
