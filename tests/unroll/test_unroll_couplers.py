"""Shear couplers near the supports: which intervals (counted here along the lamellas from the support ends), the
bolt holes in both strips of the pair (shapely: inside the strip, clear of slots, holes and engraving, at the
interval's middle), and their blocks and bolts in the bill by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest
import shapely

from fabline.jobs.bom import bill_of_materials
from fabline.mechanics.materials import get_material
from fabline.nest.layout import Nesting
from fabline.unroll import UnrollOptions, unroll_network
from fabline.unroll.parts import flatten_contour, load_parts, save_parts

H, T, D = 100.0, 1.5, 25.0


@pytest.fixture(scope="module")
def coupled(enneper):
    return unroll_network(enneper, UnrollOptions(couplers=2))


def test_couplers_sit_in_the_two_intervals_next_to_every_support(enneper, coupled):
    expected = set()
    for lam in enneper.lamellas:
        for nodes in (lam.nodes, lam.nodes[::-1]):
            if enneper.nodes[nodes[0]].kind == "support":
                expected |= {(lam.id, frozenset(pair)) for pair in zip(nodes[:2], nodes[1:3])}
    placed = {(c["lamella"], frozenset(c["nodes"])) for c in coupled.couplers}
    skipped = {(s[0], frozenset(s[1:])) for s in coupled.report["couplers"]["skipped"]}
    assert placed | skipped == expected and not placed & skipped
    assert len(placed) > 0.6 * len(expected)


def test_coupler_holes_are_in_both_strips_at_the_interval_middle_and_clear_of_everything(coupled):
    parts = {p.id: p for p in coupled.parts}
    for coupler in coupled.couplers:
        a, b = coupler["nodes"]
        assert {parts[pid].meta["side"] for pid in coupler["parts"]} == {"L", "R"}
        for pid, xs, y in zip(coupler["parts"], coupler["holes_x_mm"], coupler["hole_y_mm"]):
            part = parts[pid]
            s = {n["id"]: n["s"] for n in part.nodes}
            assert np.mean(xs) == pytest.approx((s[a] + s[b]) / 2, abs=0.01) and xs[1] - xs[0] == pytest.approx(60.0)
            outline = shapely.Polygon(flatten_contour(part.outline)[:, :2])
            mine = [shapely.Point(x, y).buffer(4.25) for x in xs]
            others = [shapely.Polygon(flatten_contour(h)[:, :2]) for h in part.holes]
            others = [o for o in others if not any(o.centroid.distance(m.centroid) < 0.05 for m in mine)]
            slots = [shapely.Polygon(flatten_contour(sl.outline)[:, :2]) for sl in part.slots]
            strokes = [shapely.LineString(line[:, :2]) for line in part.text if len(line) > 1]
            for hole in mine:
                assert outline.buffer(-4.0).contains(hole)                   # 4 mm of strip around it at least
                assert all(hole.distance(o) > 4.0 for o in others + slots)
                assert all(hole.distance(line) > 1.0 for line in strokes)
            # in the slotted half: the same side of the centre line as the slots
            side = np.sign(np.mean([sl.centroid.y for sl in slots])) if slots else np.sign(y)
            assert np.sign(y) == side and abs(y) == H / 4


def test_couplers_in_parts_json_and_in_the_bill(coupled, tmp_path):
    save_parts(coupled, tmp_path / "parts.json")
    assert load_parts(tmp_path / "parts.json").couplers == coupled.couplers
    bom = bill_of_materials(Nesting([], "p.json"), coupled, get_material("stainless"))
    block = next(i for i in bom["items"] if i["kind"] == "coupler")
    assert block["count"] == len(coupled.couplers) and block["size"] == f"120x50x{D - T:g}"
    assert block["unit_mass_kg"] == pytest.approx(120 * 50 * 23.5 * 700e-9, abs=1e-4)
    bolt = next(i for i in bom["items"] if i["item"].startswith("hex bolt with 2 washers"))
    # strip, block, strip 26.5 + two M8 washers 3.2 + nut 6.8 + 2.5 = 39.0 -> 40
    assert (bolt["size"], bolt["length_mm"], bolt["count"]) == ("M8", 40.0, 2 * len(coupled.couplers))
    assert bolt["unit_mass_kg"] * 1000 == pytest.approx(math.pi / 4 * 64 * 40 * 7.85e-3 + 6.5 + 5.2 + 2 * 2.0,
                                                        abs=0.01)


def test_no_couplers_by_default(enneper):
    plain = unroll_network(enneper, UnrollOptions(hardware=False))
    assert plain.couplers == [] and "couplers" not in plain.report
