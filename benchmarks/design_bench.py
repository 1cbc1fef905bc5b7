"""Design from surfaces: traced asymptotic networks against the closed forms, tracing speed, minimal-surface speed.

Usage: python benchmarks/design_bench.py [--sizes 5000,20000,80000] [--noisy 20000] [--noise 0.5] [--big 100000]
       [--minimal 20000] [--hard 0.07,0.035] [--dir DIR]
Table 1: for the pavilion's Enneper patch (9 x 12 m, k_max 1.1 1/m), a catenoid patch (waist 1 m) and a
helicoid (pitch 6 m), each meshed irregularly at every size, the traced network (spacing 0.35 m, seed
as the closed form's) against the closed-form rail grid: node count, mean and max node distance, max
k_n along the curves, smallest crossing angle; then the same at the `--noisy` sizes with `--noise` mm of
normal noise on the vertices (goal: 2 mm mean, 10 mm max). Table 2: the whole `design_asymptotic` on a
`--big`-triangle Enneper mesh (goal < 10 s). Table 3: `minimal_surface` from two coaxial circles
(radius 1 m, 1 m apart) at about `--minimal` triangles (goal < 30 s) and its distance to the catenoid, then
three circles (an outer one with two openings) at the same count. Table 4 (`--hard` spacings, m): the hard
family of tests/meshes.py (flat folded centre, dome in a saddle, saddle next to a dome, a hole, a thin neck,
noisy, coarse, in mm), default seed: valid or refused, lamellas, nodes, covered fraction of the area, the
area left out (K >= 0 or flat), early stops by reason, curves dropped, node error against the closed form
where there is one (the hypar's asymptotic lines are its straight rulings: the largest distance of a
lamella from the line through its ends, mm), time.
Wall time depends on what else runs on the machine, so this process's CPU time is printed too.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # the hard mesh family

from fabline.design import design_asymptotic  # noqa: E402
from fabline.design.samples import closed_form_cases, rail_grid  # noqa: E402

SPACING = 0.35
TRACE_GOAL_SECONDS = 10.0
MINIMAL_GOAL_SECONDS = 30.0


def timed(function, *args, **kwargs):
    wall, cpu = time.perf_counter(), time.process_time()
    result = function(*args, **kwargs)
    return result, time.perf_counter() - wall, time.process_time() - cpu


def accuracy_table(sizes: list[int], folder: Path, noise_mm: float = 0.0) -> None:
    if noise_mm:
        print(f"\nthe same with {noise_mm:g} mm of normal noise on the vertices (the mesh is denoised before its jets are fitted)")
    print(f"{'surface':<10}{'triangles':>10}{'nodes':>7}{'ref':>6}{'mean mm':>9}{'max mm':>8}{'max k_n':>9}{'min angle':>10}{'wall s':>8}{'cpu s':>7}")
    for name, case in closed_form_cases().items():
        truth = rail_grid(case.surface, case.seed, SPACING, case.inside)
        for size in sizes:
            path = folder / f"{name}-{size}.ply"
            mesh = case.mesh(size, seed=1, noise=noise_mm / 1000)
            mesh.export(path)
            design, wall, cpu = timed(design_asymptotic, path, SPACING, seed=case.seed_point())
            network = design.network
            at = network.lamellas_at()
            crossings = np.array([n.xyz for nid, n in network.nodes.items() if len(at[nid]) >= 2])
            distance = cKDTree(crossings).query(truth)[0] * 1000
            quality = network.meta["quality"]
            print(f"{name:<10}{len(mesh.faces):>10}{len(crossings):>7}{len(truth):>6}{distance.mean():>9.2f}{distance.max():>8.2f}"
                  f"{quality['k_n']['max']:>9.4f}{quality['crossing_angles']['min']:>10.2f}{wall:>8.2f}{cpu:>7.2f}")


def speed_table(triangles: int, folder: Path) -> None:
    case = closed_form_cases()["enneper"]
    path = folder / f"enneper-{triangles}.ply"
    mesh = case.mesh(triangles, seed=3)
    mesh.export(path)
    design, wall, cpu = timed(design_asymptotic, path, SPACING, seed=case.seed_point())
    print(f"\ntrace a full network on a {len(mesh.faces):,}-triangle mesh: {len(design.network.lamellas)} lamellas, "
          f"{len(design.network.nodes)} nodes in {wall:.2f} s wall, {cpu:.2f} s cpu (goal < {TRACE_GOAL_SECONDS:g} s, "
          "read, fit, trace, validate and quality report)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="5000,20000,80000", help="triangle counts for the accuracy table")
    parser.add_argument("--big", type=int, default=100_000, help="triangles of the speed run")
    parser.add_argument("--noisy", default="20000", help="triangle counts for the noisy accuracy table (empty: skip)")
    parser.add_argument("--noise", type=float, default=0.5, help="standard deviation of the noisy table's normal noise, mm")
    parser.add_argument("--minimal", type=int, default=20_000, help="triangles of the minimal surface run (0: skip)")
    parser.add_argument("--hard", default="0.07,0.035", help="spacings (m) for the hard mesh table (empty: skip)")
    parser.add_argument("--pipeline", action="store_true",
                        help="the hard table also runs unroll (strips alone) -> nest -> export DXF on every valid design")
    parser.add_argument("--hard-only", action="store_true", help="only the hard mesh table")
    parser.add_argument("--dir", help="folder for the meshes (default: a temporary one)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as scratch:
        folder = Path(args.dir or scratch)
        folder.mkdir(parents=True, exist_ok=True)
        if args.hard:
            hard_table([float(s) for s in args.hard.split(",")], folder, args.pipeline)
        if args.hard_only:
            return
        accuracy_table([int(s) for s in args.sizes.split(",")], folder)
        if args.noisy:
            accuracy_table([int(s) for s in args.noisy.split(",")], folder, args.noise)
        speed_table(args.big, folder)
        if args.minimal:
            minimal_table(args.minimal, folder)


def hard_table(spacings: list[float], folder: Path, pipeline: bool = False) -> None:
    from collections import Counter

    from meshes import HARD_MESHES, hard_mesh, hypar, write_mesh

    from fabline.errors import FablineError

    print(f"{'hard mesh':<20}{'vertices':>9}{'spacing':>8}{'result':>8}{'lams':>6}{'nodes':>6}{'covered':>8}{'left out':>9}"
          f"{'dropped':>8}{'ruling mm':>10}{'wall s':>7}  stops")
    for name in HARD_MESHES:
        vertices, faces, units = hard_mesh(name)
        path = write_mesh(folder / f"{name}.obj", vertices, faces)
        scale = 1000.0 if units == "mm" else 1.0
        for spacing in spacings:
            try:
                design, wall, _ = timed(design_asymptotic, path, spacing * scale, units=units)
            except FablineError as exc:
                print(f"{name:<20}{len(vertices):>9}{spacing:>8g}{'refused':>8}  {exc}")
                continue
            network = design.network
            coverage = network.meta["quality"]["coverage"]
            error = "-"
            if HARD_MESHES[name][0] is hypar:  # z = 0.3 (x^2 - y^2) is doubly ruled: its asymptotic lines are straight
                error = f"{max(_off_straight(lam.curve) for lam in network.lamellas) / scale * 1000:.3f}"
            stops = Counter(stop["reason"] for stop in network.meta["stops"])
            print(f"{name:<20}{len(vertices):>9}{spacing:>8g}{'valid':>8}{len(network.lamellas):>6}{len(network.nodes):>6}"
                  f"{coverage['fraction'] * 100:>7.1f}%{coverage['left_out'] / coverage['surface_area'] * 100:>8.1f}%"
                  f"{network.meta['dropped']['curves']:>8}{error:>10}{wall:>7.2f}  "
                  + ", ".join(f"{k} {v}" for k, v in sorted(stops.items()))
                  + (f"; to parts: {_to_parts(network, folder / name)}" if pipeline else ""))


def _to_parts(network, folder: Path) -> str:
    """unroll (strips alone) -> nest -> export DXF on a traced network, as `fabline` runs them: the parts, sheets,
    whether ezdxf's audit of every sheet is clean and every part is on one, and the wall time; or the refusal."""
    import contextlib
    import io
    import json

    import ezdxf

    from fabline.cli import main as fabline
    from fabline.model import save_network

    folder.mkdir(parents=True, exist_ok=True)
    save_network(network, folder / "net.json")
    started = time.perf_counter()
    for command in (("unroll", folder / "net.json", "--no-hardware", "-o", folder / "parts.json"),
                    ("nest", folder / "parts.json", "--time-limit", "2", "-o", folder / "nesting.json"),
                    ("export", folder / "nesting.json", "--dxf", folder / "dxf", "--no-preview")):
        errors = io.StringIO()
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(errors):
            code = fabline([str(a) for a in command])
        if code:
            return f"{command[0]} refused: {errors.getvalue().strip().splitlines()[-1].split(': ', 3)[-1]}"
    parts = {p["id"] for p in json.loads((folder / "parts.json").read_text())["parts"]}
    sheets = sorted((folder / "dxf").glob("*_S*.dxf"))
    docs = [ezdxf.readfile(sheet) for sheet in sheets]
    inserted = {i.dxf.name for doc in docs for i in doc.modelspace().query("INSERT")}
    clean = not any(doc.audit().has_errors for doc in docs)
    return (f"{len(parts)} parts on {len(sheets)} sheet(s), DXF audit {'clean' if clean else 'ERRORS'}, "
            f"{'every part placed' if parts <= inserted else f'{len(parts - inserted)} parts missing'}, "
            f"{time.perf_counter() - started:.1f} s")


