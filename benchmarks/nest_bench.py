"""Nesting benchmark: fabline against peers on the pavilion-sized cut list and a 10x larger one.

    python benchmarks/nest_bench.py                      # scales 1 and 10 of the unrolled built-in design
    python benchmarks/nest_bench.py --synthetic          # the same on the synthetic pavilion-like cut list
    python benchmarks/nest_bench.py --parts parts.json --scale 1 --scale 10
    python benchmarks/nest_bench.py --scale 1 --spyrrow-time 60

Peers run on the same parts, sheet, margin, gap and kerf: a plain first-fit-decreasing shelf packer
of bounding boxes (written here), rectpack's MaxRects bin packing of bounding boxes, and spyrrow
(sparrow strip packing of the true outlines) where installed. Every peer result that is a sheet
nesting is checked with fabline's independent validator; spyrrow solves strip packing, so its figure
is the strip length divided by the usable sheet length (parts may straddle sheet edges): an
optimistic estimate, marked with '*'. Wall-clock and CPU seconds are both printed, since the
machine may be shared; fabline's time includes its own validation, the peers' does not.
"""

from __future__ import annotations

import argparse
import copy
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fabline.model.designs import enneper_network  # noqa: E402
from fabline.nest import NestOptions, Nesting, Placement, Sheet, nest, validate_nesting
from fabline.nest.shapes import NestShape, nest_shapes  # noqa: E402
from fabline.nest.synthetic import pavilion_like_parts  # noqa: E402
from fabline.shop import StockItem  # noqa: E402
from fabline.unroll import PartSet, load_parts, unroll_network  # noqa: E402

SHEET = (4000.0, 2000.0)


def pavilion_parts(scale: int = 1, synthetic: bool = False) -> PartSet:
    """The built-in pavilion-sized cut list, `scale` times over: the Enneper design (9 x 12 m) unrolled with
    default options, or the seeded synthetic cut list of the same make-up."""
    if synthetic:
        return pavilion_like_parts(scale)
    return replicate(unroll_network(enneper_network()), scale)


def replicate(partset: PartSet, scale: int) -> PartSet:
    """`scale` copies of every part of a given parts file, ids suffixed, for the larger instance."""
    if scale == 1:
        return partset
    parts = []
    for k in range(scale):
        for part in partset.parts:
            twin = copy.copy(part)
            twin.id = f"{part.id}#{k + 1}"
            parts.append(twin)
    return PartSet(parts, partset.profile, partset.material, f"{partset.source} x{scale}")


def _boxes(shapes: list[NestShape]) -> list[tuple[NestShape, float, float, float, float]]:
    """Each part's bounding box at rotation 0: (shape, min x, min y, width, height)."""
    out = []
    for shape in shapes:
        minx, miny, maxx, maxy = shape.polygon.bounds
        out.append((shape, minx, miny, maxx - minx, maxy - miny))
    return out


def ffd_shelves(shapes: list[NestShape], options: NestOptions) -> list[Sheet]:
    """Plain first-fit decreasing height: bounding boxes, tallest first, into the first shelf with room."""
    usable_w, usable_h = SHEET[0] - 2 * options.margin, SHEET[1] - 2 * options.margin
    c = options.clearance
    sheets: list[Sheet] = []
    shelves: list[list] = []          # [sheet index, y, height, x used]
    sheet_top: list[float] = []
    for shape, minx, miny, w, h in sorted(_boxes(shapes), key=lambda b: (-b[4], -b[3])):
        shelf = next((s for s in shelves if s[2] >= h and s[3] + w <= usable_w + 1e-9), None)
        if shelf is None:
            k = next((i for i, top in enumerate(sheet_top) if top + h <= usable_h + 1e-9), None)
            if k is None:
                sheets.append(Sheet(f"S{len(sheets) + 1:03d}", *SHEET))
                sheet_top.append(0.0)
                k = len(sheets) - 1
            shelf = [k, sheet_top[k], h, 0.0]
            sheet_top[k] += h + c
            shelves.append(shelf)
        x, y = options.margin + shelf[3], options.margin + shelf[1]
        sheets[shelf[0]].placements.append(Placement(shape.id, x - minx, y - miny, 0.0))
        shelf[3] += w + c
    return sheets


