"""Pictures for the report and the web page, as inline SVG: the model in 3D, nested sheets, cutting progress.

The model is drawn as an axonometric projection of its lamellas (depth-sorted, the two families in two
colours); a sheet as its placed part outlines with the part ids written on them; cutting progress as the
G-code's own motion, the executed lines in red over the labelled sheet.
"""

from __future__ import annotations

import html
import math
import os
import re
from functools import lru_cache
from pathlib import Path

import numpy as np

from typing import TYPE_CHECKING

if TYPE_CHECKING:  # the runner's web page imports this module; keep its start-up light
    from fabline.model import Network
    from fabline.nest.layout import Sheet
    from fabline.unroll.parts import Part

FAMILY_COLOURS = {"A": "#1f6fb4", "B": "#d9622b"}
LABEL_PX = 14.0  # the largest part label on a sheet picture (picture units, 900 to the sheet's width)
_VIEWBOX = re.compile(r'viewBox="([^"]+)"')


def _fmt(value: float) -> str:
    return f"{value:.1f}".rstrip("0").rstrip(".")


def _points(xy: np.ndarray) -> str:
    return " ".join(f"{_fmt(x)},{_fmt(y)}" for x, y in xy)


def model_svg(network: "Network", width: int = 520, azimuth: float = -35.0, elevation: float = 30.0) -> str:
    """The network's lamellas seen from above at an angle (azimuth/elevation in degrees), as an SVG string."""
    az, el = math.radians(azimuth), math.radians(elevation)
    right = np.array([math.cos(az), math.sin(az), 0.0])
    towards = np.array([-math.sin(az) * math.cos(el), math.cos(az) * math.cos(el), math.sin(el)])
    up = np.cross(towards, right)
    curves = [lam.curve for lam in network.lamellas]
    every = np.vstack(curves)
    screen = [np.column_stack([c @ right, -(c @ up)]) for c in curves]
    depth = [float(np.mean(c @ towards)) for c in curves]
    lo = np.min(np.vstack(screen), axis=0)
    hi = np.max(np.vstack(screen), axis=0)
    scale = (width - 40) / max(hi[0] - lo[0], 1e-9)
    height = int((hi[1] - lo[1]) * scale) + 40
    lines = []
    for k in np.argsort(depth):
        xy = (screen[k] - lo) * scale + 20
        colour = FAMILY_COLOURS.get(network.lamellas[k].family, "#555")
        lines.append(f'<polyline points="{_points(xy)}" fill="none" stroke="{colour}" stroke-width="1.6" '
                     f'stroke-linejoin="round"><title>{html.escape(network.lamellas[k].id)}</title></polyline>')
    extent = np.ptp(every, axis=0)
    caption = (f"{html.escape(network.name)}: {len(network.lamellas)} lamellas, {len(network.nodes)} nodes, "
               f"{_fmt(extent[0])} x {_fmt(extent[1])} x {_fmt(extent[2])} {network.units}")
    return (f'<svg xmlns="http://www.w3.org/2000/svg" class="model" viewBox="0 0 {width} {height + 24}" '
            f'width="{width}" height="{height + 24}"><rect width="100%" height="100%" fill="#fbfbf8"/>'
            + "".join(lines)
            + f'<text x="20" y="{height + 14}" font-size="13" fill="#333">{caption}</text></svg>')


def sheet_svg(sheet: "Sheet", parts: dict[str, "Part"], width: int = 900) -> str:
    """One nested sheet, y up as on the machine: outlines, holes and marks of every placed part, ids on top."""
    from fabline.nest.layout import place
    from fabline.unroll.parts import flatten_contour

    scale = width / sheet.width
    height = sheet.height * scale

    def to_screen(xy: np.ndarray) -> np.ndarray:
        return np.column_stack([xy[:, 0] * scale, height - xy[:, 1] * scale])

    shapes, labels = [], []
    for placement in sheet.placements:
        part = parts[placement.part]
        flat_outline = flatten_contour(part.outline, 0.5)[:, :2]
        flat_holes = tuple(flatten_contour(hole, 0.5)[:, :2] for hole in part.holes)
        outline = place(flat_outline, placement)
        d = "M" + " L".join(f"{_fmt(x)},{_fmt(y)}" for x, y in to_screen(outline)) + " Z"
        for hole in flat_holes:
            d += " M" + " L".join(f"{_fmt(x)},{_fmt(y)}" for x, y in to_screen(place(hole, placement))) + " Z"
        shapes.append(f'<path d="{d}" fill="#dfe8f1" fill-rule="evenodd" stroke="#234" stroke-width="0.6">'
                      f'<title>{html.escape(part.id)}</title></path>')
        for mark in part.marks:
            shapes.append(f'<polyline points="{_points(to_screen(place(np.asarray(mark)[:, :2], placement)))}" '
                          'fill="none" stroke="#8a5" stroke-width="0.5"/>')
        labels.append(_label(part.id, flat_outline, flat_holes, placement, scale, to_screen))
    return (f'<svg xmlns="http://www.w3.org/2000/svg" class="sheet" font-family="sans-serif" viewBox="0 0 {_fmt(width)} {_fmt(height)}" '
            f'width="{_fmt(width)}" height="{_fmt(height)}" data-sheet="{html.escape(sheet.id)}" '
            f'data-mm-per-unit="{1 / scale:.6g}">'
            f'<rect width="100%" height="100%" fill="#f7f7f2" stroke="#999"/>' + "".join(shapes) + "".join(labels)
            + "</svg>")


