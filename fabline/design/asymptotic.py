"""`design asymptotic`: from a designer's surface file to a validated asymptotic network and its quality report."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from fabline.design.curves import declared_or_given
from fabline.design.field import Region, flat_curvature, special_regions
from fabline.errors import FablineError
from fabline.geometry.offsets import PAIR_SPACING_MM
from fabline.model.importers.surface import mesh_from_arrays, read_mesh_arrays
from fabline.model.network import UNIT_TO_MM, Network
from fabline.design.layout import (CROSSING_TOLERANCE_MM, Layout, SupportRule, build_network, check_on_surface,
                                   check_seed, default_seed, rail_layout)
from fabline.design.mesh import SmoothMesh, xyz_text
from fabline.design.nurbs import NurbsPatch, read_nurbs
from fabline.design.quality import quality_report
from fabline.design.trace import MIN_CROSSING_DEG, STOP_REASONS, StopRule
from fabline.mechanics.materials import get_material, parse_profile
from fabline.mechanics.structure import combined_radius_limit, combined_twist_limit
from fabline.model_units import Length, model_length

DEGENERATE_AREA = 1e-10  # a face smaller than this fraction of the mean edge length squared has no area
NODE_SPACING_MM = (10.0, 10_000.0)
"""Node spacings a gridshell (or its scale model) can have: outside, a number is taken for another unit."""
TRACING_STEP_MM = (0.1, 10_000.0)
SLOT_PAIR_THICKNESSES = 4.0  # a slot (unroll's default 2 t wide) and a web of as much between two nodes' slots
STRIP_STOP = 2.0
"""The tracer stops where a curve turns or twists this many times more than the strip's limit (the combined rule
with the other effect zero): no strip of the profile follows it there. Up to that, the curve goes on and the
structural check's combined verdict reports the overload with its remedies: the reference pavilion itself
twists 1.10 rad/m against 1.117 (its jets read a little more), and a designer's minimal surface often bends
under the default strip's 670 mm somewhere."""
SEED_ROOM = 0.5
"""A default seed moved out of where asymptotic lines end keeps this fraction of the largest clearance there is."""
MAX_LAMELLAS = 10_000
"""Lamellas a traced network may have at most (the reference pavilion, 9 x 12 m at 0.3 m, has about 70)."""
MAX_TRACED_POINTS = 1_000_000
"""Tracing points in all at most (lamellas times points per lamella; the reference pavilion takes about 20,000)."""


@dataclass
class AsymptoticDesign:
    """A traced network with what was found on the way: regions without asymptotic lines, early stops."""

    network: Network
    regions: list[Region]
    stops: list[str]
    surface: SmoothMesh | NurbsPatch
    notes: list[str] = field(default_factory=list)


def read_surface(path: str | Path, units: str | None = None) -> tuple[trimesh.Trimesh, str, list[str]]:
    """A surface file as one checked triangle mesh, its units, and notes (assumed units)."""
    path = str(path)
    notes = []
    if Path(path).suffix.lower() == ".3dm":
        from fabline.model.importers.rhino import read_3dm_surface
        mesh, declared = read_3dm_surface(path)
        vertices, faces = mesh.vertices, mesh.faces
    else:
        (vertices, faces), declared = read_mesh_arrays(path), None
    if units is None and declared is None:
        notes.append(f"{path}: the file declares no units; taken as m (give --units)")
    units = declared_or_given(path, declared, units)
    return check_mesh(np.asarray(vertices, dtype=float), np.asarray(faces, dtype=np.int64), path), units, notes


def load_surface(path: str | Path, units: str | None = None) -> tuple[SmoothMesh | NurbsPatch, str, list[str]]:
    """The surface to trace on: a .3dm file's one NURBS surface exactly, else any surface file as a smooth mesh."""
    if Path(path).suffix.lower() == ".3dm":
        patch, declared = read_nurbs(str(path))
        if patch is not None:
            return patch, declared_or_given(path, declared, units), []
    mesh, units, notes = read_surface(path, units)
    return SmoothMesh(mesh), units, notes


def check_mesh(vertices: np.ndarray, faces: np.ndarray, source: str) -> trimesh.Trimesh:
    """Refuse degenerate triangles, non-manifold edges and disconnected pieces, naming where; weld and orient."""
    raw = trimesh.Trimesh(vertices, faces, process=False)
    if not np.all(np.isfinite(vertices)):
        raise FablineError(f"{source}: the surface has NaN or infinite vertex coordinates")
    edge = float(np.mean(raw.edges_unique_length)) if len(raw.edges_unique) else 0.0
    tiny = np.flatnonzero(raw.area_faces <= DEGENERATE_AREA * edge * edge)
    if tiny.size:
        raise FablineError(f"{source}: face {tiny[0]} at ({xyz_text(raw.triangles_center[tiny[0]])}) is degenerate "
                           f"(area {raw.area_faces[tiny[0]]:.3g}); {tiny.size} such faces: remove or repair them")
    mesh = mesh_from_arrays(vertices, faces, source)
    edges = mesh.edges_sorted
    shared = trimesh.grouping.group_rows(edges, require_count=None)
    crowded = [group for group in shared if len(group) > 2]
    if crowded:
        a, b = mesh.vertices[edges[crowded[0][0]]]
        raise FablineError(f"{source}: non-manifold edge from ({xyz_text(a)}) to ({xyz_text(b)}) is shared by "
                           f"{len(crowded[0])} faces; {len(crowded)} such edges: the surface must be a manifold")
    labels = trimesh.graph.connected_component_labels(mesh.face_adjacency, node_count=len(mesh.faces))
    pieces = np.bincount(labels)
    if len(pieces) > 1:
        small = int(np.argsort(pieces)[0])
        where = mesh.triangles_center[labels == small].mean(axis=0)
        raise FablineError(f"{source}: the mesh has {len(pieces)} separate pieces (one of {pieces[small]} faces around "
                           f"({xyz_text(where)})): give one connected surface")
    return mesh


