"""CLI for importing a network model: `fabline import FILE [--surface MESH] -o out.network.json`."""

from __future__ import annotations

import argparse

from fabline.cli.choices import IMPORT_FORMATS, MODEL_UNITS
from fabline.cli.units import length_mm
from fabline.fileio import check_outputs


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add `import`."""
    parser = subparsers.add_parser(
        "import", help="read a network model from CAD curves or fabline JSON, validate it and write it",
        description=f"Read lamella curves ({', '.join(IMPORT_FORMATS)}), find the nodes where the two families "
                    "cross, take normals from the reference surface, and write a fabline.network/1 model.")
    parser.add_argument("file", help="curves (.obj, .dxf, .3dm) or a fabline.network/1 JSON file")
    parser.add_argument("--surface", help="reference surface mesh for the normals (.obj, .stl, .ply, .dxf, .3dm, ...); "
                                          "default: faces, meshes or surfaces in FILE")
    parser.add_argument("--units", choices=MODEL_UNITS,
                        help="units of a file that declares none (OBJ); default m, with a note")
    parser.add_argument("--tolerance", type=length_mm, default=1.0, metavar="MM",
                        help="two lamellas closer than this cross at a node")
    parser.add_argument("--supports", metavar="RULE",
                        help="support nodes: 'z<0.05' (below a level), 'x,y x,y x,y ...' (inside a plan polygon), both "
                             "in model units, or the layer/group/object name of points at the supports")
    parser.add_argument("-o", "--output", required=True, help="network JSON to write")
    parser.set_defaults(func=run_import)


def run_import(args: argparse.Namespace) -> int:
    """Import, print the summary (counts, near-misses, notes), write the model."""
    from fabline.model import save_network
    from fabline.model.importers import import_model

    check_outputs(files=(args.output,), inputs=(args.file, args.surface))
    network, report = import_model(args.file, args.surface, args.units, args.tolerance, args.supports)
    save_network(network, args.output)
    for line in report.summary():
        print(line)
    print(f"wrote {args.output}")
    return 0
