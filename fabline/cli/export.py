"""CLI for the export stage: `fabline export` (DXF and G-code per sheet) and `fabline gcode-check`."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from fabline.cli.choices import STOCK_BUILD_OPTIONS
from fabline.cli.units import length_mm
from fabline.errors import FablineError
from fabline.fileio import check_outputs
from fabline.units import duration, metres


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add `export` and `gcode-check`."""
    export = subparsers.add_parser("export", help="nested sheets to DXF and G-code",
                                   description="Write per sheet a DXF (R2010, mm, one layer per operation) and a "
                                               "G-code program for the machine, plus an all-sheets DXF.")
    export.add_argument("nesting", help="nesting.json (fabline.nesting/1); its parts file is read too")
    export.add_argument("-o", "--output", metavar="DIR", help="folder for the DXF files, the G-code programs and "
                        "their previews (default: NESTING-export/ beside the nesting file)")
    export.add_argument("--dxf", metavar="DIR", help="folder for the DXF files instead (with --gcode alone: none)")
    export.add_argument("--gcode", metavar="DIR", help="folder for the G-code programs instead (with --dxf alone: none)")
    export.add_argument("--machine", default="grbl-laser",
                        help="machine profile: a built-in name (grbl-laser, fibre-laser, grbl-plotter, rs274-mill) or a "
                             ".toml path")
    export.add_argument("--kerf", type=length_mm, metavar="MM", help="cut width, mm (default: the machine profile's)")
    export.add_argument("--lead-in", type=length_mm, metavar="MM",
                        help="lead-in length for closed cuts, mm, from a pierce point off every part; 0: none "
                             "(default: the profile's [cutting] lead_in)")
    export.add_argument("--pierce-clearance", type=length_mm, metavar="MM",
                        help="least distance from a pierce point to any part on the sheet, mm (default: the profile's)")
    export.add_argument("--tabs", type=int,
                        help="uncut bridges (micro-joints) on every outer contour; 0: none (default: the profile's "
                             "rule, on parts smaller than --tabs-below)")
    export.add_argument("--tab-width", type=length_mm, metavar="MM",
                        help="uncut length of toolpath per tab, mm (default: the profile's)")
    export.add_argument("--tabs-below", type=length_mm, metavar="MM",
                        help="the profile's tab rule: parts whose bounding box's longer side is under this (mm) get tabs, one "
                             "per --tab-every of perimeter, at least 2; 0: none (default: the profile's)")
    export.add_argument("--tab-every", type=length_mm, metavar="MM", help="perimeter per tab in the rule, mm (default: "
                        "the profile's)")
    export.add_argument("--no-preview", action="store_true",
                        help="skip the cut-order preview SVG beside each G-code program (about 1 s of CPU per sheet)")
    export.add_argument("--no-optimise", action="store_true", help="keep the nesting's part order (no travel optimisation)")
    export.set_defaults(func=run_export)

    check = subparsers.add_parser("gcode-check", help="read a G-code program back and check it against a machine",
                                  description="Report every line the controller would refuse (for a Grbl profile: "
                                              "its error code in words), $ commands, real-time characters, NUL bytes, "
                                              "F0 feeds, long lines, out-of-bed moves and travel with the tool on; "
                                              "warn of codes the controller accepts but the profile's exporter never "
                                              "writes; recompute cut length, travel and run time.")
    check.add_argument("file", help="G-code program")
    check.add_argument("--machine", default="grbl-laser", help="machine profile name or .toml path")
    check.add_argument("--build-options", default=STOCK_BUILD_OPTIONS, metavar="LETTERS",
                       help="the option letters of the Grbl build's $I answer [OPT:LETTERS,...]: M accepts M7, R M56 "
                            f"({STOCK_BUILD_OPTIONS}: a stock Grbl 1.1h)")
    check.set_defaults(func=run_check)


