"""Unroll a whole network: every lamella to flat strip parts, the joint hardware, and the structural report.

`unroll_network(network, options)` is the stage's entry point: geometry (fabline.geometry), strip stations
(offset-curve crossings), seams, one part per segment, washers/clamps/joints, and per lamella the check
of domain.md section 6. Mistakes that make parts impossible raise a FablineError naming lamella and node;
over-stress is a warning in the report (an error with `strict`), since cutting can still go on.
"""

from __future__ import annotations

import numpy as np

from fabline.errors import FablineError
from fabline.geometry.darboux import NetworkGeometry, analyse
from fabline.geometry.offsets import OffsetCurve
from fabline.model.network import Network
from fabline.progress import progress
from fabline.unroll.batch import straight_flags, straight_parts
from fabline.unroll.cables import CableSettings, cable_runs, cable_summary, clamp_lift
from fabline.unroll.collector import collector_paused
from fabline.unroll.couplers import add_couplers
from fabline.unroll.hardware import (HardwareSizes, checkerboard, clamp, clamp_ids, singularity_joints, washer_ids,
                                     washer_keys, washers)
from fabline.mechanics.slots import SlotCheck, check_slots, slot_verdict, slot_warning
from fabline.mechanics.structure import check_lamellas, limits, structural_verdict
from fabline.unroll.options import UnrollOptions
from fabline.unroll.parts import Part, PartSet
from fabline.unroll.pieces import is_seam, segment_part
from fabline.unroll.seams import Segment, split_strip
from fabline.unroll.stations import Strip, singular_nodes, strip_stations
from fabline.unroll.supports import support_parts


def unroll_network(network: Network, options: UnrollOptions | None = None,
                   geometry: NetworkGeometry | None = None) -> PartSet:
    """All flat parts of a network (mm) and the report; pass `geometry` to reuse an `analyse` result."""
    with collector_paused():
        return _unroll(network, (options or UnrollOptions()).check(), geometry)


def _unroll(network: Network, options: UnrollOptions, geometry: NetworkGeometry | None) -> PartSet:
    """`unroll_network` with checked options."""
    edges_module = None
    if options.edge_members:
        from fabline.unroll import edges as edges_module

        if geometry is None:  # a built-in design's lamellas run on to the edge of its domain
            network = edges_module.extend_to_edge(network, options)
    geometry = geometry if geometry is not None else analyse(network)
    strips = strip_stations(geometry, options)
    curves, unclamped = [], set()
    if edges_module is not None:
        curves = edges_module.boundary_curves(geometry.network, options)
        edges_module.end_fixes(strips, options, edges_module.domain_edge(geometry.network, options) is not None)
        unclamped = edges_module.nodes_near(curves, geometry.network, edges_module.edge_options(options).profile.h / 2.0
                                            + HardwareSizes.of(options.profile, options.pair_spacing,
                                                               options.bolt_square).clamp_reach)
    sizes = HardwareSizes.of(options.profile, options.pair_spacing, options.bolt_square)
    segments: list[Segment] = []
    strip_rows = []
    partner_seams: dict[str, set[tuple[str, str]]] = {}
    for strip in progress(strips, "seams", total=len(strips)):
        avoid = partner_seams.setdefault(strip.lamella, set())
        pieces = split_strip(strip, options, sizes.joint_setback, avoid)
        seams = [s.end_join.interval for s in pieces if is_seam(s.end_join)]
        avoid.update(seams)
        segments.extend(pieces)
        strip_rows.append(_strip_row(strip, pieces, seams, options))
    parts = _segment_parts(segments, options)
    couplers, uncoupled = add_couplers(parts, geometry.network, options.couplers, sizes.bolt_hole, options.profile.h,
                            options.pair_spacing, options.profile.t)
    checks = check_lamellas(list(geometry.lamellas.values()), options.material, options.profile)
    slot_checks = _slot_checks(geometry, strips, options)
    warnings = [line for check in checks for line in check.warnings]
    warnings += [line for lamella, slot in slot_checks.items()
                 if (line := slot_warning(lamella, slot, options.profile)) is not None]
    if options.strict and warnings:
        more = f" (and {len(warnings) - 1} more warnings)" if len(warnings) > 1 else ""
        raise FablineError(warnings[0] + more)
    cables = None
    if options.hardware:
        hardware = hardware_parts(geometry, options, sizes, unclamped)
        parts.extend(hardware)
        cables = cable_runs(geometry.network, {p.meta["node"] for p in hardware if p.kind == "clamp"},
                            clamp_lift(options.profile.h, options.profile.t, sizes),
                            CableSettings(options.cable_pretension, options.cable_end_allowance))
    edges = None
    if edges_module is not None:
        edge_list, edges = edges_module.curve_parts(curves, options, sizes.bolt_hole)
        parts.extend(edge_list)
        warnings = warnings + edges["warnings"]
    plates = None
    if options.supports:
        plates = PartSet(support_parts(geometry.network, sizes.bolt_hole, options.profile.h, options.profile.t,
                                       options.support_plate, options.support_height, options.text_height),
                         {"t": options.support_plate, "name": f"{options.support_plate:g} mm plate"},
                         options.support_material, network.name)
        if not plates.parts:
            raise FablineError("supports: the model marks no node as a support (node kind 'support': import with "
                               "--supports, or leave supports off)")
    lamella_rows = [{**check.summary(options.material, options.profile), **slot_checks[check.lamella].summary()}
                    for check in checks]
    report = {
        "summary": _summary(parts, lamella_rows, strip_rows, warnings),
        "limits": limits(options.material, options.profile),
        "verdict": (structural_verdict(checks, options.material, options.profile, _design_k_max(network))
                    if checks else None),
        "options": _options_row(options),
        "lamellas": lamella_rows,
        "strips": strip_rows,
        "warnings": warnings,
    }
    if report["verdict"] is not None:
        report["verdict"]["slots"] = slot_verdict(slot_checks)
    if edges is not None:
        report["edges"] = edges
    if options.couplers:
        report["couplers"] = {"intervals_from_support": options.couplers, "placed": len(couplers),
                              "skipped": uncoupled}
    if cables is not None:
        report["cables"] = cable_summary(cables, options, clamp_lift(options.profile.h, options.profile.t, sizes))
    profile = {"h": options.profile.h, "t": options.profile.t, "name": str(options.profile)}
    return PartSet(parts, profile, options.material.name, network.name, report, cables or [], plates, couplers)