def rectpack_maxrects(shapes: list[NestShape], options: NestOptions) -> list[Sheet]:
    """rectpack's offline MaxRects (best short side fit, best-fit bins) on bounding boxes grown by the clearance."""
    import rectpack

    c = options.clearance
    packer = rectpack.newPacker(mode=rectpack.PackingMode.Offline, bin_algo=rectpack.PackingBin.BFF,
                                pack_algo=rectpack.MaxRectsBssf, rotation=False)
    boxes = _boxes(shapes)
    for k, (_, _, _, w, h) in enumerate(boxes):
        packer.add_rect(math.ceil(w + c), math.ceil(h + c), rid=k)
    packer.add_bin(int(SHEET[0] - 2 * options.margin + c), int(SHEET[1] - 2 * options.margin + c), count=float("inf"))
    packer.pack()
    sheets: dict[int, Sheet] = {}
    for bin_index, x, y, _, _, rid in packer.rect_list():
        shape, minx, miny, _, _ = boxes[rid]
        sheet = sheets.setdefault(bin_index, Sheet(f"S{bin_index + 1:03d}", *SHEET))
        sheet.placements.append(Placement(shape.id, options.margin + x - minx, options.margin + y - miny, 0.0))
    return [sheets[k] for k in sorted(sheets)]


def spyrrow_strip(shapes: list[NestShape], options: NestOptions, seconds: int) -> float:
    """Sparrow strip packing (via spyrrow) of the true outlines; returns the strip length used, mm."""
    import spyrrow

    groups: dict[str, list[NestShape]] = {}
    for shape in shapes:
        groups.setdefault(shape.key, []).append(shape)
    items = []
    for key, members in groups.items():
        ring = np.asarray(members[0].solid.exterior.coords)[:-1]
        orientations = [0.0, 180.0] if members[0].part.grain else [0.0, 90.0, 180.0, 270.0]
        items.append(spyrrow.Item(key, [tuple(p) for p in ring.tolist()], demand=len(members),
                                  allowed_orientations=orientations))
    instance = spyrrow.StripPackingInstance("nest", SHEET[1] - 2 * options.margin, items)
    config = spyrrow.StripPackingConfig(early_termination=True, total_computation_time=seconds,
                                        min_items_separation=options.clearance, num_workers=2, seed=1)
    return float(instance.solve(config).width)


def _figures(partset: PartSet, sheets: list[Sheet], options: NestOptions, area: float) -> tuple[int, float, str]:
    """Sheets used, utilisation and the validator's verdict for one peer's sheets."""
    nesting = Nesting(sheets, "parts.json", options.kerf, options.gap, options.margin)
    problems = validate_nesting(nesting, partset)
    used = len(sheets)
    verdict = "ok" if not problems else f"{len(problems)} problems"
    return used, area / (used * SHEET[0] * SHEET[1]), verdict


