"""Toolpaths against independent truth: kerf offsets vs shapely's buffer, read back with gcodeparser; order; options."""

from __future__ import annotations

import numpy as np
import pytest
import shapely

from fabline.export import ToolpathOptions, export_job, sheet_toolpaths, travel_length
from fabline.export import samplejob
from fabline.export.contours import offset, segment_lengths, signed_area
from fabline.machine import load_machine
from fabline.nest.layout import CommonCut, Nesting, Placement, Sheet
from fabline.unroll.parts import Part, PartSet

from export_helpers import every_kind_nesting, every_kind_partset, placed_contours, read_toolpaths, truth_ring


def _program(nesting, partset, kerf, machine="grbl-laser", **options):
    result = export_job(nesting, {p.id: p for p in partset.parts}, load_machine(machine),
                        ToolpathOptions(kerf=kerf, **options))
    return result.sheets[0].gcode, result


@pytest.mark.parametrize("kerf", [0.0, 0.2])
def test_cut_paths_equal_nested_geometry_offset_by_half_the_kerf(kerf):
    nesting, partset = every_kind_nesting(), every_kind_partset()
    gcode, _ = _program(nesting, partset, kerf)
    cuts = [run for run in read_toolpaths(gcode) if run["comment"].startswith("cut")]
    truths = placed_contours(nesting, partset)
    assert len(cuts) == len(truths)
    kinds_seen = set()
    for part_id, role, contour in truths:
        expected = truth_ring(contour, kerf / 2, role)
        candidates = [c for c in cuts if c["comment"] == f"cut-{role} {part_id}"]
        distances = [shapely.LinearRing(c["points"]).hausdorff_distance(expected.exterior) for c in candidates]
        assert min(distances) < 0.01, (part_id, role, min(distances))
        kinds_seen.add(part_id)
    assert kinds_seen == {"A", "B", "C", "W", "K", "J"}


def test_a_3mm_slot_comes_out_3mm_with_kerf():
    """The outer toolpath inside an edge notch runs kerf/2 inside the slot walls, so the cut slot is 3.000 mm."""
    part = samplejob.strip_part("A", 800.0, "top")
    nesting = Nesting([Sheet("S", 4000, 2000, [Placement("A", 100, 100)])], "parts.json")
    gcode, _ = _program(nesting, PartSet([part]), 0.2)
    outer = next(r for r in read_toolpaths(gcode) if r["comment"] == "cut-outer A")["points"]
    slot = part.slots[0].outline
    y = 100 + (slot[:, 1].min() + slot[:, 1].max()) / 2          # half-way down the notch
    line = shapely.LineString([(100 + slot[:, 0].min() - 2, y), (100 + slot[:, 0].max() + 2, y)])
    crossings = sorted(p.x for p in shapely.LinearRing(outer).intersection(line).geoms)
    assert len(crossings) == 2
    tool_gap = crossings[1] - crossings[0]
    assert tool_gap + 0.2 == pytest.approx(3.0, abs=1e-3)


def test_arcs_stay_arcs_and_offset_to_concentric_arcs():
    """A circular hole of radius r cut with kerf k is four G3 arcs of radius r - k/2 (closed form)."""
    part = Part("H", "washer", np.array([[0, 0], [60, 0], [60, 60], [0, 60], [0, 0]], float),
                holes=[samplejob.circle(30, 30, 10.0)])
    nesting = Nesting([Sheet("S", 500, 500, [Placement("H", 50, 50)])], "parts.json")
    gcode, _ = _program(nesting, PartSet([part]), 0.4)
    arcs = [line for line in gcode.splitlines() if line.startswith(("G2 ", "G3 "))]
    assert len(arcs) == 4
    for line in arcs:
        words = dict((w[0], float(w[1:])) for w in line.split()[1:])
        assert np.hypot(words["I"], words["J"]) == pytest.approx(9.8, abs=1e-3)


def test_offset_closed_forms():
    square = np.array([[0, 0, 0], [10, 0, 0], [10, 10, 0], [0, 10, 0], [0, 0, 0]], float)
    grown = offset(square, 0.5)
    assert signed_area(grown) == pytest.approx(11.0 ** 2)                 # mitre corners stay square
    circle = samplejob.circle(0, 0, 5.0)
    assert signed_area(circle) == pytest.approx(np.pi * 25)
    assert np.sum(segment_lengths(offset(circle, -1.0))) == pytest.approx(2 * np.pi * 4.0)
    assert np.sum(segment_lengths(offset(circle, 1.0))) == pytest.approx(2 * np.pi * 6.0)