def _slot_checks(geometry: NetworkGeometry, strips: list[Strip], options: UnrollOptions) -> dict[str, SlotCheck]:
    """The net section at every node where a lamella's strips have slots (`fabline.mechanics.slots`)."""
    slotted: dict[str, set[str]] = {}
    for strip in strips:
        slotted.setdefault(strip.lamella, set()).update(strip.slot_nodes)
    return {lam_id: check_slots(geo, sorted(slotted.get(lam_id, ())), options.material, options.profile,
                                options.slot_depth) for lam_id, geo in geometry.lamellas.items()}


def _segment_parts(segments: list[Segment], options: UnrollOptions) -> list[Part]:
    """One part per segment, in order: straight ones built together (batch), curved ones one by one."""
    straight = straight_flags(segments, options).tolist()
    batched = iter(straight_parts([s for s, flag in zip(segments, straight) if flag], options))
    return [next(batched) if flag else segment_part(segment, options)
            for segment, flag in zip(progress(segments, "parts", total=len(segments)), straight)]


def hardware_parts(geometry: NetworkGeometry, options: UnrollOptions, sizes: HardwareSizes,
                   unclamped: set[str] = frozenset()) -> list[Part]:
    """Washers (two per crossing node), clamps (checkerboard nodes but `unclamped`, where the edge bars would lie on
    them: the cables end at the bars) and hexagonal joints (singularities, joint mode).

    The arm angles of all nodes and their washer keys come from whole-array operations; per node only the
    Part objects are made, from shapes shared by every node of the same (rounded) angles.
    """
    geos = list(geometry.lamellas.values())
    index: dict[str, int] = {}
    node_of = np.array([index.setdefault(nid, len(index)) for geo in geos for nid in geo.node_ids], dtype=int)
    neighbours: dict[str, list[str]] = {}
    for geo in geos:
        for a, b in zip(geo.node_ids[:-1], geo.node_ids[1:]):
            neighbours.setdefault(a, []).append(b)
            neighbours.setdefault(b, []).append(a)
    clamped = checkerboard(sorted(neighbours), neighbours) - set(unclamped)
    singular = singular_nodes(geometry)
    arms = np.bincount(node_of, minlength=len(index))
    crossing = sorted(nid for nid, count in zip(index, arms.tolist()) if count >= 2)
    angles, bounds = arm_angles(crossing, [index[nid] for nid in crossing], node_of,
                                np.concatenate([geo.node_tangents for geo in geos]), geometry.network)
    keys = washer_keys(angles, bounds)
    raw = angles.tolist()
    joint_mode = options.singularity == "joint"
    washer_text = iter(washer_ids([nid for nid in crossing if nid not in singular or not joint_mode], sizes,
                                  options.text_height))
    clamp_nodes = [(nid, key[1]) for nid, key in zip(crossing, keys) if nid in clamped and nid not in singular]
    clamp_text = iter(clamp_ids([nid for nid, _ in clamp_nodes], [angle for _, angle in clamp_nodes], sizes,
                                options.text_height))
    parts: list[Part] = []
    for k, (nid, key) in enumerate(zip(crossing, keys)):
        if nid in singular and joint_mode:
            parts.extend(singularity_joints(nid, raw[bounds[k]:bounds[k + 1]], sizes))
            continue
        parts.extend(washers(nid, key, sizes, next(washer_text)))
        if nid in clamped and nid not in singular:
            parts.append(clamp(nid, key[1], sizes, next(clamp_text)))
    return parts