def _label(text: str, outline: np.ndarray, holes: tuple[np.ndarray, ...], placement, scale: float, to_screen) -> str:
    """A part's id on the sheet picture, inside its material and clear of its holes (`fabline.jobs.labels`), along
    the outline there (a strip's or edge bar's centre line), upright, at most LABEL_PX high."""
    from fabline.jobs.labels import label_spot
    from fabline.nest.layout import place

    spot = label_spot(outline, holes, text, LABEL_PX / scale)
    if spot is None:
        return ""
    ends = to_screen(place(np.array([[spot.x, spot.y], [spot.x + spot.dx, spot.y + spot.dy]]), placement))
    (cx, cy), (ex, ey) = ends
    angle = math.degrees(math.atan2(ey - cy, ex - cx))
    angle = angle - 180.0 if angle > 90.0 else angle + 180.0 if angle <= -90.0 else angle  # never upside down
    rotate = f' transform="rotate({angle:.1f} {_fmt(cx)} {_fmt(cy)})"' if abs(angle) >= 0.05 else ""
    return (f'<text x="{_fmt(cx)}" y="{_fmt(cy)}" font-size="{spot.size * scale:.2f}" text-anchor="middle" '
            f'dominant-baseline="central" fill="#102a43"{rotate}>{html.escape(text)}</text>')


@lru_cache(maxsize=32)
def _program_paths(path: str, mtime: float) -> tuple[tuple[np.ndarray, bool], ...]:
    """Per program line, the polyline it moves along (machine mm) and whether it is a rapid; cached per file."""
    from fabline.machine.gcode import ModalState
    from fabline.machine.program import load_program

    blocks = load_program(path).plan(ModalState(), (0.0, 0.0, 0.0))
    moves = []
    for block in blocks:
        segment = block.segment
        if segment is None:
            moves.append((np.empty((0, 2)), True))
            continue
        steps = 1 if segment.center is None else max(4, min(64, int(segment.length / 5)))
        xy = np.array([segment.point_at(i / steps)[:2] for i in range(steps + 1)])
        moves.append((xy, segment.rapid))
    return tuple(moves)


def progress_svg(program: str | os.PathLike, done_lines: int, background: str = "",
                 tool: tuple[float, float] | None = None) -> str:
    """The program's cutting moves over the sheet picture `background` (an SVG file, may be empty): the first
    `done_lines` lines' moves red and thick (cut), the rest grey (to do); `tool`, the machine's work position
    (x, y in the program's mm), as a blue cross-hair circle where the head is now."""
    stamp = Path(background).stat().st_mtime if background and Path(background).is_file() else 0.0
    opening, inner, moves, (origin, scale, width) = _progress_layers(str(program), os.path.getmtime(program),
                                                                     background, stamp)
    todo = "".join(f'<polyline points="{p}" fill="none" stroke="#bbb" stroke-width="0.8"/>'
                   for n, p in moves if n >= done_lines)
    done = "".join(f'<polyline points="{p}" fill="none" stroke="#d62828" stroke-width="1.8"/>'
                   for n, p in moves if n < done_lines)
    marker = ""
    if tool is not None:
        x, y, r = (tool[0] - origin[0]) * scale, (origin[1] - tool[1]) * scale, 0.012 * width
        marker = (f'<g class="tool" data-x="{tool[0]:.3f}" data-y="{tool[1]:.3f}" stroke="#0b63c4" fill="none" '
                  f'stroke-width="{_fmt(r / 4)}"><circle cx="{_fmt(x)}" cy="{_fmt(y)}" r="{_fmt(r)}"/>'
                  f'<path d="M{_fmt(x - 2 * r)} {_fmt(y)}H{_fmt(x + 2 * r)}M{_fmt(x)} {_fmt(y - 2 * r)}V{_fmt(y + 2 * r)}"/>'
                  "<title>the head, live</title></g>")
    return f'{opening} data-done="{done_lines}">{inner}<g class="progress">{todo}{done}</g>{marker}</svg>'