def run_export(args: argparse.Namespace) -> int:
    """Export and print a per-sheet summary table."""
    from fabline.export import ToolpathOptions, export_nesting
    from fabline.export.job import cutting_summary, export_outputs
    from fabline.machine import load_machine
    from fabline.machine.profile import TOOLPATH_MINIMA
    from fabline.nest.layout import load_nesting, parts_path

    profile = load_machine(args.machine)
    given = {"kerf": args.kerf, "lead_in": args.lead_in, "pierce_clearance": args.pierce_clearance, "tabs": args.tabs,
             "tab_width": args.tab_width, "tabs_below": args.tabs_below, "tab_every": args.tab_every}
    for key, value in given.items():
        low = TOOLPATH_MINIMA[key]
        if value is not None and not low <= value < math.inf:
            raise FablineError(f"--{key.replace('_', '-')}: must be a finite number, at least {low:g}, got {value}")
    options = ToolpathOptions.for_profile(profile, optimise=not args.no_optimise, **given)
    dxf_dir, gcode_dir = args.dxf, args.gcode
    if dxf_dir is None and gcode_dir is None:
        dxf_dir = gcode_dir = args.output or default_export_folder(args.nesting)
    elif args.output:
        dxf_dir, gcode_dir = dxf_dir or args.output, gcode_dir or args.output
    nesting = load_nesting(args.nesting)
    written = export_outputs(nesting, profile, dxf_dir, gcode_dir, Path(args.nesting).stem, not args.no_preview)
    check_outputs(files=written, folders=(dxf_dir, gcode_dir),
                  inputs=(args.nesting, parts_path(args.nesting, nesting), profile.source))
    result = export_nesting(args.nesting, profile, options, dxf_dir, gcode_dir, previews=not args.no_preview)
    for path in result.files:
        print(f"wrote {path}")
    folders = dict.fromkeys(str(f) for f in (dxf_dir, gcode_dir) if f is not None)
    print(f"{len(result.files)} files in {' and '.join(folders)}")
    print(f"\nmachine {result.machine}, kerf {result.kerf:g} mm; " + "; ".join(cutting_summary(options)))
    if profile.main_output == "dxf":
        print(f"machine {profile.name} cuts from the DXF in its own CAM (with its own lead-ins and micro-joints); the "
              "G-code and the times below are fabline's plan of the cuts with the settings above")
    for sheet in result.sheets:
        if sheet.no_lead_in:
            count = len(sheet.no_lead_in)
            print(f"sheet {sheet.sheet}: {count} cut{'s' * (count != 1)} without a lead-in (no room for one "
                  f"{options.pierce_clearance:g} mm clear of every part), first on part {sheet.no_lead_in[0]}")
    print(f"{'sheet':<12}{'parts':>6}{'cut m':>11}{'mark m':>10}{'travel m':>10}{'time':>10}")
    for sheet in result.sheets + [None]:
        summary = sheet.summary if sheet else result.totals()
        label, count = (sheet.sheet, sheet.parts) if sheet else ("total", sum(s.parts for s in result.sheets))
        print(f"{label:<12}{count:>6}{metres(summary.cut_length):>11}{metres(summary.mark_length):>10}"
              f"{metres(summary.travel):>10}{duration(summary.time):>10}")
    return 0


def default_export_folder(nesting: str | Path) -> Path:
    """Where `export` writes when given no folder: `<nesting stem>-export/` beside the nesting file."""
    nesting = Path(nesting)
    return nesting.with_name(f"{nesting.stem}-export")


def run_check(args: argparse.Namespace) -> int:
    """Check one program; exit 1 when problems were found (warnings, on stderr, leave the exit code 0)."""
    from fabline.export import check_gcode
    from fabline.machine import load_machine
    from fabline.machine.build import BuildInfo

    build = BuildInfo(options=args.build_options)
    report = check_gcode(args.file, load_machine(args.machine), build)
    for warning in report.warnings:
        print(f"fabline gcode-check: warning: {args.file}: {warning}", file=sys.stderr)
    for problem in report.problems:
        print(f"{args.file}: {problem}")
    s = report.summary
    print(f"{args.file}: {report.lines} lines, {s.moves} moves, cut {metres(s.cut_length)} m, mark {metres(s.mark_length)} m, "
          f"travel {metres(s.travel)} m, estimated {duration(s.time)} ({s.time:.1f} s)")
    print(f"{args.file}: {len(report.problems)} problem(s)" if report.problems else f"{args.file}: ok")
    return 1 if report.problems else 0
