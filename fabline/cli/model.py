"""CLI for the model stage: `fabline design` (built-in networks) and `fabline inspect` (the curvature table)."""

from __future__ import annotations

import argparse
import json
import math

from fabline.cli.choices import BOUNDARIES, MODEL_UNITS
from fabline.cli.units import length_m, length_mm, length_model, profile, size
from fabline.errors import FablineError
from fabline.fileio import check_outputs


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add `design` and `inspect`."""
    design = subparsers.add_parser("design", help="build an asymptotic network on a minimal surface")
    kinds = design.add_subparsers(dest="design", metavar="SURFACE", required=True)
    enneper = kinds.add_parser("enneper", help="Enneper surface, sized like the reference pavilion by default")
    enneper.add_argument("--size", type=size("m"), default=(9.0, 12.0), metavar="XxY",
                         help="footprint x by y, e.g. 9x12 (m) or 9000x12000mm")
    enneper.add_argument("--spacing", type=length_m, default=0.35, help="node spacing along the axes")
    enneper.add_argument("--k-max", type=float, default=1.1, help="largest principal curvature, 1/m")
    enneper.add_argument("--boundary", choices=BOUNDARIES, default="ellipse", help="shape of the parameter domain")
    catenoid = kinds.add_parser("catenoid", help="catenoid, axis z, waist circle at z = 0")
    catenoid.add_argument("--waist", type=length_m, default=1.0, help="waist radius")
    catenoid.add_argument("--height", type=length_m, default=3.0, help="height, centred on the waist")
    catenoid.add_argument("--count", type=int, default=16, help="lamellas per family")
    helicoid = kinds.add_parser("helicoid", help="helicoid: straight rulings and helices")
    helicoid.add_argument("--pitch", type=length_m, default=6.0, help="rise per turn")
    helicoid.add_argument("--radius", type=length_m, default=3.0, help="outer radius")
    helicoid.add_argument("--turns", type=float, default=0.5, help="how many turns the patch spans")
    helicoid.add_argument("--spacing", type=length_m, default=0.35, help="node spacing")
    for sub in (enneper, catenoid, helicoid):
        sub.add_argument("-o", "--output", required=True, help="network JSON to write")
        sub.set_defaults(func=run_design)
    _register_surface_designs(kinds)

    inspect = subparsers.add_parser("inspect", help="table of lamellas, lengths, curvatures and crossing angles")
    inspect.add_argument("model", help="a fabline.network/1 JSON file")
    inspect.add_argument("--json", action="store_true", help="print the table as JSON")
    inspect.set_defaults(func=run_inspect)


def _register_surface_designs(kinds: argparse._SubParsersAction) -> None:
    """`design asymptotic` (trace a network on a designer's surface) and `design minimal` (a surface from its edges)."""
    traced = kinds.add_parser("asymptotic", help="trace an asymptotic network on an anticlastic mesh or .3dm surface")
    traced.add_argument("--surface", required=True, help="surface: OBJ, STL, PLY (trimesh) or .3dm (rhino3dm)")
    traced.add_argument("--spacing", type=length_model, required=True,
                        help="node spacing along the curves, in model units (the surface's) or with a unit: 0.35, 17mm")
    traced.add_argument("--seed", type=_point, metavar="X,Y,Z",
                        help="the point the rails start from, model units, e.g. -0.22,0.04,0.006 (default: the "
                             "surface's centre)")
    traced.add_argument("--supports", help="nodes matching this rule are supports, e.g. z<0.05")
    traced.add_argument("--seed-curves", help="one or two curves on the surface (.dxf or .json) to use as the rail and "
                        "the middle curve")
    traced.add_argument("--units", choices=MODEL_UNITS, help="units of a mesh file that declares none (default m)")
    traced.add_argument("--step", type=length_model,
                        help="tracing step, in model units or with a unit (default spacing/4)")
    traced.add_argument("--material", default="steel-s235", help="lamella material for the limits")
    traced.add_argument("--profile", type=profile, default="100x1.5", metavar="HxT",
                        help="lamella profile height x thickness in mm for the limits")
    traced.add_argument("--pair-spacing", type=length_mm, default=25.0, metavar="MM",
                        help="the unroll's distance of a pair's two strips, mm or with a unit (its --pair-spacing): "
                             "every crossing handed over leaves them room for their slots")
    traced.add_argument("--slot-width", type=length_mm, metavar="MM",
                        help="the unroll's slot width, mm (its --slot-width; default twice the thickness)")
    traced.add_argument("--json", action="store_true", help="print the quality report as JSON")
    traced.add_argument("-o", "--output", required=True, help="network JSON to write")
    traced.set_defaults(func=run_asymptotic)
    minimal = kinds.add_parser("minimal", help="discrete minimal surface spanning closed boundary curves")
    minimal.add_argument("--boundary", required=True, help="closed curves: .dxf (polylines, circles, splines) or .json")
    minimal.add_argument("--mesh-size", type=length_model, required=True,
                         help="triangle size, in model units (the boundary file's) or with a unit: 0.1, 100mm")
    minimal.add_argument("--units", choices=MODEL_UNITS, help="units of a file that declares none (default m)")
    minimal.add_argument("-o", "--output", required=True, help="surface mesh to write (.obj, .stl, .ply, .off)")
    minimal.set_defaults(func=run_minimal)


def _point(text: str) -> tuple[float, float, float]:
    try:
        x, y, z = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"a point must look like 0.2,1.5,0 or -0.22,0.04,0.006, got {text!r}") from None
    if not all(math.isfinite(v) for v in (x, y, z)):
        raise argparse.ArgumentTypeError(f"a point's coordinates must be finite numbers, got {text!r}")
    return x, y, z