@lru_cache(maxsize=16)
def _progress_layers(program: str, mtime: float, background: str, stamp: float) -> tuple[str, str, tuple, tuple]:
    """The picture's opening tag, the background's content, each cutting move's screen polyline by line index and
    the machine-to-screen mapping (origin, scale, picture width); cached per program and background file, so a
    progress picture is only a string join per request."""
    moves = _program_paths(program, mtime)
    sheet = Path(background).read_text(encoding="utf-8") if stamp else ""
    match = _VIEWBOX.search(sheet)
    cuts = [xy for xy, rapid in moves if not rapid and len(xy)]
    if match and "data-mm-per-unit" in sheet:
        _, _, width, height = (float(v) for v in match.group(1).split())
        mm_per_unit = float(re.search(r'data-mm-per-unit="([^"]+)"', sheet).group(1))
        origin, scale = np.array([0.0, height * mm_per_unit]), 1 / mm_per_unit
    else:
        every = np.vstack(cuts) if cuts else np.zeros((1, 2))
        lo, hi = every.min(axis=0) - 10, every.max(axis=0) + 10
        scale = 900 / max(hi[0] - lo[0], 1e-9)
        width, height = 900.0, (hi[1] - lo[1]) * scale
        origin = np.array([lo[0], hi[1]])
    polylines = []
    for n, (xy, rapid) in enumerate(moves):
        if rapid or not len(xy):
            continue
        screen = np.column_stack([(xy[:, 0] - origin[0]) * scale, (origin[1] - xy[:, 1]) * scale])
        polylines.append((n, _points(screen)))
    inner = re.sub(r"^<svg[^>]*>|</svg>\s*$", "", sheet.strip()) if sheet else '<rect width="100%" height="100%" fill="#f7f7f2"/>'
    head = (f'<svg xmlns="http://www.w3.org/2000/svg" font-family="sans-serif" viewBox="0 0 {_fmt(width)} {_fmt(height)}" '
            f'data-lines="{len(moves)}"')
    return head, inner, tuple(polylines), (tuple(origin), scale, width)


def value_plan_svg(network: "Network", values: dict[str, float], unit: str, title: str, width: int = 520) -> str:
    """The network seen from above (x right, y up), coloured by a figure per node (dots) or per lamella (its curve;
    a lamella takes the largest of its strips, `ID` or `ID-suffix`), blue at 0 to red at the largest, with a scale."""
    top = max(max(values.values(), default=0.0), 1e-12)
    lamella_ids = {lam.id for lam in network.lamellas}
    per_lamella = {lam.id: max((v for k, v in values.items() if k == lam.id or k.startswith(lam.id + "-")), default=None)
                   for lam in network.lamellas}
    nodes = {k: v for k, v in values.items() if k in network.nodes and k not in lamella_ids}
    every = np.vstack([lam.curve[:, :2] for lam in network.lamellas])
    lo, hi = every.min(axis=0), every.max(axis=0)
    scale = (width - 40) / max(hi[0] - lo[0], 1e-9)
    height = int((hi[1] - lo[1]) * scale) + 40

    def to_screen(xy: np.ndarray) -> np.ndarray:
        return np.column_stack([(xy[:, 0] - lo[0]) * scale + 20, (hi[1] - xy[:, 1]) * scale + 20])

    shapes = []
    for lam in network.lamellas:
        value = per_lamella[lam.id]
        colour, stroke = ("#bbb", 1.0) if value is None else (_ramp(value / top), 2.4)
        tip = lam.id if value is None else f"{lam.id}: {value:.3g} {unit}"
        shapes.append(f'<polyline points="{_points(to_screen(lam.curve[:, :2]))}" fill="none" stroke="{colour}" '
                      f'stroke-width="{stroke}"><title>{html.escape(tip)}</title></polyline>')
    for node, value in nodes.items():
        (x, y), = to_screen(np.asarray(network.nodes[node].xyz)[None, :2])
        shapes.append(f'<circle cx="{_fmt(x)}" cy="{_fmt(y)}" r="4" fill="{_ramp(value / top)}" data-node="{html.escape(node)}" '
                      f'data-value="{value:.6g}"><title>{html.escape(node)}: {value:.3g} {unit}</title></circle>')
    stops = "".join(f'<stop offset="{k / 4:g}" stop-color="{_ramp(k / 4)}"/>' for k in range(5))
    bar = (f'<defs><linearGradient id="ramp">{stops}</linearGradient></defs>'
           f'<rect class="scale" x="20" y="{height + 4}" width="200" height="10" fill="url(#ramp)"/>'
           f'<text x="20" y="{height + 28}" font-size="12">0</text>'
           f'<text x="220" y="{height + 28}" font-size="12" text-anchor="end" class="scale-max">{top:.3g} {html.escape(unit)}</text>'
           f'<text x="240" y="{height + 14}" font-size="13" fill="#333">{html.escape(title)}</text>')
    return (f'<svg xmlns="http://www.w3.org/2000/svg" class="value-plan" viewBox="0 0 {width} {height + 36}" '
            f'width="{width}" height="{height + 36}" data-max="{top:.6g}" data-unit="{html.escape(unit)}">'
            f'<rect width="100%" height="100%" fill="#fbfbf8"/>' + "".join(shapes) + bar + "</svg>")


def _ramp(fraction: float) -> str:
    """Blue (0) through green and yellow to red (1), clipped to [0, 1]."""
    stops = np.array([[49, 54, 149], [69, 177, 117], [254, 224, 76], [215, 48, 39]], dtype=float)
    f = min(max(fraction, 0.0), 1.0) * (len(stops) - 1)
    k = min(int(f), len(stops) - 2)
    r, g, b = stops[k] + (stops[k + 1] - stops[k]) * (f - k)
    return f"#{int(round(r)):02x}{int(round(g)):02x}{int(round(b)):02x}"
