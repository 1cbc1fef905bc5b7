"""fabline analyse on the pavilion (the example job's design: Enneper, 9 x 12 m, k_max 1.05, 100 x 1.5 stainless,
pairs 25 mm apart): model size, seconds per step and load case, and each case's figures, as one table.

    python benchmarks/analyse_bench.py [--stations N] [--pretension MM_PER_M] [--couplers N] [--no-buckling]

Wall seconds per step, and the whole process's CPU seconds at the end; a frame that does not stand under its erection
stresses is refused, as `fabline analyse` refuses it, and the bench prints the refusal and its time.
"""

import argparse
import time

from fabline.analysis.loads import LoadSettings
from fabline.errors import FablineError
from fabline.analysis.model import ModelOptions, bracing
from fabline.mechanics.hardware import load_catalogue
from fabline.unroll.couplers import coupler_intervals
from fabline.analysis.parts import case_lines
from fabline.analysis.run import analyse
from fabline.geometry.darboux import analyse as geometry_of
from fabline.mechanics.materials import Profile, get_material
from fabline.model.designs import enneper_network


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--stations", type=int, default=2)
    parser.add_argument("--pretension", type=float, default=1.0,
                        help="the cables' pretension strain, mm/m (unroll's default 1)")
    parser.add_argument("--couplers", type=int, default=2,
                        help="shear blocks in this many node intervals from each support (the pavilion job's 2)")
    parser.add_argument("--no-buckling", action="store_true")
    args = parser.parse_args()
    start = time.perf_counter()
    network = enneper_network((9.0, 12.0), 0.35, 1.05).in_mm()
    geometry = geometry_of(network)
    options = ModelOptions(stations=args.stations, cables=bracing(network), cable=load_catalogue().cable,
                           cable_prestrain=args.pretension / 1000.0,
                           couplers=tuple(coupler_intervals(network, args.couplers)))
    prepared = time.perf_counter() - start
    try:
        record = analyse(geometry, get_material("stainless"), Profile(100.0, 1.5), options,
                         LoadSettings(), buckling=not args.no_buckling)
    except FablineError as refused:
        print(f"stations {args.stations}, pretension {args.pretension:g} mm/m: refused after "
              f"{time.perf_counter() - start:.1f} s wall, {time.process_time():.1f} s CPU: {refused}")
        return
    model = record["model"]
    print(f"pavilion: {len(geometry.network.nodes)} network nodes -> {model['nodes']} frame nodes, {model['beams']} beams, "
          f"{model['links']} washer and coupler links ({model['couplers']} couplers), {model['hinges']} hinges, {model['cables']} cable members, {model['supports']} supports, {model['dofs']} DOFs; "
          f"geometry {prepared:.1f} s")
    factors = record.get("buckling", {}).get("factors", {})
    print(f"{'step':<34} {'s':>7} {'max defl mm':>12} {'max reaction kN':>16} {'max util':>9} {'buckling':>9} converged")
    for step, seconds in record["seconds"].items():
        case = record["cases"].get(step)
        factor = factors.get(step)
        figures = (f"{case['max_deflection_mm']:>12.2f} {case['max_reaction_kN']:>16.3f} {case['max_utilisation']:>9.3f} "
                   f"{'' if factor is None else f'{factor:.3f}':>9} {'yes' if case['converged'] else 'NO'}" if case else "")
        print(f"{step:<34} {seconds:>7.2f} {figures}")
    print(f"total {sum(record['seconds'].values()):.1f} s wall, {time.process_time():.1f} s CPU of this process "
          "(wall times on a shared machine count the other processes' share)")
    print(f"stations {args.stations}, pretension {args.pretension:g} mm/m; "
          + "; ".join(case_lines(record)[-2 if "buckling" in record else -1:]))
    print("residual check:", record["residual_check"])


if __name__ == "__main__":
    main()
