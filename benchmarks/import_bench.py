"""Import speed: a ~20,000-node Enneper network as fabline JSON, OBJ and DXF (curves only, nodes recomputed).

Usage: python benchmarks/import_bench.py [--spacing 0.056] [--dir DIR]
Builds the network (built-in Enneper design, 9 x 12 m), writes it in each format plus a reference
surface mesh, then times `import_model` on each file and prints a table. Wall time depends on what
else runs on the machine, so CPU time of this process is printed too. Files are kept in --dir and
reused when present (building and writing the DXF takes a while).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fabline.model import save_network  # noqa: E402
from fabline.model.designs import enneper_mesh, enneper_network  # noqa: E402
from fabline.model.importers import import_model  # noqa: E402
from fabline.model.writers import write_dxf, write_obj  # noqa: E402

GOAL_SECONDS = 5.0


def surface_mesh(network, count: int = 121) -> trimesh.Trimesh:
    """The Enneper surface meshed on a parameter grid slightly larger than the design's domain."""
    return enneper_mesh(network, count, margin=1.02)


def prepare(folder: Path, spacing: float) -> None:
    """Write network.json, curves.obj, curves.dxf and surface.obj unless they are already there."""
    files = [folder / name for name in ("network.json", "curves.obj", "curves.dxf", "surface.obj")]
    if all(f.exists() for f in files):
        return
    print(f"building the Enneper network (spacing {spacing} m) and writing it to {folder} ...", file=sys.stderr)
    network = enneper_network(spacing=spacing)
    save_network(network, files[0])
    write_obj(network, files[1])
    write_dxf(network, files[2])
    surface_mesh(network).export(files[3])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spacing", type=float, default=0.056, help="node spacing in metres (0.056: ~20,000 nodes)")
    parser.add_argument("--dir", type=Path, help="where to keep the generated files (default: a temp folder)")
    args = parser.parse_args()
    folder = args.dir or Path(tempfile.mkdtemp(prefix="fabline-import-bench-"))
    folder.mkdir(parents=True, exist_ok=True)
    prepare(folder, args.spacing)
    rows = []
    for name, surface in (("network.json", None), ("curves.obj", "surface.obj"), ("curves.dxf", "surface.obj")):
        wall, cpu = time.perf_counter(), time.process_time()
        network, report = import_model(folder / name, surface=folder / surface if surface else None, units="m")
        wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
        points = sum(len(lam.curve) for lam in network.lamellas)
        rows.append((report.format, len(network.nodes), len(network.lamellas), points, wall, cpu))
    print(f"{'format':<8}{'nodes':>8}{'lamellas':>10}{'points':>9}{'wall s':>9}{'cpu s':>8}  goal < {GOAL_SECONDS:g} s")
    for fmt, nodes, lamellas, points, wall, cpu in rows:
        print(f"{fmt:<8}{nodes:>8}{lamellas:>10}{points:>9}{wall:>9.2f}{cpu:>8.2f}  {'ok' if wall < GOAL_SECONDS else 'SLOW'}")


if __name__ == "__main__":
    main()
