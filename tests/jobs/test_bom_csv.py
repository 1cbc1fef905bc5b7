"""The bill of materials as rows and as bom.csv: fasteners sized from their stack-ups by hand, the CSV read back with
the csv module and its totals checked against counts made here from parts.json's raw JSON."""

from __future__ import annotations

import csv
import json
import math

import pytest

from fabline.errors import FablineError
from fabline.jobs.bom import BOM_COLUMNS, bill_of_materials, write_bom_csv
from fabline.jobs.fasteners import fastener_rows
from fabline.mechanics.hardware import load_catalogue
from fabline.mechanics.materials import get_material
from fabline.nest.layout import Nesting, Sheet
from fabline.unroll import UnrollOptions, unroll_network
from fabline.unroll.hardware import HardwareSizes, clamp, washers
from fabline.mechanics.materials import Profile
from fabline.unroll.parts import save_parts


def test_bolt_sizes_and_lengths_from_the_stack_up_by_hand():
    catalogue = load_catalogue()
    assert catalogue.size_for_hole(8.5, square=True).name == "M8"      # DIN 603 M8's neck is 8 mm square
    assert catalogue.size_for_hole(5.5).name == "M5"                   # ISO 273 fine: M5 5.3, M6 6.4
    assert catalogue.size_for_hole(10.0).name == "M8"                  # M10 needs 10.5
    with pytest.raises(FablineError, match="smaller than any bolt"):
        catalogue.size_for_hole(3.0)
    # 100 x 1.5 mm pair: washer + h + washer = 103, nut 6.8, two pitches 2.5: 112.3 -> 120 (DIN 603 has 110, 120)
    bolt = catalogue.bolt("carriage", 8.5, 103.0, square=True)
    assert bolt.length == 120 and bolt.size.name == "M8"
    # its mass: the nominal shank pi/4 8^2 120 mm3 of steel, the head and the nut, in grams
    assert bolt.mass_g == pytest.approx(math.pi / 4 * 64 * 120 * 7.85e-3 + 8.3 + 5.2)
    # seam: two 1.5 mm strips, an M5 washer 1.0, nut 4.7, 1.6 of thread: 10.3 -> 12
    assert catalogue.bolt("button", 5.5, 3.0, washers=1).length == 12


def test_a_clamp_can_make_a_node_bolt_longer():
    """62 x 1.5: without a clamp 62 + 3 + 6.8 + 2.5 = 74.3 -> 75; with one 75.8 -> 80: two rows."""
    sizes = HardwareSizes.of(Profile(62.0, 1.5), 25.0, 8.5)
    parts = [*washers("N1", (0.0, 90.0), sizes), *washers("N2", (0.0, 90.0), sizes), *washers("N3", (0.0, 80.0), sizes),
             clamp("N1", 90.0, sizes)]
    rows = fastener_rows(parts, 62.0, 1.5, 5.5, load_catalogue())
    assert [(r["item"], r["count"], r["grip_mm"]) for r in rows] == [
        ("carriage bolt with nut M8x75", 2, 65.0), ("carriage bolt with nut M8x80", 1, 66.5)]
    assert rows[0]["size"] == "M8" and rows[1]["length_mm"] == 80


@pytest.fixture(scope="module")
def pavilion(enneper, tmp_path_factory):
    partset = unroll_network(enneper, UnrollOptions(material=get_material("stainless")))
    folder = tmp_path_factory.mktemp("bom")
    save_parts(partset, folder / "parts.json")
    nesting = Nesting([Sheet(f"S{k}", 4000.0, 2000.0) for k in range(1, 22)], "parts.json")
    bom = bill_of_materials(nesting, partset, get_material("stainless"))
    write_bom_csv(bom["items"], folder / "bom.csv")
    return folder, bom


