"""Parts of a pavilion-sized unroll checked with shapely: features inside their parts, slots apart, every node on
its strips, seams, hardware, singularities, and the parts.json round trip."""

from __future__ import annotations

import json
from collections import defaultdict

import numpy as np
import pytest
from shapely import union_all
from shapely.geometry import MultiLineString, Polygon

from fabline.unroll import UnrollOptions, flatten_contour, load_parts, save_parts, unroll_network
from networks import network_of, polar_grid
from .test_unroll_geometry import options

STRIP_KINDS = ("strip", "curved-strip")


@pytest.fixture(scope="module")
def pavilion(enneper):
    return unroll_network(enneper, UnrollOptions())


def polygon(contour) -> Polygon:
    return Polygon(flatten_contour(contour, 0.01))


def test_every_slot_mark_and_text_lies_inside_its_part(pavilion):
    h = 100.0
    for part in (p for p in pavilion.parts if p.kind in STRIP_KINDS):
        outline = Polygon(flatten_contour(part.outline, 0.01), [flatten_contour(c, 0.01) for c in part.holes])
        assert outline.is_valid, part.id
        slots = [polygon(s.outline) for s in part.slots]
        cut = union_all(slots)
        # no two slots overlap: their union has the area of them all
        assert cut.area == pytest.approx(sum(slot.area for slot in slots), rel=1e-9), part.id
        # slots are cut out of the strip: none of their area is left in the outline, and outline and slots
        # together fill exactly the strip's length x height (so no slot reaches outside the strip)
        assert cut.intersection(outline).area < 1e-6 * max(cut.area, 1.0), part.id
        length = float(np.ptp(flatten_contour(part.outline)[:, 0]))
        full = outline.union(cut)
        assert full.area == pytest.approx(length * h - sum(polygon(c).area for c in part.holes), rel=1e-3), part.id
        engraved = MultiLineString([line[:, :2] for line in part.marks + part.text])
        assert outline.buffer(1e-6).contains(engraved), part.id


def test_every_node_on_two_lamellas_and_four_strips(enneper, pavilion):
    lamellas, strips = defaultdict(set), defaultdict(set)
    slots = defaultdict(int)
    for part in (p for p in pavilion.parts if p.kind in STRIP_KINDS):
        for node in part.nodes:
            assert 0.0 < node["s"] < float(np.ptp(flatten_contour(part.outline)[:, 0]))
            lamellas[node["id"]].add(part.lamella)
            strips[node["id"]].add(part.meta["strip"])
        for slot in part.slots:
            slots[slot.node] += 1
    at = enneper.lamellas_at()
    assert set(lamellas) == set(enneper.nodes)
    for nid, lams in at.items():
        assert lamellas[nid] == set(lams)
        assert len(strips[nid]) == 2 * len(lams)
        if len(lams) == 2:
            assert slots[nid] == 8  # each of four strips: a double slot, one per strip of the crossing pair


def test_full_overlap_seams_keep_clear_of_slots_and_segments_run_nearly_a_sheet_length(pavilion):
    """A seam may go anywhere in its interval, so a segment ending in one runs nearly a sheet length (with every seam
    in the middle of its interval they averaged 88 % of it); a full overlap holds no slot (a joint's layers stay
    whole): read off the parts' own slot outlines and seam records."""
    opts = UnrollOptions()
    clear = opts.web  # from the slot's own outline
    seam_ended = []
    for part in (p for p in pavilion.parts if p.kind in STRIP_KINDS):
        slot_x = np.array([x for slot in part.slots for x in flatten_contour(slot.outline)[:, 0]])
        for side in ("start", "end"):
            join = part.meta["joins"][side]
            if not join or join["kind"] != "seam" or join["overlap_mm"] < opts.overlap:
                continue
            lo, hi = join["seam_mm"] - opts.overlap / 2.0 - clear, join["seam_mm"] + opts.overlap / 2.0 + clear
            assert not np.any((slot_x > lo) & (slot_x < hi)), (part.id, side)
        if part.meta["joins"]["end"] and part.meta["joins"]["end"]["kind"] == "seam":
            seam_ended.append(part.meta["length_mm"])
    assert len(seam_ended) > 100
    assert max(seam_ended) <= opts.usable_length
    assert np.mean(seam_ended) > 0.93 * opts.usable_length


