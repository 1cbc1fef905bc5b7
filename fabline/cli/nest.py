"""CLI for the nest stage: `fabline nest` places parts.json on sheets, `fabline nest --check` validates a nesting."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from fabline.cli import hidden_alias
from fabline.cli.units import length_mm, size
from fabline.errors import FablineError
from fabline.fileio import check_outputs


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add `nest`."""
    parser = subparsers.add_parser("nest", help="nest parts on sheets (or --check an existing nesting)")
    parser.add_argument("parts", nargs="?", help="a fabline.parts/1 JSON file")
    parser.add_argument("-o", "--output", help="nesting JSON to write")
    parser.add_argument("--check", metavar="NESTING", help="validate an existing nesting.json and exit")
    sheet = parser.add_argument("--sheet-size", type=size("mm"), default="4000x2000", metavar="WxH",
                                help="sheet size, e.g. 4000x2000 or 4m x 2m")
    hidden_alias(parser, sheet, "--sheet")
    parser.add_argument("--stock", help="a fabline.stock/1 file of sheet sizes and remnants (overrides --sheet-size)")
    parser.add_argument("--stock-out", help="write the stock left after this job (remnants used, leftovers added)")
    parser.add_argument("--remnants-first", action="store_true", help="use the stock's remnants before full sheets")
    parser.add_argument("--remnant-min", type=size("mm"), default="400x200", metavar="WxH",
                        help="smallest leftover kept as a remnant")
    parser.add_argument("--kerf", type=length_mm, default=0.2, help="width the cut burns away")
    parser.add_argument("--gap", type=length_mm, default=3.0, help="material left between parts")
    margin = parser.add_argument("--sheet-margin", type=length_mm, default=10.0, help="unused border of each sheet")
    hidden_alias(parser, margin, "--margin")
    parser.add_argument("--rotations", type=int, default=4,
                        help="rotation steps per full turn for parts without grain (4: 0/90/180/270)")
    parser.add_argument("--common-line", action="store_true", help="neighbouring strips share one cut (no gap)")
    parser.add_argument("--fill-holes", action="store_true", help="allow small parts inside large holes")
    parser.add_argument("--time-limit", type=float, default=10.0, metavar="SECONDS", help="seconds for the strip solver")
    parser.add_argument("--svg", metavar="DIR", help="write one SVG picture per sheet into DIR")
    parser.set_defaults(func=run_nest)


def run_nest(args: argparse.Namespace) -> int:
    """Nest and print the sheet table, or validate with --check."""
    from fabline.unroll import load_parts
    from fabline.unroll.parts import check_cuttable

    if args.check:
        return _check(args.check)
    if not args.parts or not args.output:
        raise FablineError("give a parts file and -o nesting.json (or --check nesting.json)")
    check_outputs(files=(args.output, args.stock_out), folders=(args.svg,), inputs=(args.parts, args.stock))
    partset = load_parts(args.parts)  # a missing or broken parts file is told before the nester is imported
    check_cuttable(partset, args.parts)
    from fabline.nest import NestOptions, nest, save_nesting, write_sheet_svgs
    from fabline.shop import StockItem, load_stock, save_stock, stock_after

    options = NestOptions(kerf=args.kerf, gap=args.gap, margin=args.sheet_margin, rotation_steps=args.rotations,
                          common_line=args.common_line, fill_holes=args.fill_holes,
                          remnants_first=args.remnants_first, time_limit=args.time_limit, remnant_min=args.remnant_min)
    stock = load_stock(args.stock) if args.stock else [StockItem("sheet", *args.sheet_size)]
    relative = os.path.relpath(Path(args.parts).resolve(), Path(args.output).resolve().parent)
    try:
        result = nest(partset, stock, options, parts_file=relative)
    except FablineError as exc:
        raise FablineError(f"{args.parts}: {exc}") from None
    save_nesting(result.nesting, args.output)
    report = result.report
    print(f"{'sheet':<8}{'stock':<12}{'size mm':>13}{'parts':>7}{'used %':>8}")
    for row in report["sheets"]:
        print(f"{row['id']:<8}{row['stock']:<12}{row['width']:>6g}x{row['height']:<6g}{row['parts']:>7}"
              f"{100 * row['utilisation']:>8.1f}")
    bounds = report["lower_bound"]
    print(f"\n{args.output}: {report['parts']} parts on {report['sheets_used']} sheets, utilisation "
          f"{100 * report['utilisation']:.1f} %, lower bound {bounds['best']} sheets (area {bounds['area']}, "
          f"area with clearance {bounds['clearance_area']}, strip cutting-stock LP {bounds['strip_lp']}); "
          f"strips: {report['strips']['method']}; {report['runtime_s']:.1f} s")
    for remnant in result.nesting.remnants:
        print(f"remnant {remnant['id']}: {remnant['width']:.1f} x {remnant['height']:.1f} mm at "
              f"({remnant['x']:.1f}, {remnant['y']:.1f}) on sheet {remnant['sheet']}")
    if args.svg:
        written = write_sheet_svgs(result.nesting, partset, args.svg)
        print(f"{len(written)} SVG pictures in {args.svg}")
    if args.stock_out:
        prefix = Path(args.output).stem
        save_stock(stock_after(stock, [s.stock for s in result.nesting.sheets], result.nesting.remnants, prefix),
                   args.stock_out)
        print(f"{args.stock_out}: stock after this job")
    return 0


def _check(path: str) -> int:
    """Validate a nesting against its parts file; list every problem on stderr, one line each naming the sheet and
    part, and the verdict on stdout; exit 1 if there are any."""
    from fabline.nest import load_nesting, parts_path, validate_nesting
    from fabline.nest.validate import check_fit
    from fabline.unroll import load_parts

    nesting = load_nesting(path)
    partset = load_parts(parts_path(path, nesting))
    check_fit(nesting, partset, path)
    problems = validate_nesting(nesting, partset)
    for problem in problems:
        print(f"fabline nest: {path}: {problem}", file=sys.stderr)
    placed = sum(len(s.placements) for s in nesting.sheets)
    print(f"{path}: {'FAILED' if problems else 'ok'}: {placed} placements on {len(nesting.sheets)} sheets, "
          f"{len(partset.parts)} parts, {len(problems)} problems")
    return 1 if problems else 0
