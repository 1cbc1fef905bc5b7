"""CLI for the unroll stage: `fabline unroll` (network to flat parts) and `fabline limits` (a profile's limits)."""

from __future__ import annotations

import argparse
import json
import sys

from fabline.cli.choices import SINGULARITY_MODES
from fabline.cli.units import length_mm, profile
from fabline.errors import FablineError
from fabline.fileio import check_outputs


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add `unroll` and `limits`."""
    unroll = subparsers.add_parser(
        "unroll", help="unroll every lamella to flat strips with slots, marks, labels and seams",
        description="Write parts.json (fabline.parts/1): one flat part per lamella segment, washers, clamps and "
                    "singularity joints, and a structural report. Warnings go to stderr.")
    unroll.add_argument("model", help="a fabline.network/1 JSON file")
    unroll.add_argument("-o", "--output", required=True, help="parts JSON to write")
    _material_arguments(unroll)
    unroll.add_argument("--pair-spacing", type=length_mm, default=25.0, metavar="MM",
                        help="distance of a pair's two strips; 0 makes single lamellas")
    unroll.add_argument("--slot-clearance", type=length_mm, default=1.0, metavar="MM", help="slot depth beyond h/2")
    unroll.add_argument("--slot-width", type=length_mm, metavar="MM", help="slot width, mm (default twice the thickness)")
    unroll.add_argument("--overlap", type=length_mm, default=150.0, metavar="MM", help="seam overlap length")
    unroll.add_argument("--min-overlap", type=length_mm, metavar="MM",
                        help="where no seam fits, overlaps may shorten to this, mm (default two thirds of --overlap)")
    unroll.add_argument("--screw-hole", type=length_mm, default=5.5, metavar="MM", help="seam screw hole diameter")
    unroll.add_argument("--sheet-length", type=length_mm, default=4000.0, metavar="MM",
                        help="sheet length (the longer side of --sheet-size)")
    unroll.add_argument("--sheet-margin", type=length_mm, default=10.0, metavar="MM", help="unused border of each sheet")
    unroll.add_argument("--end-length", type=length_mm, metavar="MM", help="strip beyond its last slot, mm (default h/2)")
    unroll.add_argument("--compensate-twist", action="store_true",
                        help="lengthen node distances by the twisted centre fibre's helix contraction")
    unroll.add_argument("--singularity", choices=SINGULARITY_MODES, default="joint",
                        help="valence-6 nodes: a separate hexagonal joint or slots for three pairs")
    unroll.add_argument("--no-hardware", action="store_true", help="leave out washers, clamps and joints")
    unroll.add_argument("--edge-members", action=argparse.BooleanOptionalAction, default=False,
                        help="also the boundary curves as flat curved bars, top and bottom, a bolt hole at each "
                             "lamella end")
    unroll.add_argument("--edge-width", type=length_mm, metavar="MM",
                        help="edge member bar width in mm (none: the profile height)")
    unroll.add_argument("--cable-pretension", default="1 mm/m", metavar="STRAIN",
                        help="cut the bracing cables this much short: '1 mm/m', '0.1 %%' (default 1 mm/m)")
    unroll.add_argument("--cable-end-allowance", type=length_mm, default=80.0, metavar="MM",
                        help="cable beyond each end clamp's centre, for its outer hole and end stop (default 80 mm)")
    unroll.add_argument("--supports", action=argparse.BooleanOptionalAction, default=False,
                        help="also a bracket (fin and base plate) at every support node, cut from plate")
    unroll.add_argument("--support-plate", type=length_mm, default=6.0, metavar="MM",
                        help="the brackets' plate thickness (default 6 mm)")
    unroll.add_argument("--support-material", default="steel-s235", help="the brackets' plate material")
    unroll.add_argument("--support-height", type=length_mm, default=150.0, metavar="MM",
                        help="from a support's bolt down to its footing (default 150 mm)")
    unroll.add_argument("--couplers", type=int, default=0, metavar="N",
                        help="shear blocks between a pair's strips in the N node intervals next to each support (default 0)")
    unroll.add_argument("--text-height", type=length_mm, default=6.0, metavar="MM", help="engraved text height")
    unroll.add_argument("--min-crossing-angle", type=float, default=30.0, metavar="DEG",
                        help="smallest crossing angle the slotted joint reaches, degrees")
    unroll.add_argument("--strict", action="store_true", help="treat over-stress warnings as errors")
    unroll.add_argument("--svg", metavar="DIR", help="also write one SVG preview per strip into DIR")
    unroll.add_argument("--json", action="store_true", help="print the report as JSON instead of a table")
    unroll.set_defaults(func=run_unroll)

    check = subparsers.add_parser("limits", help="minimum bending radius, maximum twist and stresses of a profile",
                                  description="A designer's quick check of a strip profile before any model exists "
                                              "(domain.md section 6).")
    _material_arguments(check)
    check.add_argument("--radius", type=length_mm, metavar="MM", help="also the bending stress at this radius, mm")
    check.add_argument("--twist", type=float, metavar="RAD_PER_M", help="also the stresses at this twist")
    check.add_argument("--json", action="store_true", help="print JSON")
    check.set_defaults(func=run_limits)


def _material_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--profile", type=profile, default="100x1.5", metavar="HxT", help="strip height x thickness in mm")
    parser.add_argument("--material", default="steel-s235", help="material name (built-in: steel-s235, stainless)")
    parser.add_argument("--materials", metavar="FILE", help="TOML file with more materials (E, G, f_y, density)")


def run_unroll(args: argparse.Namespace) -> int:
    """Unroll, write the parts (and previews), print the lamella table; warnings to stderr."""
    from fabline.mechanics import get_material, parse_profile
    from fabline.model import load_network
    from fabline.unroll import UnrollOptions, save_parts
    from fabline.unroll.cables import parse_pretension

    check_outputs(files=(args.output,), folders=(args.svg,), inputs=(args.model, args.materials))
    network = load_network(args.model)
    get_material(args.support_material, args.materials)  # the support plates' material must be known too
    options = UnrollOptions(
        profile=parse_profile(args.profile), material=get_material(args.material, args.materials),
        pair_spacing=args.pair_spacing, slot_clearance=args.slot_clearance, slot_width=args.slot_width,
        overlap=args.overlap, min_overlap=args.min_overlap, screw_hole=args.screw_hole,
        sheet_length=args.sheet_length, sheet_margin=args.sheet_margin, end_length=args.end_length,
        compensate_twist=args.compensate_twist,
        singularity=args.singularity, hardware=not args.no_hardware, text_height=args.text_height,
        min_crossing_angle=args.min_crossing_angle, strict=args.strict, edge_members=args.edge_members,
        edge_width=args.edge_width, cable_pretension=parse_pretension(args.cable_pretension, "--cable-pretension"),
        cable_end_allowance=args.cable_end_allowance, supports=args.supports, support_plate=args.support_plate,
        support_material=args.support_material, support_height=args.support_height, couplers=args.couplers)
    from fabline.mechanics.structure import percent, verdict_lines
    from fabline.unroll import unroll_network  # after the model and the options are checked: it takes a second
    from fabline.unroll.preview import write_previews

    try:
        partset = unroll_network(network, options)
    except FablineError as exc:
        raise FablineError(f"{args.model}: {exc}") from None
    partset.source = args.model
    save_parts(partset, args.output)
    if args.svg:
        write_previews(partset, args.svg)
    report = partset.report
    for line in report["warnings"]:
        print(f"fabline unroll: warning: {line}", file=sys.stderr)
    if args.json:
        print(json.dumps({"output": args.output, **report}, indent=1))
        return 0
    _print_table(report["lamellas"])
    s = report["summary"]
    kinds = ", ".join(f"{count} {kind}" for kind, count in s["parts_by_kind"].items())
    print(f"\n{args.output}: {s['parts']} parts ({kinds}) from {s['lamellas']} lamellas, {s['strips']} strips, "
          f"{s['strip_length_m']:.3f} m of strip; max utilisation {percent(s['max_utilisation'])} "
          f"({s['governing_check']}, lamella {s['governing_lamella']}); {s['warnings']} warnings")
    if report["verdict"]:
        print("\n".join(verdict_lines(report["verdict"])))
    if "edges" in report:
        edges = report["edges"]
        worst = max(edges["members"], key=lambda row: row["utilisation"], default=None)
        print(f"edge members: {len(edges['members'])} boundary curves, {len(edges['bars'])} bars "
              f"{edges['width_mm']:g} x {edges['thickness_mm']:g} mm, {edges['bolt_hole_mm']:g} mm bolt holes"
              + (f"; max utilisation {percent(worst['utilisation'])} ({worst['governing']}, {worst['edge']})" if worst else ""))
    if partset.plates:
        print(f"supports: {len(partset.plates.parts)} plates ({partset.plates.profile['t']:g} mm "
              f"{partset.plates.material}) at {len({p.meta['node'] for p in partset.plates.parts})} support nodes")
    if "couplers" in report:
        print(f"couplers: {report['couplers']['placed']} shear blocks, {len(report['couplers']['skipped'])} intervals "
              "skipped for a seam or too short")
    if "cables" in report:
        cables = report["cables"]
        print(f"cables: {cables['runs']} diagonal runs through {cables['clamps']} clamps, "
              f"{cables['geometric_length_m']:.3f} m geometric, {cables['cut_length_m']:.3f} m cut "
              f"({cables['pretension_mm_per_m']:g} mm/m pretension, {cables['end_allowance_mm']:g} mm per end)")
    return 0


def _print_table(rows: list[dict]) -> None:
    from fabline.mechanics.structure import percent

    print(f"{'lamella':<10}{'length m':>10}{'min r m':>10}{'twist /m':>10}{'sigma_b':>9}{'tau':>8}{'sigma_H':>9}"
          f"{'util %':>8}{'slot %':>8}{'helix top/bot mm':>18}")
    for r in rows:
        radius = f"{r['min_radius_mm'] / 1000:.3f}" if r["min_radius_mm"] else "inf"
        print(f"{r['lamella']:<10}{r['length_mm'] / 1000:>10.3f}{radius:>10}{r['max_twist_rad_per_m']:>10.3f}"
              f"{r['max_bending_stress']:>9.1f}{r['max_shear_stress']:>8.1f}{r['max_helix_stress']:>9.1f}"
              f"{percent(r['utilisation'])[:-2]:>8}{percent(r['slot_utilisation'])[:-2] if r['slot_node'] else '-':>8}"
              f"{r['helix_top_edge_extension_mm']:>9.1f}/{r['helix_bottom_edge_extension_mm']:.1f}")


def run_limits(args: argparse.Namespace) -> int:
    """Print the profile's minimum radius and maximum twist, and stresses at a given radius or twist."""
    from fabline.mechanics import get_material, limits, parse_profile
    from fabline.mechanics.structure import percent

    for name, value in (("--radius", args.radius), ("--twist", args.twist)):
        if value is not None and not value > 0:
            raise FablineError(f"{name}: must be positive, got {value:g}")
    result = limits(get_material(args.material, args.materials), parse_profile(args.profile), args.radius, args.twist)
    if args.json:
        print(json.dumps(result, indent=1))
        return 0
    print(f"profile {result['profile']} mm, {result['material']}: E {result['E']:g}, G {result['G']:g}, "
          f"f_y {result['f_y']:g}, tau_y {result['tau_y']:.1f} N/mm2")
    print(f"minimum bending radius (weak axis)  {result['min_bending_radius_mm']:.1f} mm")
    print(f"maximum twist                       {result['max_twist_rad_per_m']:.3f} rad/m "
          f"({result['max_twist_deg_per_m']:.1f} deg/m) by shear alone; "
          f"{result['combined_max_twist_rad_per_m']:.3f} rad/m by the combined check (the verdict's)")
    if "at_radius" in result:
        r = result["at_radius"]
        print(f"at radius {r['radius_mm']:g} mm: bending stress {r['bending_stress']:.1f} N/mm2, "
              f"utilisation {percent(r['utilisation'])}")
    if "at_twist" in result:
        t = result["at_twist"]
        print(f"at twist {t['twist_rad_per_m']:g} rad/m: shear {t['shear_stress']:.1f} N/mm2 "
              f"({percent(t['shear_utilisation'])}), helix stress {t['helix_stress_min']:.2f} / "
              f"{t['helix_stress_max']:.2f} N/mm2 ({percent(t['helix_utilisation'])}), strain "
              f"{t['helix_strain_min']:.6f} / {t['helix_strain_max']:.6f}, centre contracts "
              f"{t['centre_contraction_mm_per_m']:.3f} mm/m")
        with_radius = f" with radius {args.radius:g} mm" if args.radius else ""
        verdict = "within yield" if t["combined_utilisation"] <= 1.0 else "OVER YIELD"
        print(f"combined{with_radius} (von Mises at the face centre, bending plus helix at the edge): "
              f"{percent(t['combined_utilisation'])} of f_y, {verdict} (the verdict's rule, docs/unrolling.md)")
    return 0
