"""Printable pages of the assembly plan (SVG, A3 landscape, millimetres): one per lamella, and an overview.

A lamella's page: a key plan of the whole shell from above with the lamella in red and its segment(s) shaded;
its pieces with their segment, step and length; and each strip drawn straight along the page, its pieces end to
end with the seams' overlaps marked, and at every slot the crossing lamella's label and the node id. The
overview numbers the segments on the key plan and marks the crossings made on site. The same pages, in the same
order, also go into one vector PDF beside them (`fabline.assembly.pdf`).
"""

from __future__ import annotations

import html
import os
from pathlib import Path

import numpy as np
from shapely.geometry import LineString, MultiLineString, Point
from shapely.ops import unary_union

from fabline.assembly.pdf import PDF, write_pdf
from fabline.assembly.pieces import Piece
from fabline.assembly.plan import AssemblyPlan
from fabline.fileio import atomic_output

PAGE = (420.0, 297.0)  # A3 landscape, mm
MARGIN = 12.0
SHADES = ("#cfe3f7", "#f7dccf", "#d6efd2", "#efe3b8", "#e2d4f0", "#f4cfe0", "#cdeceb", "#e8e8cc", "#dcdcdc")
OVERVIEW = "overview.svg"


def page_name(lamella: str) -> str:
    """A lamella's page file name (lamella ids are file-name safe: `fabline.naming`)."""
    return f"lamella-{lamella}.svg"