def test_seams_overlap_staggered_and_screwed(pavilion):
    opts = UnrollOptions()
    by_strip = defaultdict(list)
    for part in (p for p in pavilion.parts if p.kind in STRIP_KINDS):
        assert float(np.ptp(flatten_contour(part.outline)[:, 0])) <= opts.usable_length
        by_strip[part.meta["strip"]].append(part)
    seamed = 0
    for strip, parts in by_strip.items():
        parts.sort(key=lambda p: p.meta["segment"])
        for first, second in zip(parts, parts[1:]):
            end, start = first.meta["strip_range_mm"][1], second.meta["strip_range_mm"][0]
            assert end - start == pytest.approx(opts.overlap)
            holes_first = [[first.meta["strip_range_mm"][0], 0.0] + np.mean(h[:4, :2], axis=0) for h in first.holes]
            holes_second = [[start, 0.0] + np.mean(h[:4, :2], axis=0) for h in second.holes]
            shared = [p for p in holes_first if any(np.allclose(p, q, atol=1e-6) for q in holes_second)]
            assert len(shared) == 6
            assert first.meta["joins"]["end"]["part"] == second.id and f"{second.id}>" in first.label
            seamed += 1
    assert seamed > 50
    rows = {row["strip"]: row for row in pavilion.report["strips"]}
    for strip, row in rows.items():
        if strip.endswith("-L"):
            partner = rows[strip[:-1] + "R"]
            assert not ({tuple(s) for s in row["seams"]} & {tuple(s) for s in partner["seams"]}), strip


def test_hardware_washers_clamps(enneper, pavilion):
    crossings = [nid for nid, lams in enneper.lamellas_at().items() if len(lams) == 2]
    washers = [p for p in pavilion.parts if p.kind == "washer"]
    clamps = [p for p in pavilion.parts if p.kind == "clamp"]
    assert len(washers) == 2 * len(crossings)
    clamped = {p.meta["node"] for p in clamps}
    assert 0.4 * len(crossings) < len(clamped) < 0.6 * len(crossings)
    for lam in enneper.lamellas:  # every second node along a lamella: no two neighbours both clamped
        flags = [n in clamped for n in lam.nodes]
        assert not any(a and b for a, b in zip(flags, flags[1:])), lam.id
    for part in washers[:50] + clamps[:50]:
        shape = Polygon(part.outline, [flatten_contour(h) for h in part.holes])
        assert shape.is_valid and shape.area > 0
    assert all(90.0 == pytest.approx(p.meta["arm_angles_deg"][1], abs=0.5) for p in washers)


def test_parts_json_round_trip(tmp_path):
    partset = unroll_network(polar_grid(3000.0 + 350.0 * np.arange(3), 0.1 * np.arange(5)), UnrollOptions())
    path = tmp_path / "parts.json"
    save_parts(partset, path)
    data = json.loads(path.read_text())
    assert data["schema"] == "fabline.parts/1" and data["units"] == "mm"
    strip = next(p for p in data["parts"] if p["kind"] == "strip")
    for key in ("id", "kind", "lamella", "outline", "holes", "slots", "marks", "text", "nodes"):
        assert key in strip
    assert strip["outline"][0][:2] == strip["outline"][-1][:2]
    assert {"id", "s"} <= set(strip["nodes"][0])
    again = load_parts(path)
    assert [p.id for p in again.parts] == [p.id for p in partset.parts]
    assert again.report["summary"] == partset.report["summary"]
    for before, after in zip(partset.parts, again.parts):
        assert np.allclose(before.outline, after.outline, atol=1e-4)
        assert len(before.text) == len(after.text) and before.nodes == after.nodes


