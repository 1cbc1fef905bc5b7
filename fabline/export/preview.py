"""The cut-order preview of one sheet: an SVG at 1:1 drawn from the G-code program itself (read back with the
controller's own parser, `fabline.link`), so it shows what the machine will do rather than what fabline meant.

The cut contours are drawn in a colour running from blue (cut first) through purple to red (cut last) and
numbered in order at their start point, the engraving (which comes first) thinner in green, and every travel
move (G0) as a dashed grey line. Arcs stay SVG arcs, so the lengths of the drawn paths are those of the program's moves.
"""

from __future__ import annotations

import html
import math
import re

from fabline.errors import FablineError
from fabline.machine.codes import explain_error
from fabline.machine.gcode import GcodeError, ModalState, Segment, execute
from fabline.machine.program import strip_line
from fabline.shop.layers import LAYERS

OPERATION = re.compile(r"^\s*;\s*((?:engrave|cut)-[a-z]+)\b\s*(\S*)")   # the writer's `; <operation> <part>` lines
ORDER_COLOURS = ((0x21, 0x66, 0xAC), (0x7B, 0x32, 0x94), (0xD7, 0x19, 0x1C))   # first, middle, last
TRAVEL_COLOUR = "#8C8C8C"
ENGRAVE_COLOUR = "#4DAF4A"     # engraving (marks and labels, cut before anything else) in one green
PREVIEW_SUFFIX = ".order.svg"  # beside the program: <program stem>.order.svg
NUMBER_SIZE = 8.0       # mm: legible when zoomed in, small beside a 100 mm strip


def order_colour(fraction: float) -> str:
    """The colour of the contour `fraction` (0..1) of the way along the cut order."""
    scaled = min(max(fraction, 0.0), 1.0) * (len(ORDER_COLOURS) - 1)
    k = min(int(scaled), len(ORDER_COLOURS) - 2)
    t = scaled - k
    rgb = [round(a + (b - a) * t) for a, b in zip(ORDER_COLOURS[k], ORDER_COLOURS[k + 1])]
    return "#" + "".join(f"{c:02X}" for c in rgb)


def _arc_command(segment: Segment, height: float) -> str:
    """SVG arc command(s) for a G2/G3 move, y flipped (a whole circle as two half arcs)."""
    cx, cy = segment.center[0], segment.center[1]
    x0, y0, x1, y1 = segment.start[0], segment.start[1], segment.end[0], segment.end[1]
    radius = math.hypot(x0 - cx, y0 - cy)
    a0, a1 = math.atan2(y0 - cy, x0 - cx), math.atan2(y1 - cy, x1 - cx)
    sweep = (a0 - a1) % (2 * math.pi) if segment.clockwise else (a1 - a0) % (2 * math.pi)
    flag = 1 if segment.clockwise else 0        # y flipped: the machine's clockwise is SVG's positive sweep
    if sweep < 1e-9:                            # start = end: a whole circle
        mid = segment.point_at(0.5)
        return (f"A {radius:.3f} {radius:.3f} 0 0 {flag} {mid[0]:.3f},{height - mid[1]:.3f} "
                f"A {radius:.3f} {radius:.3f} 0 0 {flag} {x1:.3f},{height - y1:.3f}")
    return f"A {radius:.3f} {radius:.3f} 0 {int(sweep > math.pi)} {flag} {x1:.3f},{height - y1:.3f}"


def cut_order_svg(data: bytes, name: str, width: float, height: float, title: str = "") -> str:
    """The preview of the program `data` (its file `name`, for errors) on a `width` x `height` mm sheet."""
    modal, position, operation = ModalState(), (0.0, 0.0, 0.0), ("", "")
    contours, travel, current = [], [], None
    for number, raw in enumerate(data.decode("ascii").split("\n"), 1):
        match = OPERATION.match(raw)
        if match:
            operation = (match.group(1), match.group(2))
        command = strip_line(raw.rstrip("\r"), f"{name}:{number}")
        if not command:
            continue
        try:
            block = execute(command, modal, position)       # as the controller reads the line
        except GcodeError as exc:
            raise FablineError(f"{name}:{number}: {explain_error(exc.code)}: {raw.strip()}") from None
        modal, position, segment = block.modal, block.position, block.segment
        if segment is None or segment.start[:2] == segment.end[:2] and segment.center is None:
            continue
        if segment.rapid:
            travel.append(segment)
            current = None
            continue
        if current is None:
            current = {"operation": operation, "start": segment.start,
                       "d": [f"M {segment.start[0]:.3f},{height - segment.start[1]:.3f}"]}
            contours.append(current)
        current["d"].append(_arc_command(segment, height) if segment.center is not None
                            else f"L {segment.end[0]:.3f},{height - segment.end[1]:.3f}")
    cuts = max(sum(not c["operation"][0].startswith("engrave") for c in contours) - 1, 1)
    paths, numbers, cut = [], [], 0
    for k, contour in enumerate(contours):
        kind, part = contour["operation"]
        engrave = kind.startswith("engrave")
        colour = ENGRAVE_COLOUR if engrave else order_colour(cut / cuts)
        label = "" if engrave else f"<title>{cut + 1}: {html.escape(kind or 'move')} {html.escape(part)}</title>"
        paths.append(f'<path d="{" ".join(contour["d"])}" stroke="{colour}" class="{"engrave" if engrave else "cut"}" '
                     f'data-order="{k + 1}">{label}</path>')
        if not engrave:
            cut += 1
            x, y = contour["start"][0], height - contour["start"][1]
            numbers.append(f'<text x="{x:.1f}" y="{y:.1f}" fill="{colour}">{cut}</text>')
    lines = "".join(f'<line x1="{s.start[0]:.3f}" y1="{height - s.start[1]:.3f}" x2="{s.end[0]:.3f}" '
                    f'y2="{height - s.end[1]:.3f}"/>' for s in travel)
    caption = html.escape(title or name)
    return (f'<svg xmlns="http://www.w3.org/2000/svg" class="cut-order" width="{width:g}mm" height="{height:g}mm" '
            f'viewBox="0 0 {width:g} {height:g}" font-family="sans-serif">'
            f"<title>{caption}: engraving green (first), then the {cut} cut contours numbered and coloured from blue "
            f"(first) to red (last); dashed grey: travel</title>"
            f'<rect x="0" y="0" width="{width:g}" height="{height:g}" fill="#fbfbf8" stroke="{LAYERS["SHEET"].rgb}" '
            f'stroke-width="1"/>'
            f'<g class="travel" stroke="{TRAVEL_COLOUR}" stroke-width="0.5" stroke-dasharray="6 4">{lines}</g>'
            '<style>.contours .cut{stroke-width:.8}.contours .engrave{stroke-width:.4}</style>'
            f'<g class="contours" fill="none">{"".join(paths)}</g>'
            f'<g class="numbers" font-size="{NUMBER_SIZE:g}" text-anchor="start">{"".join(numbers)}</g></svg>\n')