def write_pages(plan: AssemblyPlan, folder: str | os.PathLike) -> list[Path]:
    """Write the overview and one page per lamella of the network into `folder`, and all of them as its `plan.pdf`;
    returns the SVG pages' paths, overview first."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    keyplan = _KeyPlan(plan)
    pages = [(folder / OVERVIEW, overview_svg(plan, keyplan))]
    pages += [(folder / page_name(lam.id), lamella_svg(plan, lam.id, keyplan)) for lam in plan.network.lamellas]
    for path, text in pages:
        with atomic_output(path) as handle:
            handle.write(text)
    write_pdf([text for _, text in pages], folder / PDF, PAGE)
    return [path for path, _ in pages]


def _e(text: object) -> str:
    return html.escape(str(text), quote=True)


def _f(value: float) -> str:
    return f"{value:.2f}".rstrip("0").rstrip(".")


def _text(x: float, y: float, text: str, size: float = 3.0, anchor: str = "start", rotate: float = 0.0,
          weight: str = "normal", table: bool = False) -> str:
    """A text line; `table` sets it in a monospaced font with its spaces kept, so that columns line up."""
    turn = f' transform="rotate({_f(rotate)} {_f(x)} {_f(y)})"' if rotate else ""
    mono = ' font-family="DejaVu Sans Mono, Consolas, monospace" xml:space="preserve"' if table else ""
    return (f'<text x="{_f(x)}" y="{_f(y)}" font-size="{_f(size)}" text-anchor="{anchor}" font-weight="{weight}"'
            f'{mono}{turn}>{_e(text)}</text>')


def _svg(body: list[str], title: str) -> str:
    w, h = PAGE
    return (f'<svg xmlns="http://www.w3.org/2000/svg" width="{_f(w)}mm" height="{_f(h)}mm" viewBox="0 0 {_f(w)} '
            f'{_f(h)}" font-family="DejaVu Sans, Arial, sans-serif"><title>{_e(title)}</title>'
            f'<rect width="{_f(w)}" height="{_f(h)}" fill="#fff"/>' + "".join(body) + "</svg>\n")


class _KeyPlan:
    """The shell from above fitted into a box of the page: lamella centrelines and each segment's shaded patch,
    drawn once per box and colour (every page shares them)."""

    def __init__(self, plan: AssemblyPlan) -> None:
        network = plan.network
        k = network.mm_per_unit
        self.curves = {lam.id: _thinned(np.asarray(lam.curve, dtype=float)[:, :2] * k) for lam in network.lamellas}
        xy = np.concatenate(list(self.curves.values()))
        self.low, self.high = xy.min(axis=0), xy.max(axis=0)
        steps = [np.linalg.norm(plan.plan[a] - plan.plan[b]) for lam in network.lamellas
                 for a, b in zip(lam.nodes[:-1], lam.nodes[1:])]
        reach = 0.5 * float(np.median(steps)) if steps else 1.0
        self.patches = []
        for nodes in plan.segments:
            inside = set(nodes)
            lines = [LineString([plan.plan[a], plan.plan[b]]) for lam in network.lamellas
                     for a, b in zip(lam.nodes[:-1], lam.nodes[1:]) if a in inside and b in inside]
            shape = unary_union(([MultiLineString(lines).buffer(reach, 4)] if lines else [])
                                + [Point(plan.plan[n]).buffer(reach, 4) for n in nodes])
            self.patches.append(shape.simplify(reach / 8.0))
        self._drawn: dict[tuple, str] = {}

    def box(self, x: float, y: float, width: float, height: float):
        """A function from plan mm to page mm that fits the plan into the box (y up on the plan, down on the page)."""
        span = np.maximum(self.high - self.low, 1e-9)
        scale = min(width / span[0], height / span[1])
        ox = x + (width - scale * span[0]) / 2.0
        oy = y + (height + scale * span[1]) / 2.0

        def to_page(points: np.ndarray) -> np.ndarray:
            points = np.atleast_2d(points)
            return np.column_stack([ox + scale * (points[:, 0] - self.low[0]), oy - scale * (points[:, 1] - self.low[1])])

        to_page.key = (x, y, width, height)
        return to_page

    def draw(self, to_page, shaded: dict[int, str], red: str | None = None) -> list[str]:
        """The patches in `shaded` (segment number -> colour), every centreline, and `red` on top."""
        out = [self._once(("patch", to_page.key, number, colour), lambda: self._patch(to_page, number, colour))
               for number, colour in shaded.items()]
        out.append(self._once(("lines", to_page.key), lambda: "".join(
            _polyline(to_page(curve), "#777", 0.25) for curve in self.curves.values())))
        if red is not None:
            out.append(_polyline(to_page(self.curves[red]), "#d11", 1.2))
        return out

    def _once(self, key: tuple, draw) -> str:
        if key not in self._drawn:
            self._drawn[key] = draw()
        return self._drawn[key]

    def _patch(self, to_page, number: int, colour: str) -> str:
        shape = self.patches[number - 1]
        paths = []
        for polygon in getattr(shape, "geoms", [shape]):
            rings = [polygon.exterior, *polygon.interiors]
            d = " ".join("M" + " L".join(f"{_f(px)},{_f(py)}" for px, py in to_page(np.asarray(ring.coords)))
                         + " Z" for ring in rings)
            paths.append(f'<path d="{d}" fill="{colour}" fill-rule="evenodd" stroke="#8aa" stroke-width="0.2"/>')
        return "".join(paths)


def _thinned(points: np.ndarray, most: int = 80) -> np.ndarray:
    """At most `most` points of a dense centreline (its ends kept): enough for a key plan of a few centimetres."""
    if len(points) <= most:
        return points
    keep = np.unique(np.round(np.linspace(0, len(points) - 1, most)).astype(int))
    return points[keep]


def _polyline(points: np.ndarray, colour: str, width: float) -> str:
    return (f'<polyline points="{" ".join(f"{_f(x)},{_f(y)}" for x, y in points)}" fill="none" stroke="{colour}" '
            f'stroke-width="{_f(width)}" stroke-linecap="round"/>')


def overview_svg(plan: AssemblyPlan, keyplan: _KeyPlan) -> str:
    """The segments numbered on the key plan, the crossings made on site ringed, and the segments table."""
    _, h = PAGE
    to_page = keyplan.box(MARGIN, 24.0, 260.0, h - 36.0)
    body = [_text(MARGIN, 14.0, f"{plan.network.name or 'network'}: assembly in {len(plan.segments)} segments",
                  6.0, weight="bold"),
            _text(MARGIN, 20.0, "From above (plan x to the right, y up). Shaded: the segments, built flat; red rings: "
                                "crossings made on site between segments.", 3.0)]
    body += keyplan.draw(to_page, {k: SHADES[(k - 1) % len(SHADES)] for k in range(1, len(plan.segments) + 1)})
    for c in plan.crossings:
        x, y = to_page(plan.plan[c["node"]])[0]
        body.append(f'<circle cx="{_f(x)}" cy="{_f(y)}" r="0.9" fill="none" stroke="#d11" stroke-width="0.3"/>')
    for k, nodes in enumerate(plan.segments, start=1):
        x, y = to_page(np.mean([plan.plan[n] for n in nodes], axis=0))[0]
        body.append(f'<g class="segment" data-segment="{k}">' + _text(x, y + 2.5, str(k), 8.0, "middle", weight="bold")
                    + "</g>")
    summary = plan.summary()
    x0, y = 285.0, 30.0
    body.append(_text(x0, y, "segment  nodes  pieces  strip m  on site", 3.2, weight="bold", table=True))
    for row in summary["segments"]:
        y += 5.0
        body.append(_text(x0, y, f"{row['segment']:>4}  {row['nodes']:>6}  {row['pieces']:>6}  "
                                 f"{row['strip_length_m']:>7.1f}  {row['site_crossings']:>4} x, {row['site_seams']} seams",
                          3.2, table=True))
    y += 9.0
    for line in _wrap(f"Rule: {plan.rule}.", 60):
        body.append(_text(x0, y, line, 2.6))
        y += 3.6
    return _svg(body, f"assembly overview: {len(plan.segments)} segments")


def lamella_svg(plan: AssemblyPlan, lamella: str, keyplan: _KeyPlan) -> str:
    """One lamella's page (see the module)."""
    w, h = PAGE
    pieces = [p for p in plan.pieces if p.lamella == lamella]
    homes = sorted({p.home for p in pieces})
    lies_in = sorted({k for p in pieces for k in p.segments})
    to_page = keyplan.box(w - MARGIN - 150.0, 8.0, 150.0, 120.0)
    shaded = {k: ("#9cc7ef" if k in homes else "#dde8f3") for k in lies_in}
    family = pieces[0].family if pieces else ""
    body = [_text(MARGIN, 16.0, f"Lamella {lamella}", 9.0, weight="bold"),
            _text(MARGIN, 23.0, f"family {family}; built into segment {', '.join(map(str, homes)) or '-'}"
                                + (f" (lies in {', '.join(map(str, lies_in))})" if lies_in != homes else "")
                                + f" of {len(plan.segments)}", 3.6)]
    body += keyplan.draw(to_page, shaded, red=lamella)
    body.append(_text(w - MARGIN - 150.0, 131.0, "key plan from above: this lamella red, its segment shaded dark "
                                                 "(lighter: the segments it reaches into)", 2.6))
    y = 32.0
    body.append(_text(MARGIN, y, "piece              segment  step   length mm   nodes", 3.2, weight="bold", table=True))
    for piece in pieces:
        y += 5.0
        step = plan.step_of(piece.id)
        first, last = (piece.nodes[0][0], piece.nodes[-1][0]) if piece.nodes else ("-", "-")
        body.append(f'<g class="piece" data-piece="{_e(piece.id)}" data-length="{piece.length:.1f}">'
                    + _text(MARGIN, y, f"{piece.id:<18} {piece.home:>4}  {step[1] if step else '-':>5}  "
                                       f"{piece.length:>10.1f}   {first} .. {last}", 3.2, table=True) + "</g>")
    y += 8.0
    for line in _wrap("Each strip below is drawn straight, start at the left; at every slot the lamella that crosses "
                      "there and the node id (the same id is engraved on the strip). Seams: the pieces overlap by the "
                      "red bracket and are screwed together.", 95):
        body.append(_text(MARGIN, y, line, 2.8))
        y += 3.8
    strips = list(dict.fromkeys(p.strip for p in pieces))
    top = max(y + 30.0, 150.0)
    band = (h - MARGIN - top) / max(len(strips), 1)
    for k, strip in enumerate(strips):
        body += _strip(plan, [p for p in pieces if p.strip == strip], strip, top + k * band, band)
    return _svg(body, f"lamella {lamella}")


