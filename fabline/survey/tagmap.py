"""The tag map (`fabline.tagmap/1`): which AprilTag 36h11 id sits on which node, its size and mounting.

A tag lies flat on the top washer of its node, facing along the node normal, its centre offset from the
node by `mount_offset_mm` along that normal; so node = tag centre - offset * tag normal. Tag size is the
edge of the tag's outer black square (the AprilTag convention). Also writes printable tag sheets.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import cv2
import numpy as np

from fabline.errors import FablineError
from fabline.fileio import atomic_output, finite_number, read_json, write_json
from fabline.model import Network
from fabline.model_units import check_plausible

TAGMAP_SCHEMA = "fabline.tagmap/1"
TAG_FAMILY = "tag36h11"
TAG_DICTIONARY = cv2.aruco.DICT_APRILTAG_36h11
TAG_COUNT = 587
TAG_CELLS = 8  # the black square is 8 cells wide (6 data + border); a 1-cell white quiet zone surrounds it
# Tag sizes (the black square's edge) are millimetres everywhere; outside this range a value is taken for another unit
TAG_SIZE_RANGE_MM = (5.0, 2000.0)


@dataclass
class TagMap:
    """Tag id -> node id for one model, with the tag size and mounting offset (both mm)."""

    tag_size_mm: float
    mount_offset_mm: float
    node_of_tag: dict[int, str]
    model_name: str = ""
    family: str = TAG_FAMILY

    @cached_property
    def tag_of_node(self) -> dict[str, int]:
        """Node id -> tag id (made once: `node_of_tag` is not changed after the map is made)."""
        return {node: tag for tag, node in self.node_of_tag.items()}


def check_tag_size_mm(value: float, source: str = "--tag-size") -> float:
    """`value` as a tag size in mm; a value no tag has in mm (0.065: metres; 6500: a tenth of a mm) raises naming
    `source` and what to give instead."""
    return check_plausible(value, "mm", TAG_SIZE_RANGE_MM, source, "a tag's black-square edge")


MAX_MOUNT_OFFSET_MM = 1e6
"""Largest |mounting offset| (1 km in mm): more than any structure is large, so a tag that far is a mistake."""


def check_mount_offset_mm(value: float, source: str = "--mount-offset") -> float:
    """`value` as a tag's mounting offset in mm; a non-finite one or one beyond MAX_MOUNT_OFFSET_MM raises naming
    `source`."""
    if not finite_number(value) or abs(value) > MAX_MOUNT_OFFSET_MM:
        raise FablineError(f"{source}: {value} mm is not a mounting offset; the tag face sits within "
                           f"{MAX_MOUNT_OFFSET_MM:g} mm (1 km) of its node, typically 10-50 mm")
    return float(value)


def make_tag_map(network: Network, tag_size_mm: float = 65.0, mount_offset_mm: float = 20.0,
                 every: int = 1) -> TagMap:
    """Give tag ids 0, 1, ... to the model's nodes in order (every `every`-th node, supports always)."""
    check_tag_size_mm(tag_size_mm)
    check_mount_offset_mm(mount_offset_mm)
    if every < 1:
        raise FablineError(f"--every must be at least 1, got {every}")
    chosen = [nid for i, (nid, node) in enumerate(network.nodes.items()) if i % every == 0 or node.kind == "support"]
    if len(chosen) > TAG_COUNT:
        raise FablineError(f"model {network.name or ''}: {len(chosen)} nodes to tag but {TAG_FAMILY} has only "
                           f"{TAG_COUNT} ids; tag every 2nd node or more sparsely (--every)")
    return TagMap(float(tag_size_mm), float(mount_offset_mm), {i: nid for i, nid in enumerate(chosen)},
                  network.name)


def tagmap_to_dict(tag_map: TagMap) -> dict:
    """The JSON-ready form of a tag map."""
    return {
        "schema": TAGMAP_SCHEMA,
        "family": tag_map.family,
        "model": tag_map.model_name,
        "tag_size_mm": tag_map.tag_size_mm,
        "mount_offset_mm": tag_map.mount_offset_mm,
        "tags": [{"tag": tag, "node": node} for tag, node in sorted(tag_map.node_of_tag.items())],
    }


