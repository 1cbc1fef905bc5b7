"""CLI for the analysis stage: `fabline analyse` solves the erected gridshell on OpenSees and writes analysis.json."""

from __future__ import annotations

import argparse
import sys

from fabline.cli import positive
from fabline.cli.units import load_area, load_point
from fabline.errors import FablineError
from fabline.fileio import check_outputs


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add `analyse`."""
    parser = subparsers.add_parser("analyse", help="load analysis of the erected gridshell on OpenSees "
                                                   "(the analysis extra)")
    parser.add_argument("model", help="the network model the parts were unrolled from")
    parser.add_argument("parts", help="its fabline.parts/1 file (profile, material, pair spacing, cables)")
    parser.add_argument("-o", "--output", required=True, help="analysis JSON to write")
    parser.add_argument("--materials", metavar="FILE", help="TOML file with more materials (E, G, f_y, density)")
    parser.add_argument("--supports", choices=("pinned", "fixed"), default="pinned",
                        help="how the support nodes hold the shell")
    parser.add_argument("--stations", type=positive(int, 16), default=2, help="beams per node interval")
    parser.add_argument("--snow", type=load_area, default=0.75, metavar="LOAD",
                        help="snow on the plan area (or with a unit: 0.8kPa, 750 N/m2)")
    parser.add_argument("--wind", type=load_area, default=0.5, metavar="LOAD",
                        help="wind pressure normal to the shell (or with a unit)")
    parser.add_argument("--person", type=load_point, default=1000.0, metavar="LOAD",
                        help="a person's point load (or with a unit: 1.5kN)")
    parser.add_argument("--no-buckling", action="store_true", help="skip the buckling factor search")
    parser.set_defaults(func=run_analyse)


def run_analyse(args: argparse.Namespace) -> int:
    """Analyse and print one line per load case."""
    from fabline.unroll import load_parts
    from fabline.model import load_network

    check_outputs(files=(args.output,), inputs=(args.model, args.parts, args.materials))
    network = load_network(args.model).in_mm()
    partset = load_parts(args.parts)
    from fabline.analysis.loads import LoadSettings
    from fabline.analysis.parts import analyse_parts, case_lines
    from fabline.fileio import write_json

    settings = LoadSettings(snow=args.snow, wind=args.wind, person=args.person)
    record = analyse_parts(network, partset, settings, supports=args.supports, stations=args.stations,
                           buckling=not args.no_buckling, materials_file=args.materials, where=(args.model, args.parts))
    write_json(args.output, {"schema": "fabline.analysis/1", "units": "mm, N, N/mm2 (reactions kN)",
                             "model_file": args.model, "parts_file": args.parts, **record})
    for line in case_lines(record):
        print(line)
    print(f"{args.output}: {record['model']['nodes']} nodes, {record['model']['beams']} beams, "
          f"{sum(record['seconds'].values()):.1f} s")
    _warn_unverified(record)
    return 0


RESIDUAL_TRUST_PCT = 2.0
"""The unloaded frame must carry the geometric check's stresses this closely (median beam) to be trusted."""


def _warn_unverified(record: dict) -> None:
    """Say on stderr when the figures above rest on a frame that does not carry the erection's stresses as the
    geometric check computes them (a model that does not reproduce its own unloaded state), that cannot buckle between
    joints, or did not converge, and which cases buckle."""
    bending = record["residual_check"]["bending"]
    failed = [name for name, case in record["cases"].items() if not case["converged"]]
    if bending["deviation_median_pct"] > RESIDUAL_TRUST_PCT:
        print(f"warning: the unloaded frame's weak-axis bending differs from the geometric check by "
              f"{bending['deviation_median_pct']:.1f} % at the median beam ({bending['deviation_max_pct']:.0f} % at "
              f"the worst): this frame does not reproduce the erected state, so its figures are unverified",
              file=sys.stderr)
    if record["model"]["stations"] == 1:
        print("warning: with one beam per node interval (--stations 1) a strip cannot buckle between its joints: the "
              "buckling factors are upper bounds (the pavilion's erection factor: 162 with 1, 8.7 with 4)", file=sys.stderr)
    factors = record.get("buckling", {}).get("factors", {})
    buckles = [name for name, factor in factors.items() if factor is not None and factor <= 1.0]
    if buckles:
        print(f"warning: {len(buckles)} load case(s) buckle (linear buckling factor at most 1: "
              f"{', '.join(f'{name} {factors[name]:.3f}' for name in buckles)}): the shell does not carry them",
              file=sys.stderr)
    if failed:
        print(f"warning: {len(failed)} load case(s) did not converge ({', '.join(failed)}): their figures are the last "
              f"state reached, not an equilibrium", file=sys.stderr)