def test_marks_then_inner_then_outer_for_every_part():
    nesting, partset = every_kind_nesting(), every_kind_partset()
    paths = sheet_toolpaths(nesting.sheets[0], {p.id: p for p in partset.parts}, ToolpathOptions(kerf=0.2))
    rank = {"engrave-mark": 0, "engrave-text": 0, "cut-inner": 1, "cut-outer": 2}
    ranks = [rank[p.operation] for p in paths]
    assert ranks == sorted(ranks)
    for part in partset.parts:
        mine = [k for k, p in enumerate(paths) if p.part == part.id]
        outer = [k for k in mine if paths[k].operation == "cut-outer"]
        features = [k for k in mine if k not in outer]
        assert outer and features and min(outer) > max(features)


def test_travel_is_at_least_30_percent_below_the_plain_order():
    nesting, partset = samplejob.pavilion_job(strips=40, washers=80, clamps=20)
    parts = {p.id: p for p in partset.parts}
    for sheet in nesting.sheets:
        plain = travel_length(sheet_toolpaths(sheet, parts, ToolpathOptions(kerf=0.2, optimise=False)))
        optimised = travel_length(sheet_toolpaths(sheet, parts, ToolpathOptions(kerf=0.2)))
        assert optimised <= 0.7 * plain, (sheet.id, optimised, plain)


def test_common_cut_is_cut_once():
    """Two 100 x 50 plates sharing a 100 mm edge: with a common cut the shared edge is cut once (closed form)."""
    rect = np.array([[0, 0], [100, 0], [100, 50], [0, 50], [0, 0]], float)
    parts = {"P": Part("P", "clamp", rect), "Q": Part("Q", "clamp", rect)}
    sheet = Sheet("S", 500, 500, [Placement("P", 10, 10), Placement("Q", 10, 60)],
                  common_cuts=[CommonCut(("P", "Q"), (10.0, 60.0), (110.0, 60.0))])
    profile = load_machine("grbl-laser")
    result = export_job(Nesting([sheet], "parts.json"), parts, profile, ToolpathOptions(kerf=0.0))
    assert result.sheets[0].summary.cut_length == pytest.approx(2 * 300 - 100, abs=1e-6)
    cuts = [r for r in read_toolpaths(result.sheets[0].gcode) if r["comment"].startswith("cut")]
    assert sum(shapely.LineString(r["points"]).length for r in cuts) == pytest.approx(500, abs=1e-6)


def test_tabs_leave_bridges_and_lead_ins_start_on_the_scrap_side():
    rect = np.array([[0, 0], [200, 0], [200, 100], [0, 100], [0, 0]], float)
    part = Part("P", "clamp", rect, holes=[samplejob.circle(100, 50, 10.0)])
    nesting = Nesting([Sheet("S", 1000, 1000, [Placement("P", 100, 100)])], "parts.json")
    partset = PartSet([part])
    _, plain = _program(nesting, partset, 0.0)
    gcode, tabbed = _program(nesting, partset, 0.0, tabs=4, tab_width=2.0)
    assert plain.sheets[0].summary.cut_length - tabbed.sheets[0].summary.cut_length == pytest.approx(8.0, abs=1e-6)
    assert len([r for r in read_toolpaths(gcode) if r["comment"] == "cut-outer P"]) == 4
    gcode, _ = _program(nesting, partset, 0.2, lead_in=3.0)
    body = shapely.Polygon(rect + 100)
    for run in read_toolpaths(gcode):
        first = shapely.Point(run["points"][0])
        if run["comment"] == "cut-outer P":
            assert not body.contains(first) and body.exterior.distance(first) > 2.0
        elif run["comment"] == "cut-inner P":
            assert shapely.Point(200, 150).distance(first) < 10.0 - 2.0


def test_a_profile_without_arcs_gets_lines_within_tolerance(tmp_path):
    (tmp_path / "no-arcs.toml").write_text('extends = "grbl-laser"\nname = "no-arcs"\narcs = false\n'
                                           'words = ["G0", "G1", "G4", "G17", "G21", "G90", "G94", "M2", "M4", "M5"]\n')
    nesting, partset = every_kind_nesting(), every_kind_partset()
    result = export_job(nesting, {p.id: p for p in partset.parts}, load_machine(str(tmp_path / "no-arcs.toml")),
                        ToolpathOptions(kerf=0.2))
    gcode = result.sheets[0].gcode
    assert not [line for line in gcode.splitlines() if line.startswith(("G2 ", "G3 "))]
    cuts = [run for run in read_toolpaths(gcode) if run["comment"].startswith("cut")]
    for part_id, role, contour in placed_contours(nesting, partset):
        expected = truth_ring(contour, 0.1, role).exterior
        best = min(shapely.LinearRing(c["points"]).hausdorff_distance(expected)
                   for c in cuts if c["comment"] == f"cut-{role} {part_id}")
        assert best < 0.01, (part_id, role, best)