def design_asymptotic(path: str | Path, spacing: float | Length, seed: np.ndarray | None = None, supports: str | None = None,
                      units: str | None = None, step: float | Length | None = None, material: str = "steel-s235",
                      profile: str = "100x1.5", seed_curves: list[np.ndarray] | None = None,
                      pair_spacing: float = PAIR_SPACING_MM, slot_pair: float | None = None) -> AsymptoticDesign:
    """Trace an asymptotic network at `spacing` (model units, or a `Length` with a unit) on the surface in `path`;
    seed defaults to the centre. A spacing or step implausible in the surface's units is refused.

    `pair_spacing` and `slot_pair` (mm) are the unroll's: its pair's strip distance and a slot plus the web it leaves
    between two nodes' slots (default its own, 2 t and 2 t), so that every crossing handed over can be slotted.

    `seed_curves` (one or two polylines on the surface, model units) replace the rail and the middle curve;
    the seed then defaults to the middle of the first.
    The quality report (quality_report) and the regions without asymptotic lines go into the network's meta.
    """
    source = str(path)
    step_given = step is not None
    for name, length in (("--spacing", spacing), ("--step", step)):
        number = length.value if isinstance(length, Length) else length
        if length is not None and not (0 < number < np.inf):
            raise FablineError(f"{name} must be a positive number, got {number:g}")
    rule = SupportRule.parse(supports) if supports else None
    strip = (get_material(material), parse_profile(profile))  # a mistake there is refused before the work, not after
    surface, units, notes = load_surface(path, units)
    spacing = model_length(spacing, units, "--spacing", NODE_SPACING_MM, "a node spacing")
    step = None if step is None else model_length(step, units, "--step", TRACING_STEP_MM, "a tracing step")
    across = float(np.linalg.norm(np.ptp(surface.vertices, axis=0)))
    step = step or min(spacing / 4.0, 0.05 * across)
    check_tracing_size(across, spacing, step, units, step_given)
    slot_pair = SLOT_PAIR_THICKNESSES * strip[1].t if slot_pair is None else slot_pair
    check_pair_room(spacing, units, pair_spacing, slot_pair)
    k1, k2, _, _ = surface.vertex_curvatures()
    if not np.any((k1 > 0) & (k2 < 0)):
        worst = int(np.argmin(k1 * k2))
        raise FablineError(f"{source}: K >= 0 everywhere (synclastic or flat, no asymptotic directions; the most "
                           f"anticlastic point ({xyz_text(surface.vertices[worst])}) has K = {k1[worst] * k2[worst]:.3g})")
    regions = special_regions(surface.vertices, surface.faces, k1, k2)
    mm = UNIT_TO_MM[units]
    stop_rule = StopRule(flat_curvature(k1, k2), STRIP_STOP * mm / combined_radius_limit(*strip, 0.0),
                         STRIP_STOP * combined_twist_limit(*strip, 0.0) * mm)
    curves = tuple(np.asarray(c, dtype=float) for c in seed_curves or ())
    for k, curve in enumerate(curves):
        check_on_surface(surface, curve, f"{source}: seed curve {k + 1}")
    if seed is None:
        seed = _middle(curves[0]) if curves else traceable_seed(surface, default_seed(surface), k1, k2, stop_rule, spacing, units,
                                                                         notes)
    seed = check_seed(surface, np.asarray(seed, dtype=float), source)
    layout = rail_layout(surface, seed, spacing, step, CROSSING_TOLERANCE_MM / mm, source, curves, stop_rule, units)
    meta = {"design": "asymptotic", "surface": Path(source).name, "spacing": spacing, "seed": seed.round(9).tolist(),
            "seed_curves": len(curves),
            "step": step, "supports": str(rule) if rule else None}
    network = build_network(surface, layout, spacing, units, rule, Path(source).stem.split(".")[0], meta, source,
                            pair_spacing, slot_pair)
    network.meta["regions"] = [{"kind": r.kind, "centre": r.centre.round(6).tolist(), "vertices": r.vertices,
                                "extent": r.extent, "area": r.area} for r in regions]
    network.meta["stops"] = layout.stop_records
    network.meta["dropped"] = {"curves": layout.dropped, "refused": layout.rejected, "trimmed": layout.trimmed}
    network.meta["quality"] = quality_report(network, surface, spacing, material, profile)
    network.meta["quality"]["coverage"]["left_out"] = float(sum(r.area for r in regions))
    return AsymptoticDesign(network, regions, stop_lines(layout, units), surface, notes)