def arm_angles(nodes: list[str], rows: list[int], node_of: np.ndarray, tangents: np.ndarray,
               network: Network) -> tuple[np.ndarray, list[int]]:
    """The directions (degrees) of the lamellas at each node in its tangent plane, the first lamella at 0: one flat
    array, node k's from bounds[k] to bounds[k + 1]. `node_of` and `tangents` hold every lamella's nodes in order
    (node row and tangent), `rows` the nodes' rows; a node's lamellas keep that order."""
    if not nodes:
        return np.zeros(0), [0]
    arms = np.bincount(node_of)
    by_node = np.argsort(node_of, kind="stable")
    counts = arms[rows]
    before = np.cumsum(counts) - counts
    all_t = tangents[by_node[np.repeat((np.cumsum(arms) - arms)[rows] - before, counts) + np.arange(counts.sum())]]
    normals = np.array([network.nodes[nid].normal for nid in nodes], dtype=float)
    first = all_t[before]
    first -= np.einsum("ij,ij->i", first, normals)[:, None] * normals
    first /= np.linalg.norm(first, axis=1)[:, None]
    second = np.cross(normals, first)
    owner = np.repeat(np.arange(len(nodes)), counts)
    angles = np.degrees(np.arctan2(np.einsum("ij,ij->i", all_t, second[owner]), np.einsum("ij,ij->i", all_t, first[owner])))
    return angles, np.append(before, len(angles)).tolist()


def _strip_row(strip: Strip, segments: list[Segment], seams: list[tuple[str, str]], options: UnrollOptions) -> dict:
    """A strip's report row: length, segments, seams (their node intervals), how its node distances differ from
    the centreline's."""
    start, end = segments[0].start, segments[-1].end
    change = np.diff(strip.node_x) - np.diff(strip.geometry.node_s)
    row = {
        "strip": strip.id, "lamella": strip.lamella, "side": strip.side, "offset_mm": strip.offset,
        "length_mm": round(end - start, 3), "segments": [s.id for s in segments],
        "seams": [list(interval) for interval in seams],
        "slots": len(strip.slot_x),
        "node_distance_change_max_mm": round(float(np.abs(change).max()), 4) if change.size else 0.0,
        "node_distance_change_total_mm": round(float(change.sum()), 4) if change.size else 0.0,
    }
    if options.compensate_twist:
        plain = OffsetCurve.of(strip.geometry, strip.offset)
        row["twist_compensation_mm"] = round(strip.curve.length - plain.length, 4)
    return row


def _summary(parts: list[Part], lamellas: list[dict], strips: list[dict], warnings: list[str]) -> dict:
    """Counts, total strip length and the governing utilisation of the run."""
    kinds: dict[str, int] = {}
    for part in parts:
        kinds[part.kind] = kinds.get(part.kind, 0) + 1
    worst = max(lamellas, key=lambda row: row["utilisation"]) if lamellas else None
    return {
        "lamellas": len(lamellas), "strips": len(strips), "parts": len(parts), "parts_by_kind": kinds,
        "strip_length_m": round(sum(s["length_mm"] for s in strips) / 1000.0, 3),
        "max_utilisation": worst["utilisation"] if worst else 0.0,
        "governing_lamella": worst["lamella"] if worst else None,
        "governing_check": worst["governing"] if worst else None,
        "warnings": len(warnings),
    }


def _design_k_max(network) -> float | None:
    """The design's largest principal curvature (1/m) when its generator recorded one (`fabline design enneper`)."""
    k_max = network.meta.get("k_max")
    return float(k_max) if isinstance(k_max, (int, float)) and not isinstance(k_max, bool) and k_max > 0 else None


def _options_row(options: UnrollOptions) -> dict:
    """The settings that shaped the parts, for the record in parts.json."""
    return {
        "pair_spacing_mm": options.pair_spacing, "slot_width_mm": options.slot, "slot_depth_mm": options.slot_depth,
        "overlap_mm": options.overlap, "min_overlap_mm": options.shortest_overlap, "screw_hole_mm": options.screw_hole, "usable_length_mm": options.usable_length,
        "end_length_mm": options.end, "compensate_twist": options.compensate_twist,
        "singularity": options.singularity, "hardware": options.hardware, "text_height_mm": options.engrave_height,
        "min_crossing_angle_deg": options.min_crossing_angle, "edge_members": options.edge_members,
        "edge_width_mm": (options.profile.h if options.edge_width is None else options.edge_width) if options.edge_members else None,
        "cable_pretension_mm_per_m": options.cable_pretension, "cable_end_allowance_mm": options.cable_end_allowance,
        "supports": options.supports, "support_plate_mm": options.support_plate if options.supports else None,
        "support_height_mm": options.support_height if options.supports else None, "couplers": options.couplers,
    }