def tagmap_from_dict(data: object, source: str = "tag map") -> TagMap:
    """Build a tag map from JSON; a duplicate tag id, an id outside 36h11 or a bad field raises naming it."""
    if not isinstance(data, dict) or data.get("schema") != TAGMAP_SCHEMA:
        raise FablineError(f"{source}: not a {TAGMAP_SCHEMA} file (missing or wrong 'schema')")
    if data.get("family", TAG_FAMILY) != TAG_FAMILY:
        raise FablineError(f"{source}: family {data.get('family')!r} is not supported (use {TAG_FAMILY})")
    numbers = {}
    for key in ("tag_size_mm", "mount_offset_mm"):
        value = data.get(key)
        if not finite_number(value):
            raise FablineError(f"{source}: field '{key}' must be a number")
        numbers[key] = float(value)
    check_tag_size_mm(numbers["tag_size_mm"], f"{source}: field 'tag_size_mm'")
    check_mount_offset_mm(numbers["mount_offset_mm"], f"{source}: field 'mount_offset_mm'")
    entries = data.get("tags")
    if not isinstance(entries, list):
        raise FablineError(f"{source}: missing or malformed 'tags' (expected a list)")
    node_of_tag: dict[int, str] = {}
    tag_of_node: dict[str, int] = {}
    for i, entry in enumerate(entries):
        if not isinstance(entry, dict) or not isinstance(entry.get("tag"), int) or "node" not in entry:
            raise FablineError(f"{source}: tags[{i}] must be an object with an integer 'tag' and a 'node'")
        tag, node = entry["tag"], str(entry["node"])
        if not 0 <= tag < TAG_COUNT:
            raise FablineError(f"{source}: tags[{i}]: tag id {tag} is outside {TAG_FAMILY} (0..{TAG_COUNT - 1})")
        if tag in node_of_tag:
            raise FablineError(f"{source}: tag {tag} is given to two nodes, {node_of_tag[tag]} and {node}")
        if node in tag_of_node:
            raise FablineError(f"{source}: node {node} carries two tags, {tag_of_node[node]} and {tag}")
        node_of_tag[tag] = node
        tag_of_node[node] = tag
    return TagMap(numbers["tag_size_mm"], numbers["mount_offset_mm"], node_of_tag, str(data.get("model", "")))


def load_tag_map(path: str | os.PathLike) -> TagMap:
    """Read a `fabline.tagmap/1` file."""
    return tagmap_from_dict(read_json(path), str(path))


def save_tag_map(tag_map: TagMap, path: str | os.PathLike) -> None:
    """Write a tag map atomically."""
    write_json(path, tagmap_to_dict(tag_map))


def check_tag_map(tag_map: TagMap, network: Network, source: str = "tag map") -> None:
    """Raise naming the tag when the map refers to a node the model does not define."""
    for tag, node in sorted(tag_map.node_of_tag.items()):
        if node not in network.nodes:
            raise FablineError(f"{source}: tag {tag} is mapped to node {node}, which the model does not define")


def tag_cells(tag_id: int) -> np.ndarray:
    """The tag as a 10 x 10 boolean cell grid (True = black), quiet zone included."""
    marker = cv2.aruco.generateImageMarker(cv2.aruco.getPredefinedDictionary(TAG_DICTIONARY), tag_id, TAG_CELLS, borderBits=1)
    return np.pad(marker < 128, 1, constant_values=False)


def tag_image(tag_id: int, pixels_per_cell: int) -> np.ndarray:
    """The tag with its quiet zone as an 8-bit image, `pixels_per_cell` pixels per cell."""
    cells = np.where(tag_cells(tag_id), 0, 255).astype(np.uint8)
    return np.kron(cells, np.ones((pixels_per_cell, pixels_per_cell), dtype=np.uint8))


# -- printable sheets -------------------------------------------------------------------------------

A4_MM = (210.0, 297.0)
PAGE_MARGIN_MM = 10.0
LABEL_MM = 8.0