def _off_straight(curve: np.ndarray) -> float:
    """The largest distance of a curve's points from the straight line through its ends."""
    axis = (curve[-1] - curve[0]) / np.linalg.norm(curve[-1] - curve[0])
    offset = curve - curve[0]
    return float(np.linalg.norm(offset - np.outer(offset @ axis, axis), axis=1).max())


def minimal_table(triangles: int, folder: Path) -> None:
    import trimesh

    from fabline.design.minimal import catenoid_waist, coaxial_circles, minimal_surface

    circles = coaxial_circles(1.0, 1.0)
    area = 2 * np.pi * 1.0 * 1.0
    size = float(np.sqrt(4 * area / (np.sqrt(3) * triangles)))
    mesh, wall, cpu = timed(minimal_surface, circles, size)
    waist = catenoid_waist(1.0, 1.0)
    radius = np.hypot(mesh.vertices[:, 0], mesh.vertices[:, 1])
    error = np.abs(radius - waist * np.cosh(mesh.vertices[:, 2] / waist)) / np.sqrt(1 + np.sinh(mesh.vertices[:, 2] / waist) ** 2)
    print(f"\nminimal surface between two circles (r 1 m, 1 m apart), mesh size {size * 1000:.1f} mm: {len(mesh.faces):,} triangles "
          f"in {wall:.2f} s wall, {cpu:.2f} s cpu (goal < {MINIMAL_GOAL_SECONDS:g} s); distance to the catenoid "
          f"(waist {waist:.6f} m): {error.mean() * 1000:.3f} mm mean, {error.max() * 1000:.3f} mm max")
    angle = np.linspace(0.0, 2 * np.pi, 720, endpoint=False)
    ring = np.stack([np.cos(angle), np.sin(angle), np.zeros_like(angle)], axis=1)
    loops = [1.5 * ring, 0.3 * ring + [-0.6, 0, 0.4], 0.3 * ring + [0.6, 0, 0.4]]
    size = float(np.sqrt(4 * np.pi * (1.5 ** 2 - 2 * 0.3 ** 2) / (np.sqrt(3) * triangles)))
    mesh, wall, cpu = timed(minimal_surface, loops, size)
    smallest = np.degrees(trimesh.triangles.angles(mesh.triangles)).min(axis=1)
    print(f"minimal surface spanning three circles (r 1.5 m, two 0.3 m openings 0.4 m up), mesh size {size * 1000:.1f} mm: "
          f"{len(mesh.faces):,} triangles in {wall:.2f} s wall, {cpu:.2f} s cpu; smallest angle {smallest.min():.1f} deg, "
          f"{(smallest < 30).mean() * 100:.2f} % of the triangles under 30 deg")


if __name__ == "__main__":
    main()
