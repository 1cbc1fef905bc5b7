"""fabline analyse on the pavilion (the example job's design: Enneper, 9 x 12 m, k_max 1.05, 100 x 1.5 stainless,
pairs 25 mm apart): model size, seconds per step and load case, and each case's figures, as one table.

    python benchmarks/analyse_bench.py [--stations N] [--no-buckling]

Wall seconds per step, and the whole process's CPU seconds at the end.
"""

import argparse
import time

from fabline.analysis.loads import LoadSettings
from fabline.analysis.model import ModelOptions, bracing
from fabline.mechanics.hardware import load_catalogue
from fabline.analysis.run import analyse
from fabline.geometry.darboux import analyse as geometry_of
from fabline.mechanics.materials import Profile, get_material
from fabline.model.designs import enneper_network


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--stations", type=int, default=2)
    parser.add_argument("--no-buckling", action="store_true")
    args = parser.parse_args()
    start = time.perf_counter()
    network = enneper_network((9.0, 12.0), 0.35, 1.05).in_mm()
    geometry = geometry_of(network)
    options = ModelOptions(stations=args.stations, cables=bracing(network), cable=load_catalogue().cable,
                           cable_prestrain=0.001)
    prepared = time.perf_counter() - start
    record = analyse(geometry, get_material("stainless"), Profile(100.0, 1.5), options,
                     LoadSettings(), buckling=not args.no_buckling)
    model = record["model"]
    print(f"pavilion: {len(geometry.network.nodes)} network nodes -> {model['nodes']} frame nodes, {model['beams']} beams, "
          f"{model['links']} washer links, {model['hinges']} hinges, {model['cables']} cable members, {model['supports']} supports, {model['dofs']} DOFs; "
          f"geometry {prepared:.1f} s")
    print(f"{'step':<34} {'s':>7} {'max defl mm':>12} {'max reaction kN':>16} {'max util':>9}")
    for step, seconds in record["seconds"].items():
        case = record["cases"].get(step)
        figures = (f"{case['max_deflection_mm']:>12.2f} {case['max_reaction_kN']:>16.3f} {case['max_utilisation']:>9.3f}"
                   if case else "")
        print(f"{step:<34} {seconds:>7.2f} {figures}")
    print(f"total {sum(record['seconds'].values()):.1f} s wall, {time.process_time():.1f} s CPU of this process "
          "(wall times on a shared machine count the other processes' share)")
    if "buckling" in record:
        print(f"buckling factor {record['buckling']['factor']:.3f} ({record['buckling']['case']})")
    print("residual check:", record["residual_check"])


if __name__ == "__main__":
    main()