def _strip(plan: AssemblyPlan, pieces: list[Piece], strip: str, y0: float, band: float) -> list[str]:
    """One strip straight along the page: pieces, seams, node ticks and the slot labels above it."""
    w, _ = PAGE
    pieces = sorted(pieces, key=lambda p: p.start)
    start = min(p.start for p in pieces)
    end = max(p.start + p.length for p in pieces)
    left, right = MARGIN, w - MARGIN
    scale = (right - left) / max(end - start, 1e-9)
    bar = y0 + band - 14.0
    out = [_text(MARGIN, bar + 16.0, f"strip {strip}, its start at the left", 3.0, weight="bold")]
    for k, piece in enumerate(pieces):
        x = left + scale * (piece.start - start)
        width = scale * piece.length
        lift = 1.5 if k % 2 else 0.0  # neighbouring pieces overlap at a seam: offset alternate ones
        out.append(f'<rect x="{_f(x)}" y="{_f(bar + lift)}" width="{_f(width)}" height="4" fill="{"#e9e9e9" if k % 2 else "#d0d0d0"}" '
                   f'stroke="#222" stroke-width="0.25"/>')
        out.append(_text(x + width / 2.0, bar + 10.0, f"{piece.id}  {piece.length:.0f} mm", 2.8, "middle"))
        for join in (j for j in piece.seams if float(j.get("seam_mm", 0.0)) > piece.length / 2.0):  # its end's
            overlap = float(join.get("overlap_mm", 0.0))
            seam = piece.start + float(join.get("seam_mm", 0.0))
            a, b = left + scale * (seam - overlap / 2.0 - start), left + scale * (seam + overlap / 2.0 - start)
            out.append(f'<g class="seam" data-piece="{_e(piece.id)}"><path d="M{_f(a)},{_f(bar + 7)} L{_f(a)},{_f(bar + 7.8)} '
                       f'L{_f(b)},{_f(bar + 7.8)} L{_f(b)},{_f(bar + 7)}" fill="none" stroke="#d11" stroke-width="0.4"/></g>')
        slotted = dict.fromkeys(piece.slots)
        for nid, s in piece.nodes:
            x_node = left + scale * (piece.start + s - start)
            out.append(f'<line x1="{_f(x_node)}" y1="{_f(bar - 0.8)}" x2="{_f(x_node)}" y2="{_f(bar + 4 + lift)}" '
                       f'stroke="#1565c0" stroke-width="0.25"/>')
            if nid not in slotted:
                continue
            crossing = plan.crossing_lamellas(nid, piece.lamella)
            label = f"{'+'.join(crossing) or '?'}  {nid}"
            out.append(f'<g class="slot" data-piece="{_e(piece.id)}" data-node="{_e(nid)}" '
                       f'data-crossing="{_e(" ".join(crossing))}">'
                       + _text(x_node + 0.8, bar - 1.5, label, 2.3, rotate=-90.0) + "</g>")
    return out


def _wrap(text: str, width: int) -> list[str]:
    lines, line = [], ""
    for word in text.split():
        if line and len(line) + 1 + len(word) > width:
            lines.append(line)
            line = word
        else:
            line = f"{line} {word}".strip()
    return lines + ([line] if line else [])