def run_instance(name: str, partset: PartSet, options: NestOptions, peers: list[str], spyrrow_time: int,
                 spyrrow_max_parts: int) -> list[dict]:
    """Every method on one instance; rows for the table (wall-clock and this process's CPU seconds)."""
    wall, cpu = time.perf_counter(), time.process_time()
    result = nest(partset, [StockItem("sheet", *SHEET)], options)
    rows = [{"method": "fabline", "sheets": result.report["sheets_used"], "utilisation": result.report["utilisation"],
             "seconds": time.perf_counter() - wall, "cpu": time.process_time() - cpu, "valid": "ok"}]
    bounds = result.report["lower_bound"]
    shapes = nest_shapes(partset.parts)
    area = sum(s.area for s in shapes)
    for peer in peers:
        row = {"method": peer, "sheets": None, "utilisation": None, "seconds": None, "cpu": None}
        wall, cpu = time.perf_counter(), time.process_time()
        try:
            if peer == "spyrrow" and len(shapes) > spyrrow_max_parts:
                row.update(method="spyrrow*", valid=f"skipped: over --spyrrow-max-parts {spyrrow_max_parts}")
            elif peer == "spyrrow":
                length = spyrrow_strip(shapes, options, spyrrow_time)
                count = length / (SHEET[0] - 2 * options.margin)
                row.update(method="spyrrow*", sheets=math.ceil(count - 1e-9),
                           utilisation=area / (count * SHEET[0] * SHEET[1]),
                           valid=f"strip {length / 1000:.2f} m = {count:.2f} sheet lengths")
            elif peer in ("ffd", "rectpack"):
                sheets = ffd_shelves(shapes, options) if peer == "ffd" else rectpack_maxrects(shapes, options)
                row.update(seconds=time.perf_counter() - wall, cpu=time.process_time() - cpu)
                row["sheets"], row["utilisation"], row["valid"] = _figures(partset, sheets, options, area)
            else:
                raise ValueError(f"unknown peer {peer}")
        except ImportError as exc:
            row.update(valid=f"not installed ({exc.name})")
        if row["seconds"] is None and row["sheets"] is not None:
            row.update(seconds=time.perf_counter() - wall, cpu=time.process_time() - cpu)
        rows.append(row)
    for row in rows:
        row.update(instance=name, parts=len(partset.parts), lb_area=bounds["area"],
                   lb_clearance=bounds["clearance_area"], lb_strip_lp=bounds["strip_lp"])
    return rows


def main() -> None:
    """Parse options, run every instance and print one table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--parts", help="a parts.json to use instead of the built-in pavilion cut list")
    parser.add_argument("--synthetic", action="store_true",
                        help="use the seeded synthetic pavilion-like cut list instead of the unrolled built-in design")
    parser.add_argument("--scale", type=int, action="append", help="instance sizes to run (default 1 and 10)")
    parser.add_argument("--peers", default="ffd,rectpack,spyrrow", help="comma-separated peers to run")
    parser.add_argument("--spyrrow-time", type=int, default=60, help="seconds for spyrrow per instance (default 60)")
    parser.add_argument("--spyrrow-max-parts", type=int, default=5000,
                        help="skip spyrrow on larger instances (it needs far more than its time budget there)")
    parser.add_argument("--time-limit", type=float, default=10.0, help="fabline's strip solver time limit")
    args = parser.parse_args()
    options = NestOptions(kerf=0.2, gap=3.0, margin=10.0, time_limit=args.time_limit)
    peers = [p for p in args.peers.split(",") if p]
    print(f"sheet {SHEET[0]:g} x {SHEET[1]:g} mm, margin {options.margin:g}, gap {options.gap:g}, kerf {options.kerf:g}\n")
    header = (f"{'instance':<14}{'parts':>7}  {'method':<10}{'sheets':>7}{'util %':>8}{'LB area':>9}{'LB clear':>9}"
              f"{'LB strip':>9}{'wall s':>8}{'cpu s':>8}  check")
    print(header)
    print("-" * len(header), flush=True)
    for scale in args.scale or [1, 10]:
        partset = replicate(load_parts(args.parts), scale) if args.parts else pavilion_parts(scale, args.synthetic)
        name = Path(args.parts).stem if args.parts else ("synthetic" if args.synthetic else "enneper")
        for r in run_instance(f"{name} x{scale}", partset, options,
                              peers, args.spyrrow_time, args.spyrrow_max_parts):
            sheets = "-" if r["sheets"] is None else str(r["sheets"])
            util = "-" if r["utilisation"] is None else f"{100 * r['utilisation']:.1f}"
            secs = "-" if r["seconds"] is None else f"{r['seconds']:.1f}"
            cpu = "-" if r["cpu"] is None else f"{r['cpu']:.1f}"
            print(f"{r['instance']:<14}{r['parts']:>7}  {r['method']:<10}{sheets:>7}{util:>8}{r['lb_area']:>9}"
                  f"{r['lb_clearance']:>9}{r['lb_strip_lp']:>9}{secs:>8}{cpu:>8}  {r['valid']}", flush=True)
    print("\n* spyrrow packs one strip of the sheet's usable height; its sheet count is the strip length over the "
          "usable sheet length, rounded up (parts may straddle sheet edges), so it is optimistic.")


if __name__ == "__main__":
    main()
