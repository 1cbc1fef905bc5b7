"""Nest a part set on sheets: straight strips in rows by cutting stock, everything else by raster nesting.

Straight strips are the bulk of a gridshell's steel. They are packed into rows along the sheet's
length (1D cutting stock, `cutstock`), rows stacked on sheets fullest first. Curved strips, joints,
clamps and washers then go into whatever space is left, largest first, on the sheets already open
and on new ones as needed (`raster`); identical parts are placed as one group, on a repeating pattern
when there are many. The result is checked by the independent validator before it is returned.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from shapely import affinity
from shapely.geometry import Polygon

from fabline.errors import FablineError
from fabline.nest.cutstock import pack_rows, row_lower_bound
from fabline.nest.layout import CommonCut, Nesting, Placement, Sheet
from fabline.nest.raster import Canvas, Lattice, Template, densest_lattice, make_template, place_copies
from fabline.nest.remnants import leftover_rectangles
from fabline.nest.shapes import NestShape, nest_shapes
from fabline.nest.stacking import StackSheet
from fabline.nest.validate import validate_nesting
from fabline.progress import progress
from fabline.shop.stock import StockItem, usable_extent
from fabline.unroll.parts import PartSet

# Raster resolution for irregular parts: about 60 cells across the part, between these bounds (mm).
FINEST_CELL, COARSEST_CELL, CELLS_ACROSS = 1.0, 5.0, 60.0
ROTATION_STEPS = (1, 2, 4, 8, 12, 24, 36, 72)   # the rotation steps a part may take (360 / steps degrees)
REMNANT_CELL = 20.0
# Groups of at least this many identical parts are laid on a repeating pattern before the greedy fill.
LATTICE_MIN_COPIES = 12
# Parts with grain at least this long that are not strips (the curved edge bars) are stacked by their outlines.
STACK_MIN_LENGTH = 1000.0


@dataclass
class NestOptions:
    """What the user chose: spacing, rotations, cutting style, stock use and the time the strip solver may take."""

    kerf: float = 0.2
    gap: float = 3.0
    margin: float = 10.0
    rotation_steps: int = 4
    common_line: bool = False
    fill_holes: bool = False
    remnants_first: bool = False
    remnant_min: tuple[float, float] = (400.0, 200.0)
    time_limit: float = 10.0

    @property
    def clearance(self) -> float:
        """Distance kept between parts: the web of material left (gap) plus the width the beam burns (kerf)."""
        return self.gap + self.kerf

    def check(self, name: Callable[[str], str] = lambda key: "--" + key.replace("_", "-")) -> None:
        """Reject nonsensical settings with a one-line message naming the setting as `name(key)` gives it (the
        command line's option by default; a job file names its own keys)."""
        for key, option in (("kerf", "kerf"), ("gap", "gap"), ("margin", "sheet_margin")):
            value = getattr(self, key)
            if not (math.isfinite(value) and value >= 0):
                raise FablineError(f"{name(option)}: must be a finite number, not negative, got {value}")
        if self.rotation_steps not in ROTATION_STEPS:
            raise FablineError(f"{name('rotations')}: must be one of {', '.join(map(str, ROTATION_STEPS))}, "
                               f"got {self.rotation_steps}")
        if not self.time_limit > 0:
            raise FablineError(f"{name('time_limit')}: must be positive, got {self.time_limit}")


@dataclass
class _OpenSheet:
    """A sheet being filled: the layout sheet plus the geometry the raster canvas is rebuilt from.

    `misfits` holds the sorted extents of parts that found no room here: parts at least as large in both
    directions are not tried again on this sheet.
    """

    sheet: Sheet
    stock: StockItem
    rectangles: list[tuple[float, float, float, float]] = field(default_factory=list)
    polygons: list[Polygon] = field(default_factory=list)
    part_area: float = 0.0
    zone_area: float = 0.0
    misfits: list[list[float]] = field(default_factory=list)

    def usable_area(self, margin: float) -> float:
        """Area inside the margins, mm²."""
        return max(0.0, self.stock.width - 2 * margin) * max(0.0, self.stock.height - 2 * margin)


class _Supply:
    """Sheets in the order they are taken: remnants first when asked, counts respected."""

    def __init__(self, stock: list[StockItem], remnants_first: bool):
        sheets = [s for s in stock if not s.remnant]
        remnants = sorted((s for s in stock if s.remnant), key=lambda s: -s.area)
        self.order = remnants + sheets if remnants_first else sheets + remnants
        self.left = {s.id: s.count for s in self.order}

    def available(self) -> list[StockItem]:
        """Stock items with sheets left, in order of use."""
        return [s for s in self.order if self.left[s.id] is None or self.left[s.id] > 0]

    def take(self, item: StockItem) -> None:
        """Use one sheet of `item`."""
        if self.left[item.id] is not None:
            self.left[item.id] -= 1

    @property
    def main(self) -> StockItem:
        """The sheet size bounds are stated in: the first full-size sheet kind (largest if several)."""
        sheets = [s for s in self.order if not s.remnant] or self.order
        return max(sheets, key=lambda s: s.area)


@dataclass
class NestResult:
    """The nesting and the figures of the run (bounds, timings, method used for the strips)."""

    nesting: Nesting
    report: dict


def nest(partset: PartSet, stock: list[StockItem], options: NestOptions, parts_file: str = "parts.json") -> NestResult:
    """Place every part of `partset` on sheets from `stock`; the result passes the independent validator."""
    started = time.monotonic()
    options.check()
    shapes = nest_shapes(partset.parts)
    supply = _Supply(stock, options.remnants_first)
    _check_fits(shapes, supply.order, options)
    sheets: list[_OpenSheet] = []
    row_shapes = [s for s in shapes if s.strip_like and _row_fits_some(s, supply.order, options)]
    row_ids = {s.id for s in row_shapes}
    strip_report = _place_strips(row_shapes, supply, sheets, options)
    rest = [s for s in shapes if s.id not in row_ids]
    stacked = _stack_bars([s for s in rest if s.part.grain and _extent(s)[0] >= STACK_MIN_LENGTH], supply, sheets,
                          options)
    _place_irregular([s for s in rest if s.id not in stacked], supply, sheets, options)
    nesting = Nesting([o.sheet for o in sheets], parts_file, options.kerf, options.gap, options.margin)
    nesting.remnants = _remnants(sheets, options)
    report = _summary(shapes, sheets, supply, options, strip_report, time.monotonic() - started)
    nesting.summary = report
    problems = validate_nesting(nesting, partset)
    if problems:
        raise RuntimeError(f"nesting failed its own validation ({len(problems)} problems): {problems[0]}")
    return NestResult(nesting, report)


def _extent(shape: NestShape) -> tuple[float, float]:
    minx, miny, maxx, maxy = shape.polygon.bounds
    return maxx - minx, maxy - miny


def _fits(shape: NestShape, item: StockItem, options: NestOptions) -> bool:
    usable_w, usable_h = usable_extent(item.width, options.margin), usable_extent(item.height, options.margin)
    for angle in shape.rotations(options.rotation_steps):
        minx, miny, maxx, maxy = affinity.rotate(shape.solid, angle, origin=(0, 0)).bounds
        if maxx - minx <= usable_w + 1e-9 and maxy - miny <= usable_h + 1e-9:
            return True
    return False


def _check_fits(shapes: list[NestShape], stock: list[StockItem], options: NestOptions) -> None:
    """A part that fits no sheet kind in any allowed rotation is the user's error, named with its size."""
    for shape in (members[0] for members in _groups(shapes).values()):
        if not any(_fits(shape, item, options) for item in stock):
            w, h = _extent(shape)
            raise FablineError(f"part {shape.id} ({w:.0f} x {h:.0f} mm) is larger than every sheet's usable area "
                               f"(margin {options.margin:g} mm)")


def _row_fits_some(shape: NestShape, stock: list[StockItem], options: NestOptions) -> bool:
    w, h = _extent(shape)
    return any(w <= usable_extent(s.width, options.margin) and h <= usable_extent(s.height, options.margin)
               for s in stock)


def _spacing(options: NestOptions) -> float:
    return options.kerf if options.common_line else options.clearance


def _place_strips(strips: list[NestShape], supply: _Supply, sheets: list[_OpenSheet], options: NestOptions) -> dict:
    """Strips into rows (cutting stock per height class), rows onto sheets fullest first, sheet kinds in order."""
    spacing = _spacing(options)
    remaining = list(strips)
    report: dict = {"rows": 0, "method": "none", "row_lower_bound": None, "lp_rows": None}
    for item in supply.available():
        if not remaining:
            break
        usable_w, usable_h = usable_extent(item.width, options.margin), usable_extent(item.height, options.margin)
        fitting = [s for s in remaining if _extent(s)[0] <= usable_w and _extent(s)[1] <= usable_h]
        if not fitting:
            continue
        rows: list[tuple[float, list[NestShape]]] = []
        classes = _height_classes(fitting)
        for height, members in classes.items():
            sizes = np.array([_extent(s)[0] + spacing for s in members])
            packing = pack_rows(sizes, usable_w + spacing, options.time_limit)
            rows += [(height, [members[i] for i in row]) for row in packing.rows]
            report["method"] = packing.method
            if item is supply.main and len(fitting) == len(strips) and len(classes) == 1:
                report.update(row_lower_bound=packing.lower_bound, lp_rows=packing.lp_value)
        rows.sort(key=lambda r: -sum(_extent(s)[0] for s in r[1]))
        for sheet_rows in _rows_to_sheets(rows, usable_h + spacing, spacing):
            if supply.left[item.id] == 0:
                break
            supply.take(item)
            open_sheet = _open(sheets, item)
            _lay_rows(open_sheet, sheet_rows, options)
            placed = {s.id for _, row in sheet_rows for s in row}
            remaining = [s for s in remaining if s.id not in placed]
            report["rows"] += len(sheet_rows)
    if remaining:
        raise FablineError(f"part {remaining[0].id}: not enough sheets in stock for all strips")
    return report


def _height_classes(strips: list[NestShape]) -> dict[float, list[NestShape]]:
    """Strips grouped by height rounded up to 0.5 mm, so strips in one row are all as high as the row."""
    classes: dict[float, list[NestShape]] = {}
    for shape in sorted(strips, key=lambda s: -_extent(s)[1]):
        classes.setdefault(math.ceil(_extent(shape)[1] * 2 - 1e-9) / 2, []).append(shape)
    return classes


def _rows_to_sheets(rows: list[tuple[float, list[NestShape]]], budget: float, spacing: float) -> list[list]:
    """First-fit of rows (pitch = height + spacing) into sheets of height `budget`, keeping the fullest-first order."""
    sheets: list[list] = []
    room: list[float] = []
    for row in rows:
        pitch = row[0] + spacing
        k = next((i for i, r in enumerate(room) if r >= pitch - 1e-9), None)
        if k is None:
            sheets.append([])
            room.append(budget)
            k = len(sheets) - 1
        sheets[k].append(row)
        room[k] -= pitch
    return sheets


def _open(sheets: list[_OpenSheet], item: StockItem) -> _OpenSheet:
    open_sheet = _OpenSheet(Sheet(f"S{len(sheets) + 1:03d}", item.width, item.height, stock=item.id), item)
    sheets.append(open_sheet)
    return open_sheet


def _lay_rows(open_sheet: _OpenSheet, sheet_rows: list, options: NestOptions) -> None:
    """Rows bottom-up from the margin, strips longest first from the left; common cuts where asked."""
    spacing = _spacing(options)
    y = options.margin
    previous: list[tuple[str, float, float, float]] = []
    for height, row in sheet_rows:
        x = options.margin
        current = []
        for shape in sorted(row, key=lambda s: -_extent(s)[0]):
            minx, miny, maxx, maxy = shape.polygon.bounds
            open_sheet.sheet.placements.append(Placement(shape.id, x - minx, y - miny, 0.0))
            open_sheet.rectangles.append((x, y, x + maxx - minx, y + maxy - miny))
            open_sheet.part_area += shape.area
            open_sheet.zone_area += (maxx - minx + spacing) * (height + spacing)
            if options.common_line and current:
                cut_x = x - options.kerf / 2
                open_sheet.sheet.common_cuts.append(CommonCut((current[-1][0], shape.id), (cut_x, y),
                                                              (cut_x, y + min(height, maxy - miny))))
            current.append((shape.id, x, x + maxx - minx, y + maxy - miny))
            x += maxx - minx + spacing
        if options.common_line:
            _row_common_cuts(open_sheet, previous, current, y, options)
        previous = current
        y += height + spacing


def _row_common_cuts(open_sheet: _OpenSheet, below: list, above: list, y: float, options: NestOptions) -> None:
    """Common cuts between a row and the one below it: along the shared line wherever strips face or near each other."""
    line_y = y - options.kerf / 2
    for lower_id, lx0, lx1, top in below:
        if abs(top - (y - options.kerf)) > 1e-6:
            continue
        for upper_id, ux0, ux1, _ in above:
            start, end = max(lx0, ux0), min(lx1, ux1)
            if end - start > -options.clearance:
                if start > end:
                    start, end = end, start
                open_sheet.sheet.common_cuts.append(CommonCut((lower_id, upper_id), (start, line_y), (end, line_y)))


def _cell_size(shape: NestShape) -> float:
    return float(np.clip(max(_extent(shape)) / CELLS_ACROSS, FINEST_CELL, COARSEST_CELL))


def _canvas(open_sheet: _OpenSheet, res: float, options: NestOptions, clearance: float) -> Canvas:
    """The sheet's occupancy at `res`: strips as rectangles, other parts as polygons (holes free if allowed)."""
    canvas = Canvas(open_sheet.stock.width, open_sheet.stock.height, options.margin, res)
    half = clearance / 2
    for xmin, ymin, xmax, ymax in open_sheet.rectangles:
        canvas.block_rectangle(xmin - half, ymin - half, xmax + half, ymax + half)
    for polygon in open_sheet.polygons:
        canvas.block_polygon(polygon, half)
        if options.fill_holes:
            canvas.mark_holes(polygon)
    return canvas


def _templates(shape: NestShape, res: float, options: NestOptions) -> list[Template]:
    """One template per allowed rotation, dropping rotations that give the same mask (symmetric parts)."""
    unique: list[Template] = []
    for angle in shape.rotations(options.rotation_steps):
        template = make_template(shape.solid, angle, res, options.clearance / 2)
        if not any(t.mask.shape == template.mask.shape and np.array_equal(t.mask, template.mask)
                   and np.allclose(t.origin, template.origin, atol=1e-6) for t in unique):
            unique.append(template)
    return unique


def _groups(shapes: list[NestShape]) -> dict[str, list[NestShape]]:
    """Identical parts grouped by shape key, groups in order of first appearance."""
    groups: dict[str, list[NestShape]] = {}
    for shape in shapes:
        groups.setdefault(shape.key, []).append(shape)
    return groups


def _place_irregular(shapes: list[NestShape], supply: _Supply, sheets: list[_OpenSheet], options: NestOptions) -> None:
    """Groups of identical parts, largest first, into the free space of open sheets, then onto new sheets."""
    groups = _groups(sorted(shapes, key=lambda s: (-max(_extent(s)), -s.area)))
    for members in progress(groups.values(), desc="nesting parts", total=len(groups)):
        representative = members[0]
        res = _cell_size(representative)
        templates = _templates(representative, res, options)
        lattice = _lattice(templates) if len(members) >= LATTICE_MIN_COPIES else None
        remaining = list(members)
        size = sorted(_extent(representative))
        for open_sheet in sheets:
            if not remaining:
                break
            if open_sheet.usable_area(options.margin) - open_sheet.zone_area < representative.area or \
                    any(size[0] >= small and size[1] >= large for small, large in open_sheet.misfits):
                continue
            before = len(remaining)
            remaining = _fill(open_sheet, remaining, templates, res, options, lattice)
            if len(remaining) == before:
                open_sheet.misfits.append(size)
        while remaining:
            item = next((s for s in supply.available() if _fits(representative, s, options)), None)
            if item is None:
                raise FablineError(f"part {representative.id}: not enough sheets in stock")
            supply.take(item)
            open_sheet = _open(sheets, item)
            before = len(remaining)
            remaining = _fill(open_sheet, remaining, templates, res, options, lattice)
            if len(remaining) == before:
                w, h = _extent(representative)
                raise FablineError(f"part {representative.id} ({w:.0f} x {h:.0f} mm) does not fit on an empty "
                                   f"{item.width:g} x {item.height:g} mm sheet ({item.id}) with its clearance of gap "
                                   f"{options.gap:g} + kerf {options.kerf:g} mm")


def _stack_bars(bars: list[NestShape], supply: _Supply, sheets: list[_OpenSheet], options: NestOptions) -> set[str]:
    """Long curved parts, longest first, each as low as it fits above the strip rows of the first sheet that holds
    it (open sheets, then new ones); returns their ids. Their outlines, not cells, set the spacing (`stacking`)."""
    stacks: dict[int, StackSheet] = {}

    def stack_of(open_sheet: _OpenSheet) -> StackSheet:
        if id(open_sheet) not in stacks:
            top = max((r[3] for r in open_sheet.rectangles), default=None)
            stacks[id(open_sheet)] = StackSheet(open_sheet.stock.width, open_sheet.stock.height, options.margin,
                                                options.clearance, top)
            for polygon in open_sheet.polygons:
                stacks[id(open_sheet)].add(polygon)
        return stacks[id(open_sheet)]

    placed: set[str] = set()
    for shape in sorted(bars, key=lambda s: -_extent(s)[0]):
        geometry = shape.polygon if options.fill_holes else shape.solid
        rotations = shape.rotations(options.rotation_steps)
        spot = next(((o, s) for o in sheets if (s := stack_of(o).place(geometry, rotations)) is not None), None)
        if spot is None:
            item = next((s for s in supply.available() if _fits(shape, s, options)), None)
            if item is None:
                raise FablineError(f"part {shape.id}: not enough sheets in stock")
            supply.take(item)
            open_sheet = _open(sheets, item)
            spot = (open_sheet, stack_of(open_sheet).place(geometry, rotations))
        open_sheet, where = spot
        if where is None:
            continue  # the raster fill places it (or names why it does not fit)
        x, y, rotation = where
        open_sheet.sheet.placements.append(Placement(shape.id, x, y, rotation))
        laid = affinity.translate(affinity.rotate(geometry, rotation, origin=(0, 0)), x, y)
        open_sheet.polygons.append(laid)
        stack_of(open_sheet).add(laid)
        open_sheet.part_area += shape.area
        open_sheet.zone_area += float(laid.buffer(options.clearance / 2).area)
        placed.add(shape.id)
    return placed


def _lattice(templates: list[Template]) -> Lattice | None:
    """The densest repeating pattern over the allowed rotations, for groups of many identical parts."""
    lattices = [lattice for lattice in map(densest_lattice, templates) if lattice is not None]
    return min(lattices, key=lambda lattice: lattice.cell_area, default=None)


def _fill(open_sheet: _OpenSheet, members: list[NestShape], templates: list[Template], res: float,
          options: NestOptions, lattice: Lattice | None) -> list[NestShape]:
    """Place as many of `members` as fit on one sheet; return those left over."""
    canvas = _canvas(open_sheet, res, options, options.clearance)
    spots = place_copies(canvas, templates, len(members), lattice)
    for shape, (template, i, j) in zip(members, spots):
        x, y = canvas.translation(template, i, j)
        placement = Placement(shape.id, x, y, template.rotation)
        open_sheet.sheet.placements.append(placement)
        geometry = shape.polygon if options.fill_holes else shape.solid
        open_sheet.polygons.append(affinity.translate(affinity.rotate(geometry, template.rotation, origin=(0, 0)), x, y))
        open_sheet.part_area += shape.area
        open_sheet.zone_area += float(template.mask.sum()) * res * res
    return members[len(spots):]


def _remnants(sheets: list[_OpenSheet], options: NestOptions) -> list[dict]:
    """Leftover rectangles above the minimum size on every sheet, kept clear of parts by gap + kerf."""
    out = []
    for open_sheet in sheets:
        canvas = _canvas(open_sheet, REMNANT_CELL, options, 2 * options.clearance)
        for k, (x, y, w, h) in enumerate(leftover_rectangles(canvas, open_sheet.stock.width, open_sheet.stock.height,
                                                             *options.remnant_min)):
            out.append({"id": f"{open_sheet.sheet.id}-R{k + 1}", "sheet": open_sheet.sheet.id, "x": float(x), "y": float(y),
                        "width": float(w), "height": float(h)})
    return out


def lower_bounds(shapes: list[NestShape], main: StockItem, options: NestOptions, strip_report: dict) -> dict:
    """Sheets needed at least, three ways: total part area over sheet area; the same with every part grown by
    half the clearance (parts at least gap + kerf apart have disjoint grown shapes inside the grown usable
    area); and the strips' cutting-stock LP bound, valid when strips keep their grain (rows, by interval colouring).
    """
    area_bound = math.ceil(sum(s.area for s in shapes) / main.area - 1e-9)
    spacing = _spacing(options)
    half = spacing / 2
    grown_sheet = (main.width - 2 * options.margin + spacing) * (main.height - 2 * options.margin + spacing)
    grown_area = sum(len(group) * float((group[0].polygon if options.fill_holes else group[0].solid)
                                        .buffer(half, quad_segs=16).area)
                     for group in _groups(shapes).values())
    clearance_bound = math.ceil(grown_area / grown_sheet - 1e-9)
    strips = [s for s in shapes if s.strip_like]
    strip_bound = 0
    if strips and (all(s.part.grain for s in strips) or options.rotation_steps <= 2):
        usable_w = main.width - 2 * options.margin
        fitting = [s for s in strips if _extent(s)[0] <= usable_w]
        row_bound = strip_report["row_lower_bound"]
        if row_bound is None:
            sizes = np.array([_extent(s)[0] + spacing for s in fitting])
            row_bound = row_lower_bound(sizes, usable_w + spacing, options.time_limit)
            strip_report.update(row_lower_bound=row_bound)
        # Every row is at least as high as the lowest strip, so this many rows fit on a sheet at most.
        lowest = min(_extent(s)[1] for s in fitting) if fitting else 1.0
        rows_per_sheet = int((main.height - 2 * options.margin + spacing) // (lowest + spacing))
        strip_bound = math.ceil(row_bound / max(rows_per_sheet, 1) - 1e-9)
    return {"area": area_bound, "clearance_area": clearance_bound, "strip_lp": strip_bound,
            "best": max(area_bound, clearance_bound, strip_bound)}



def _summary(shapes: list[NestShape], sheets: list[_OpenSheet], supply: _Supply, options: NestOptions,
             strip_report: dict, seconds: float) -> dict:
    """Per-sheet utilisation, totals, lower bounds and settings, as stored in nesting.json's `summary`."""
    table = [{"id": o.sheet.id, "stock": o.stock.id, "width": o.stock.width, "height": o.stock.height,
              "parts": len(o.sheet.placements), "utilisation": round(o.part_area / o.stock.area, 4)} for o in sheets]
    total_area = sum(o.stock.area for o in sheets)
    bounds = lower_bounds(shapes, supply.main, options, strip_report)
    return {
        "sheets_used": len(sheets),
        "parts": len(shapes),
        "utilisation": round(sum(o.part_area for o in sheets) / total_area, 4) if total_area else 0.0,
        "lower_bound": bounds,
        "strips": {"rows": strip_report["rows"], "row_lower_bound": strip_report["row_lower_bound"],
                   "lp_rows": None if strip_report["lp_rows"] is None else round(strip_report["lp_rows"], 3),
                   "method": strip_report["method"]},
        "sheets": table,
        "runtime_s": round(seconds, 2),
        "settings": {"rotation_steps": options.rotation_steps, "common_line": options.common_line,
                     "fill_holes": options.fill_holes, "remnants_first": options.remnants_first},
    }