def star_network(mode_arms: int = 3, length: float = 700.0):
    """Three straight lamellas through one centre node at 60 degrees: a valence-6 singularity in a plane."""
    curves = []
    for k in range(mode_arms):
        angle = np.pi * k / mode_arms
        s = np.linspace(-length, length, 141)
        points = np.column_stack([s * np.cos(angle), s * np.sin(angle), np.zeros_like(s)])
        normals = np.tile([0.0, 0.0, 1.0], (len(s), 1))
        curves.append((f"{'AB'[k % 2]}-{k:03d}", "AB"[k % 2], points, normals, [0, 35, 70, 105, 140]))
    return network_of(curves, "star")


def test_singularity_slots_mode_puts_the_node_on_six_strips():
    network = star_network()
    centre = next(n for n, node in network.nodes.items() if node.kind == "singularity")
    partset = unroll_network(network, options(singularity="slots"))
    strips = {p.meta["strip"] for p in partset.parts if any(n["id"] == centre for n in p.nodes)}
    assert len(strips) == 6
    for part in partset.parts:
        slots = [s for s in part.slots if s.node == centre]
        assert len(slots) == 4  # two crossing pairs, a slot for each of their strips
        shapes = [polygon(s.outline) for s in slots]
        assert all(a.intersection(b).area == 0.0 for i, a in enumerate(shapes) for b in shapes[i + 1:])


def test_singularity_joint_mode_ends_strips_at_a_hexagonal_joint():
    network = star_network()
    centre = next(n for n, node in network.nodes.items() if node.kind == "singularity")
    partset = unroll_network(network, UnrollOptions())
    joints = [p for p in partset.parts if p.kind == "joint"]
    assert len(joints) == 2 and all(p.meta["node"] == centre for p in joints)
    assert len(joints[0].meta["arm_angles_deg"]) == 3 and len(joints[0].holes) == 6
    strips = [p for p in partset.parts if p.kind in STRIP_KINDS]
    assert len(strips) == 12  # three lamellas, two strips each, cut in two at the joint
    for part in strips:
        assert centre not in {n["id"] for n in part.nodes} and not any(s.node == centre for s in part.slots)
        ends = [part.meta["joins"]["start"], part.meta["joins"]["end"]]
        assert {"kind": "joint", "node": centre} in ends and f"J {centre}" in part.label


def same_parts(reference, batched) -> None:
    """Two lists of parts with the same ids, kinds, contours (to 1e-9 mm), nodes, labels and meta."""
    def close(x, y):
        return np.shape(x) == np.shape(y) and np.allclose(x, y, rtol=0.0, atol=1e-9)

    assert [p.id for p in reference] == [p.id for p in batched]
    for r, q in zip(reference, batched):
        assert (r.kind, r.label, r.nodes, r.meta, r.grain, r.lamella) == (q.kind, q.label, q.nodes, q.meta, q.grain, q.lamella)
        assert close(r.outline, q.outline), r.id
        for name in ("holes", "marks", "text"):
            a, b = getattr(r, name), getattr(q, name)
            assert len(a) == len(b) and all(close(x, y) for x, y in zip(a, b)), (r.id, name)
        assert [(s.node, s.edge) for s in r.slots] == [(s.node, s.edge) for s in q.slots]
        assert all(close(s.outline, t.outline) for s, t in zip(r.slots, q.slots)), r.id


@pytest.mark.parametrize("case", ["pavilion", "star-joint"])
def test_batched_straight_strips_equal_the_one_by_one_construction(case, enneper):
    from fabline.geometry import analyse
    from fabline.unroll.batch import straight_flags, straight_parts
    from fabline.unroll.pieces import segment_part
    from fabline.unroll.seams import split_strip
    from fabline.unroll.stations import strip_stations

    network, opts = (enneper, UnrollOptions()) if case == "pavilion" else (star_network(), UnrollOptions())
    segments = [s for strip in strip_stations(analyse(network), opts) for s in split_strip(strip, opts, 20.0)]
    straight = [s for s, flag in zip(segments, straight_flags(segments, opts)) if flag]
    assert len(straight) > 0.8 * len(segments)
    same_parts([segment_part(s, opts) for s in straight], straight_parts(straight, opts))