def run_asymptotic(args: argparse.Namespace) -> int:
    """Trace the network, write it, print what was found and the quality report."""
    from fabline.design import design_asymptotic, summary_lines
    from fabline.design.curves import read_curves
    from fabline.model import save_network

    check_outputs(files=(args.output,), inputs=(args.surface, args.seed_curves))
    curves = None
    if args.seed_curves:
        found, _ = read_curves(args.seed_curves, args.units)
        if len(found) > 2:
            raise FablineError(f"{args.seed_curves}: {len(found)} curves; give one (the rail) or two (rail and middle curve)")
        curves = [points for points, _ in found]
    design = design_asymptotic(args.surface, args.spacing, args.seed, args.supports, args.units, args.step,
                               args.material, args.profile, curves, args.pair_spacing,
                               None if args.slot_width is None else 2.0 * args.slot_width)
    network = design.network
    save_network(network, args.output)
    report = network.meta["quality"]
    if args.json:
        print(json.dumps({"output": args.output, "notes": design.notes, "regions": network.meta["regions"],
                          "stops": network.meta["stops"], "dropped": network.meta["dropped"], "quality": report}, indent=1))
        return 0
    for note in design.notes:
        print(f"note: {note}")
    print(f"{args.output}: asymptotic network on {args.surface}, {len(network.nodes)} nodes, {len(network.lamellas)} lamellas "
          f"(units {network.units})")
    for region in design.regions:
        print(f"found: {region.describe(network.units)}")
    for stop in design.stops:
        print(f"found: {stop}")
    for line in summary_lines(report, network.units):
        print(f"  {line}")
    return 0


def run_minimal(args: argparse.Namespace) -> int:
    """Compute the minimal surface and write it as a mesh."""
    from fabline.design.minimal import MESH_SIZE_MM, minimal_surface, read_boundaries, write_mesh
    from fabline.model_units import model_length

    check_outputs(files=(args.output,), inputs=(args.boundary,))
    curves, names, units = read_boundaries(args.boundary, args.units)
    mesh_size = model_length(args.mesh_size, units, "--mesh-size", MESH_SIZE_MM, "a triangle size")
    mesh = minimal_surface(curves, mesh_size, args.boundary, names)
    write_mesh(mesh, args.output)
    print(f"{args.output}: minimal surface spanning {len(curves)} boundary curve{'s' * (len(curves) > 1)}, "
          f"{len(mesh.faces)} triangles, area {mesh.area:.4g} {units}2 (units {units})")
    return 0


def run_design(args: argparse.Namespace) -> int:
    """Build the chosen design and write it."""
    from fabline.model import save_network
    from fabline.model.designs import DESIGNS

    check_outputs(files=(args.output,))
    options = {k: v for k, v in vars(args).items() if k not in ("command", "design", "output", "func")}
    network = DESIGNS[args.design](**options)
    save_network(network, args.output)
    from fabline.model.extent import extent_text

    print(f"{args.output}: {args.design} network, {len(network.nodes)} nodes, {len(network.lamellas)} lamellas (units m), "
          f"{extent_text(network)}")
    return 0


def run_inspect(args: argparse.Namespace) -> int:
    """Print the lamella table and a one-line summary for the whole network."""
    from fabline.geometry import analyse, lamella_table
    from fabline.model import load_network

    network = load_network(args.model)
    try:
        rows = lamella_table(analyse(network))
    except FablineError as exc:
        raise FablineError(f"{args.model}: {exc}") from None
    if args.json:
        print(json.dumps({"model": args.model, "units": network.units, "lamellas": rows,
                          **({"quality": network.meta["quality"]} if "quality" in network.meta else {})}, indent=1))
        return 0
    print(f"{'lamella':<10}{'fam':>4}{'nodes':>6}{'length m':>10}{'max k_g':>9}{'max tau_g':>10}{'max k_n':>9}{'angle min..max':>16}")
    for r in rows:
        angle = f"{r['min_angle']:.2f}..{r['max_angle']:.2f}" if r["min_angle"] is not None else "-"
        print(f"{r['lamella']:<10}{r['family']:>4}{r['nodes']:>6}{r['length_m']:>10.3f}{r['max_k_g']:>9.3f}"
              f"{r['max_tau_g']:>10.3f}{r['max_k_n']:>9.2e}{angle:>16}")
    angles = [a for r in rows for a in (r["min_angle"], r["max_angle"]) if a is not None]
    print(f"\n{len(rows)} lamellas, {len(network.nodes)} nodes, total length {sum(r['length_m'] for r in rows):.3f} m; "
          f"max k_g {max(r['max_k_g'] for r in rows):.3f} 1/m, max tau_g {max(r['max_tau_g'] for r in rows):.3f} 1/m, "
          f"max k_n {max(r['max_k_n'] for r in rows):.2e} 1/m; crossing angles "
          + (f"{min(angles):.2f}..{max(angles):.2f} deg" if angles else "none"))
    if "quality" in network.meta:
        from fabline.design import summary_lines

        print(f"\ntraced on the surface {network.meta.get('surface', '')} (fabline design asymptotic):")
        for line in summary_lines(network.meta["quality"], network.units):
            print(f"  {line}")
    return 0