def stop_lines(layout: Layout, units: str) -> list[str]:
    """The early stops as a designer reads them: per reason, how many curve ends and one place (model units);
    then the curves dropped (too short to carry two crossings, or refused by the network check) and cut back."""
    lines = []
    reasons = [r["reason"] for r in layout.stop_records]
    for reason in dict.fromkeys(reasons):
        first = next(r for r in layout.stop_records if r["reason"] == reason)
        lines.append(f"{reasons.count(reason)} curve end(s) stop where the curve {STOP_REASONS[reason]}, e.g. "
                     f"{first['curve']} near ({xyz_text(np.array(first['xyz']))}) {units}")
    if layout.dropped:
        lines.append(f"{layout.dropped} traced curve(s) dropped: too short to carry two crossings"
                     + (f" or refused by the network check ({len(layout.rejected)}: {layout.rejected[0]})" if layout.rejected else ""))
    if layout.trimmed:
        lines.append(f"{layout.trimmed} curve end(s) cut back before a crossing the strips of a pair could not be "
                     "slotted at (a curve stopping there, or a neighbour's slots too close)")
    return lines


def traceable_seed(surface: SmoothMesh | NurbsPatch, seed: np.ndarray, k1: np.ndarray, k2: np.ndarray, rule: StopRule,
                   spacing: float, units: str, notes: list[str]) -> np.ndarray:
    """The default seed where the curves can start: `seed` (the centre) if every vertex within a spacing of it lets
    the tracer go on (anticlastic, not flat, the families crossing at MIN_CROSSING_DEG or more, a twist the strip
    takes), else the nearest such vertex with room around it (a note says so): a spacing, or SEED_ROOM of the
    largest room there is if more, so the seed lies well inside the largest anticlastic part, not in a pocket."""
    angle = 2.0 * np.degrees(np.arctan(np.sqrt(np.maximum(k1, 0) / np.maximum(-k2, 1e-300))))
    good = (k1 > 0) & (k2 < 0) & (np.maximum(np.abs(k1), np.abs(k2)) >= rule.flat) & \
        (np.minimum(angle, 180 - angle) >= MIN_CROSSING_DEG) & (np.sqrt(np.maximum(-k1 * k2, 0)) <= rule.max_twist)
    if good.all() or not good.any():
        return seed
    bad = cKDTree(surface.vertices[~good])
    clearance = np.where(good, bad.query(surface.vertices)[0], 0.0)
    if bad.query(seed)[0] >= spacing:
        return seed
    room = min(max(spacing, SEED_ROOM * clearance.max()), clearance.max())
    ok = np.flatnonzero(clearance >= room)
    nearest = ok[np.argmin(np.linalg.norm(surface.vertices[ok] - seed, axis=1))]
    notes.append(f"the surface's centre ({xyz_text(seed)}) {units} lies near where asymptotic lines end: "
                 f"seed moved to ({xyz_text(surface.vertices[nearest])}) {units} (give --seed to choose)")
    return surface.vertices[nearest]


def check_tracing_size(across: float, spacing: float, step: float, units: str, step_given: bool) -> None:
    """Refuse, before tracing, a network whose estimated size (two families of `across` / `spacing` lamellas, each
    `across` / `step` tracing points long, `across` the surface's bounding-box diagonal) is over the limits."""
    lamellas = 2.0 * across / spacing
    points = across / step
    size = f"--spacing {spacing:g} {units} on a surface {across:.4g} {units} across"
    if lamellas > MAX_LAMELLAS:
        raise FablineError(f"{size} would trace about {lamellas:.0f} lamellas; the limit is {MAX_LAMELLAS}: give a "
                           "larger --spacing")
    if lamellas * points > MAX_TRACED_POINTS:
        stepped = f"--step {step:g} {units}" if step_given else f"the step {step:g} {units} (spacing/4)"
        raise FablineError(f"{size} with {stepped} would trace about {lamellas:.0f} lamellas of {points:.0f} points, "
                           f"{lamellas * points:.2g} points in all; the limit is {MAX_TRACED_POINTS:.0e}: give a larger "
                           f"{'--step' if step_given else '--spacing'}")


def check_pair_room(spacing: float, units: str, pair_spacing: float, slot_pair: float) -> None:
    """Refuse a spacing under which two neighbouring lamella pairs' slots overlap even where they cross square."""
    least = pair_spacing + slot_pair
    if spacing * UNIT_TO_MM[units] < least:
        raise FablineError(f"--spacing {spacing:g} {units}: two neighbouring lamella pairs (strips {pair_spacing:g} mm "
                           f"apart, a slot and a web {slot_pair:g} mm) need nodes at least {least:g} mm apart; give a "
                           "larger spacing")


def _middle(curve: np.ndarray) -> np.ndarray:
    """The point halfway along a polyline."""
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(curve, axis=0), axis=1))])
    return np.array([np.interp(s[-1] / 2, s, curve[:, i]) for i in range(3)])