def _sheet_layout(tag_map: TagMap) -> list[list[tuple[float, float, int, str]]]:
    """Pages of (x, y, tag, node): the top-left corner of each tag's quiet zone in mm from the page's top left."""
    cell = tag_map.tag_size_mm / TAG_CELLS
    box = 10 * cell
    pitch_x, pitch_y = box + 4.0, box + LABEL_MM + 4.0
    columns = int((A4_MM[0] - 2 * PAGE_MARGIN_MM + 4.0) // pitch_x)
    rows = int((A4_MM[1] - 2 * PAGE_MARGIN_MM + 4.0) // pitch_y)
    if columns < 1 or rows < 1:
        raise FablineError(f"tags of {tag_map.tag_size_mm} mm do not fit on an A4 page")
    per_page = columns * rows
    entries = sorted(tag_map.node_of_tag.items())
    pages = []
    for start in range(0, len(entries), per_page):
        page = []
        for k, (tag, node) in enumerate(entries[start:start + per_page]):
            row, col = divmod(k, columns)
            page.append((PAGE_MARGIN_MM + col * pitch_x, PAGE_MARGIN_MM + row * pitch_y, tag, node))
        pages.append(page)
    return pages


def _black_runs(cells: np.ndarray) -> list[tuple[int, int, int]]:
    """Horizontal runs of black cells as (row, first column, length), to draw few rectangles per tag."""
    runs = []
    for r, row in enumerate(cells):
        c = 0
        while c < len(row):
            if row[c]:
                start = c
                while c < len(row) and row[c]:
                    c += 1
                runs.append((r, start, c - start))
            else:
                c += 1
    return runs


def write_tag_sheets(tag_map: TagMap, out_dir: str | os.PathLike) -> list[Path]:
    """Write A4 sheets at true size as SVG pages and one multi-page PDF, plus the tag map; return the paths."""
    out_dir = Path(out_dir)
    cell = tag_map.tag_size_mm / TAG_CELLS
    pages = _sheet_layout(tag_map)
    written = []
    for number, page in enumerate(pages, 1):
        parts = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{A4_MM[0]}mm" height="{A4_MM[1]}mm" '
                 f'viewBox="0 0 {A4_MM[0]} {A4_MM[1]}">', f'<rect width="{A4_MM[0]}" height="{A4_MM[1]}" fill="white"/>']
        for x, y, tag, node in page:
            parts.append(f'<g transform="translate({x:.3f} {y:.3f})">')
            parts.append(f'<rect width="{10 * cell:.3f}" height="{10 * cell:.3f}" fill="none" stroke="#bbb" stroke-width="0.1"/>')
            parts.extend(f'<rect x="{c * cell:.4f}" y="{r * cell:.4f}" width="{n * cell:.4f}" height="{cell:.4f}"/>'
                         for r, c, n in _black_runs(tag_cells(tag)))
            parts.append(f'<text x="{5 * cell:.3f}" y="{10 * cell + 5:.3f}" font-family="Helvetica, Arial" '
                         f'font-size="4" text-anchor="middle">node {_xml(node)} · tag {tag}</text></g>')
        parts.append("</svg>\n")
        path = out_dir / f"tags-{number:03d}.svg"
        with atomic_output(path) as handle:
            handle.write("\n".join(parts))
        written.append(path)
    pdf = out_dir / "tags.pdf"
    with atomic_output(pdf, "wb") as handle:
        handle.write(_pdf(pages, cell))
    save_tag_map(tag_map, out_dir / "tagmap.json")
    return written + [pdf, out_dir / "tagmap.json"]


def _xml(text: str) -> str:
    return text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


def _pdf(pages: list[list[tuple[float, float, int, str]]], cell: float) -> bytes:
    """A minimal PDF (vector rectangles, Helvetica labels) of the sheet layout, 1 unit = 1 pt."""
    pt = 72.0 / 25.4
    height = A4_MM[1] * pt
    objects: list[bytes] = [b"", b"", b"<< /Type /Font /Subtype /Type1 /BaseFont /Helvetica >>"]
    page_ids = []
    for page in pages:
        ops = ["0 g"]
        for x, y, tag, node in page:
            for r, c, n in _black_runs(tag_cells(tag)):
                ops.append(f"{(x + c * cell) * pt:.3f} {height - (y + (r + 1) * cell) * pt:.3f} "
                           f"{n * cell * pt:.3f} {cell * pt:.3f} re f")
            label = f"node {node} / tag {tag}".replace("\\", "\\\\").replace("(", "\\(").replace(")", "\\)")
            ops.append(f"BT /F1 11 Tf {x * pt:.3f} {height - (y + 10 * cell + 5) * pt:.3f} Td ({label}) Tj ET")
        stream = "\n".join(ops).encode("latin-1", "replace")
        objects.append(b"<< /Length %d >>\nstream\n" % len(stream) + stream + b"\nendstream")
        objects.append(b"<< /Type /Page /Parent 2 0 R /MediaBox [0 0 %.3f %.3f] /Resources << /Font << /F1 3 0 R >> >> "
                       b"/Contents %d 0 R >>" % (A4_MM[0] * pt, height, len(objects)))
        page_ids.append(len(objects))
    objects[0] = b"<< /Type /Catalog /Pages 2 0 R >>"
    objects[1] = b"<< /Type /Pages /Kids [%s] /Count %d >>" % (b" ".join(b"%d 0 R" % i for i in page_ids), len(page_ids))
    out = bytearray(b"%PDF-1.4\n")
    offsets = []
    for number, body in enumerate(objects, 1):
        offsets.append(len(out))
        out += b"%d 0 obj\n" % number + body + b"\nendobj\n"
    xref = len(out)
    out += b"xref\n0 %d\n0000000000 65535 f \n" % (len(objects) + 1)
    out += b"".join(b"%010d 00000 n \n" % off for off in offsets)
    out += b"trailer\n<< /Size %d /Root 1 0 R >>\nstartxref\n%d\n%%%%EOF\n" % (len(objects) + 1, xref)
    return bytes(out)