def test_bom_csv_reads_back_with_totals_counted_from_parts_json(pavilion):
    folder, bom = pavilion
    with open(folder / "bom.csv", newline="", encoding="utf-8") as handle:
        reader = csv.DictReader(handle)
        assert tuple(reader.fieldnames) == BOM_COLUMNS
        rows = list(reader)
    raw = json.loads((folder / "parts.json").read_text())
    parts = raw["parts"]
    by_kind = {}
    for part in parts:
        by_kind[part["kind"]] = by_kind.get(part["kind"], 0) + 1

    def total(kind: str, word: str) -> int:
        return sum(int(r["count"]) for r in rows if r["kind"] == kind and word in r["item"])

    nodes = {p["meta"]["node"] for p in parts if p["kind"] == "washer"}
    seams = sum(1 for p in parts if ((p["meta"].get("joins") or {}).get("start") or {}).get("kind") == "seam")
    assert total("fastener", "carriage bolt") == len(nodes) == by_kind["washer"] // 2
    assert total("fastener", "button head screw") == 6 * seams
    assert total("cut part", "washer") == by_kind["washer"] and total("cut part", "clamp") == by_kind["clamp"]
    assert total("sheet", "sheet") == 21
    # the cables: one row per run, its cut length; the total as parts.json's cables add up
    cable_rows = [r for r in rows if r["kind"] == "cable"]
    assert len(cable_rows) == len(raw["cables"]) == 36
    cut = sum(float(r["length_mm"]) for r in cable_rows)
    assert cut == pytest.approx(sum(c["cut_length_mm"] for c in raw["cables"]), abs=0.5)
    geometric = sum(c["geometric_length_mm"] for c in raw["cables"])
    assert abs(cut - geometric) < 0.1 * geometric
    # masses: a cable row is its length times 0.8 x pi 3^2 mm2 x 7900 kg/m3; every total is count x unit mass
    kg_per_m = 0.8 * math.pi * 9 * 7900e-6
    assert sum(float(r["total_mass_kg"]) for r in cable_rows) == pytest.approx(cut / 1000 * kg_per_m, rel=1e-3)
    for r in rows:
        if r["unit_mass_kg"]:
            assert float(r["total_mass_kg"]) == pytest.approx(int(r["count"]) * float(r["unit_mass_kg"]), rel=2e-3,
                                                              abs=0.01)
    assert bom["cables"]["runs"] == 36 and bom["cables"]["cut_length_m"] == pytest.approx(cut / 1000, abs=1e-3)


def test_edge_and_end_fix_fasteners_from_the_edge_stack_up_by_hand(enneper):
    # the bars lie on the washers: offsets +-(h/2 + t + t/2) = +-52.25, so 103 mm between them (h + 2t): the spacer
    # tube's length; edge bolt grip 103 + 2 bars = 106 + nut 6.8 + 2.5 = 115.3 -> 120. End fix: strip, cleat (the
    # pair's gap 25 - 1.5 = 23.5), strip: grip 26.5 + 9.3 = 35.8 -> 40; one per lamella end, two per lamella
    partset = unroll_network(enneper, UnrollOptions(edge_members=True, pair_spacing=25.0))
    items = bill_of_materials(Nesting([], "p.json"), partset, get_material("stainless"))["items"]
    row = {i["item"]: i for i in items}
    ends = 2 * len(enneper.lamellas)
    assert row["end-fix hex bolt with nut M8x40"]["count"] == ends
    assert row["square tube cleat 23.5 x 1.5"]["count"] == ends
    assert row["square tube cleat 23.5 x 1.5"]["length_mm"] == pytest.approx(103.0)
    tube = next(i for i in items if i["item"].startswith("spacer tube"))
    assert tube["length_mm"] == pytest.approx(103.0)
    edge_bolts = [i for i in items if i["item"].startswith("edge bolt")]
    bar_holes = {n["id"] for p in partset.parts if p.meta.get("member") == "edge" for n in p.nodes}
    assert sum(i["count"] for i in edge_bolts) == tube["count"] == len(bar_holes)
    assert "edge bolt with nut M8x120" in row
    # one bolt per axis: no carriage bolt is counted at an edge bar's hole
    carriage = sum(i["count"] for i in items if i["item"].startswith("carriage bolt"))
    washer_nodes = {p.meta["node"] for p in partset.parts if p.kind == "washer"}
    assert carriage == len(washer_nodes - bar_holes)
