"""CLI for the assembly plan: `fabline assembly` (parts.json and its model to segments, order and printable pages)."""

from __future__ import annotations

import argparse
import json
import os

from fabline.cli import positive
from fabline.cli.units import length_m
from fabline.errors import FablineError
from fabline.fileio import check_outputs

DEFAULT_MAX_SEGMENT_M = 5.0
"""The largest segment by default, m: the pavilion (9 x 12 m) comes out in 9 segments, as the thesis built it."""


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add `assembly`."""
    parser = subparsers.add_parser(
        "assembly", help="assembly plan: prefabricated segments, laying order, a printable page per lamella",
        description="Cut the network into connected segments built flat (a number of them, or the fewest within a "
                    "size), order the strips in each, and write an overview page and one SVG page per lamella "
                    "(A3 landscape) with assembly.json into the output folder.")
    parser.add_argument("parts", help="a fabline.parts/1 JSON file (from fabline unroll)")
    parser.add_argument("-o", "--output", required=True, metavar="FOLDER", help="folder for the pages and assembly.json")
    parser.add_argument("--model", help="the fabline.network/1 file the parts were unrolled from "
                                        "(default: the one the parts file names)")
    size = parser.add_mutually_exclusive_group()
    size.add_argument("--segments", type=positive(int, 1000), metavar="N", help="this many segments")
    size.add_argument("--max-segment", type=length_m, default=DEFAULT_MAX_SEGMENT_M, metavar="LENGTH",
                      help="the fewest segments no larger than this along x, y and z (unless --segments)")
    parser.add_argument("--json", action="store_true", help="print the plan as JSON")
    parser.set_defaults(func=run_assembly)


def run_assembly(args: argparse.Namespace) -> int:
    """Plan, write the pages and assembly.json, print the segments table."""
    from fabline.unroll import load_parts

    check_outputs(folders=(args.output,), inputs=(args.parts, args.model))
    partset = load_parts(args.parts)
    model = args.model or partset.source
    if not model or not os.path.isfile(model):
        raise FablineError(f"{args.parts}: names its model as {partset.source!r}, which is not a file here: give "
                           "--model, the network the parts were unrolled from")
    from fabline.assembly import plan_assembly
    from fabline.assembly.pdf import PDF
    from fabline.assembly.sheets import write_pages
    from fabline.fileio import write_json
    from fabline.model import load_network

    network = load_network(model)
    if not args.max_segment > 0:
        raise FablineError(f"--max-segment: must be a positive length, got {args.max_segment:g} m")
    try:
        plan = plan_assembly(network, partset, args.segments, None if args.segments else args.max_segment * 1000.0)
    except FablineError as exc:
        raise FablineError(f"{args.parts}: {exc}") from None
    pages = write_pages(plan, args.output)
    summary = plan.summary()
    write_json(os.path.join(args.output, "assembly.json"), {"schema": "fabline.assembly/1", **summary,
                                                             "pages": [p.name for p in pages]})
    if args.json:
        print(json.dumps(summary, indent=1))
        return 0
    print(f"{'segment':>7}{'nodes':>7}{'pieces':>8}{'lamellas':>10}{'extent m':>10}{'strip m':>9}{'site x':>8}"
          f"{'site seams':>12}")
    for row in summary["segments"]:
        print(f"{row['segment']:>7}{row['nodes']:>7}{row['pieces']:>8}{row['lamellas']:>10}"
              f"{row['extent_mm'] / 1000.0:>10.2f}{row['strip_length_m']:>9.1f}{row['site_crossings']:>8}"
              f"{row['site_seams']:>12}")
    count = len(plan.segments)
    print(f"{args.output}: {len(pages) - 1} lamella pages and the overview (SVG, and all in {PDF}), {count} segment{'s' * (count != 1)}; "
          f"{len(summary['site_crossings'])} crossings and {len(summary['site_seams'])} seams made on site")
    return 0
