"""Cutting as a laser shop cuts: lead-ins from pierce points clear of every part, tabs by part size, the fibre laser.

The programs are read back with pygcode (not fabline's writer nor its checker's state machine) and measured with
shapely against the nested geometry; expected tab counts are worked out by hand in each test.
"""

from __future__ import annotations

import math
import re

import ezdxf
import numpy as np
import pygcode
import pytest
import shapely

from fabline.export import ToolpathOptions, check_program, export_job, samplejob
from fabline.machine import load_machine
from fabline.nest.layout import Nesting, Placement, Sheet, save_nesting
from fabline.unroll.parts import Part, PartSet, flatten_contour, save_parts

from export_helpers import every_kind_nesting, every_kind_partset, placed_contours, truth_ring

CLEARANCE = 1.0   # both laser profiles' pierce_clearance, mm
ROUNDING = 0.003  # the program's 0.001 mm coordinates and the arcs' flattening


def _square(size: float) -> np.ndarray:
    return np.array([[0, 0], [size, 0], [size, size], [0, size], [0, 0]], float)


def crowded_job() -> tuple[Nesting, PartSet]:
    """Nine 100 mm squares 3 mm apart (the pavilion's nesting gap), a 140 mm square with an 8 mm hole beside them,
    and a 60 mm square with a 1.6 mm hole, too small for any pierce 1 mm clear of its edge."""
    parts = [Part(f"Q{k}", "clamp", _square(100.0)) for k in range(9)]
    parts.append(Part("B", "clamp", _square(140.0), holes=[samplejob.circle(70, 70, 4.0)]))
    parts.append(Part("T", "clamp", _square(60.0), holes=[samplejob.circle(30, 30, 0.8)]))
    placements = [Placement(f"Q{3 * i + j}", 10 + 103 * j, 10 + 103 * i) for i in range(3) for j in range(3)]
    placements += [Placement("B", 322, 10), Placement("T", 465, 10)]
    return Nesting([Sheet("S1", 1000.0, 1000.0, placements)], "parts.json", kerf=0.2), PartSet(parts)


def cut_segments(text: str) -> list[dict]:
    """Every tool-on feed move of a program read with pygcode: its operation comment ("cut-outer Q1"), start, end,
    length (arcs by their radius and sweep) and whether it is the first move after the tool went on or travelled."""
    segments, position, comment, motion, power, tool, fresh = [], (0.0, 0.0), "", None, 0.0, False, True
    for raw in text.splitlines():
        if raw.startswith(";"):
            comment = raw[1:].strip()
            continue
        block = pygcode.Line(raw).block
        for word in block.words:
            if word.letter == "S":
                power = float(word.value)
        for code in block.gcodes:
            name = str(code.word)
            if name in ("M03", "M04"):
                tool, fresh = True, True
            elif name == "M05":
                tool, fresh = False, True
            elif name in ("G00", "G01", "G02", "G03"):
                motion = name
                params = {k: float(v.value) for k, v in code.params.items()}
                target = (params.get("X", position[0]), params.get("Y", position[1]))
                if motion == "G00":
                    fresh = True
                elif tool and power > 0 and target != position:
                    if motion == "G01":
                        length = math.dist(position, target)
                    else:
                        centre = (position[0] + params["I"], position[1] + params["J"])
                        a0 = math.atan2(position[1] - centre[1], position[0] - centre[0])
                        a1 = math.atan2(target[1] - centre[1], target[0] - centre[0])
                        sweep = (a0 - a1) % (2 * math.pi) if motion == "G02" else (a1 - a0) % (2 * math.pi)
                        length = math.hypot(params["I"], params["J"]) * sweep
                    segments.append({"comment": comment, "start": position, "end": target, "length": length,
                                     "first": fresh})
                    fresh = False
                position = target
    return segments


def _material(contours) -> shapely.Geometry:
    """The placed parts as polygons with their holes, from the nested contours (not the toolpaths)."""
    shells = {part: shapely.Polygon(flatten_contour(c, 0.0005)) for part, role, c in contours if role == "outer"}
    holes = {}
    for part, role, c in contours:
        if role == "inner":
            holes.setdefault(part, []).append(flatten_contour(c, 0.0005))
    return shapely.union_all([shapely.Polygon(shell.exterior.coords, holes.get(part, []))
                              for part, shell in shells.items()])


def _export(nesting, partset, machine="grbl-laser", **given):
    profile = load_machine(machine)
    result = export_job(nesting, {p.id: p for p in partset.parts}, profile, ToolpathOptions.for_profile(profile, **given))
    return result.sheets[0]


def _rings(nesting, partset, kerf):
    """(part, role, ring the cut should follow, nested polygon) for every cut contour of the first sheet."""
    return [(part, role, truth_ring(c, kerf / 2, role).exterior, shapely.Polygon(flatten_contour(c, 0.0005)))
            for part, role, c in placed_contours(nesting, partset)]


def every_kind_job() -> tuple[Nesting, PartSet]:
    return every_kind_nesting(), every_kind_partset()


@pytest.mark.parametrize("job", [every_kind_job, crowded_job], ids=["every-kind", "crowded"])
@pytest.mark.parametrize("machine", ["grbl-laser", "fibre-laser"])
def test_every_closed_cut_pierces_in_the_scrap_clear_of_every_part(job, machine):
    nesting, partset = job()
    sheet = _export(nesting, partset, machine)
    kerf = load_machine(machine).kerf
    rings = _rings(nesting, partset, kerf)
    material = _material(placed_contours(nesting, partset))
    lead_ins = {}
    for segment in cut_segments(sheet.gcode):
        if not segment["first"] or not segment["comment"].startswith("cut"):
            continue
        _, part = segment["comment"].split()
        start, end = shapely.Point(segment["start"]), shapely.Point(segment["end"])
        mine = [(p, role, ring, polygon) for p, role, ring, polygon in rings if p == part]
        if min(ring.distance(start) for _, _, ring, _ in mine) < ROUNDING:
            continue                                      # a piece after a tab: the beam starts on the contour
        p, role, ring, polygon = min(mine, key=lambda m: m[2].distance(end))
        assert ring.distance(end) < ROUNDING              # the lead-in runs onto the cut it starts
        assert polygon.contains(start) == (role == "inner"), (part, role, segment["start"])
        assert material.distance(start) >= CLEARANCE - ROUNDING, (part, role, segment["start"])
        assert not shapely.LineString([segment["start"], segment["end"]]).crosses(material)
        lead_ins[(part, role, ring.wkb)] = lead_ins.get((part, role, ring.wkb), 0) + 1
    expected = {(p, role, ring.wkb) for p, role, ring, _ in rings} - {("T", "inner", r.wkb) for p, role, r, _ in rings
                                                                       if (p, role) == ("T", "inner")}
    assert {key: 1 for key in expected} == lead_ins
    assert sheet.no_lead_in == (["T"] if "T" in {p.id for p in partset.parts} else [])


def pocket_job() -> tuple[Nesting, PartSet]:
    """A 100 mm square Q in the hole of a 300 mm frame F, the hole Q's outline grown by 3 mm with round corners (the
    pavilion's nesting gap all round, as nesting into holes leaves it)."""
    q = _square(100.0)
    pocket = np.asarray(shapely.Polygon(q).buffer(3.0, quad_segs=16).exterior.coords)[::-1] + 100.0   # round corners
    frame = Part("F", "clamp", _square(300.0), holes=[pocket])
    return (Nesting([Sheet("S1", 500.0, 500.0, [Placement("F", 10, 10), Placement("Q", 110, 110)])], "parts.json",
                    kerf=0.2), PartSet([frame, Part("Q", "clamp", q)]))


def test_a_lead_in_without_room_is_shortened_rather_than_landing_on_a_neighbour():
    """Q's every vertex is a corner whose outward bisector meets the pocket's round corner 3 mm out: a 2 mm lead-in
    from the toolpath's mitred corner (0.1 * sqrt 2 off the part) pierces 2.14 mm from Q and 0.86 mm from F, too
    close; 1.5 mm (the 0.75 step) pierces 1.64 mm from Q and 1.36 mm from F. The pocket's own cut (inner, of F)
    must pierce in the same 3 mm ring, clear of Q, which sits in its hole."""
    nesting, partset = pocket_job()
    sheet = _export(nesting, partset)
    material = _material(placed_contours(nesting, partset))
    firsts = {s["comment"]: s for s in cut_segments(sheet.gcode) if s["first"] and s["comment"] != "cut-outer F"
              and material.distance(shapely.Point(s["start"])) > 0.5}
    assert sorted(firsts) == ["cut-inner F", "cut-outer Q"]
    for segment in firsts.values():
        pierce = shapely.Point(segment["start"])
        assert CLEARANCE - ROUNDING <= material.distance(pierce) <= 1.5 + ROUNDING   # in the 3 mm ring, 1 mm clear
    assert math.dist(firsts["cut-outer Q"]["start"], firsts["cut-outer Q"]["end"]) == pytest.approx(1.5, abs=ROUNDING)
    assert sheet.no_lead_in == []


@pytest.mark.parametrize("crowded", [False, True])
def test_a_lead_in_with_no_room_at_any_length_moves_to_another_vertex(crowded):
    """Unoptimised, Q's cut starts at its first corner (the lower left, 100, 100). With a small part R whose corner
    stands 0.9 mm off in x and y (1.27 mm away along the corner's bisector, less than twice the 1 mm clearance) no
    lead-in fits along that bisector at any length: the cut starts at another corner, where one fits."""
    parts = [Part("Q", "clamp", _square(100.0)), Part("R", "clamp", _square(20.0))]
    placements = [Placement("Q", 100, 100)] + ([Placement("R", 100 - 0.9 - 20, 100 - 0.9 - 20)] if crowded else [])
    nesting = Nesting([Sheet("S1", 500.0, 500.0, placements)], "parts.json")
    sheet = _export(nesting, PartSet(parts), tabs=0, optimise=False)
    material = _material(placed_contours(nesting, PartSet(parts)))
    [lead_in] = [s for s in cut_segments(sheet.gcode) if s["comment"] == "cut-outer Q" and s["first"]]
    assert material.distance(shapely.Point(lead_in["start"])) >= CLEARANCE - ROUNDING
    at_first_corner = math.dist(lead_in["end"], (99.9, 99.9)) < ROUNDING
    assert at_first_corner != crowded
    assert sheet.no_lead_in == []


def _uncut(sheet, nesting, partset, kerf) -> dict[str, float]:
    """Per outer contour: its ring's length less the feed moves that run along it (lead-ins do not)."""
    segments = cut_segments(sheet.gcode)
    uncut = {}
    for part, role, ring, _ in _rings(nesting, partset, kerf):
        if role != "outer":
            continue
        along = sum(s["length"] for s in segments if s["comment"] == f"cut-outer {part}"
                    and ring.distance(shapely.Point(s["start"])) < ROUNDING
                    and ring.distance(shapely.Point(s["end"])) < ROUNDING)
        uncut[part] = ring.length - along
    return uncut


def test_small_parts_keep_tabs_by_default_and_big_ones_none():
    """grbl-laser: tabs of 1 mm on parts under 150 mm, one per 250 mm of perimeter, at least 2. By hand: the star
    washer W (60 mm across, 8 edges of sqrt(30^2 + 14^2 - 2 30 14 cos 45) = 22.4 mm: 179 mm) and the clamp K (90 mm,
    12 arms' edges of 30 mm: 360 mm) get 2; a 100 mm square (401 mm with the kerf) 2; the 140 mm square (561 mm)
    ceil(561 / 250) = 3; the strips (1200, 900 mm), the curved strip and the 300 mm joint none."""
    expected = {"A": 0, "B": 0, "C": 0, "J": 0, "W": 2, "K": 2}
    nesting, partset = every_kind_nesting(), every_kind_partset()
    uncut = _uncut(_export(nesting, partset), nesting, partset, 0.2)
    assert uncut == pytest.approx({p: 1.0 * n for p, n in expected.items()}, abs=0.01)
    nesting, partset = crowded_job()
    uncut = _uncut(_export(nesting, partset), nesting, partset, 0.2)
    assert uncut == pytest.approx({**{f"Q{k}": 2.0 for k in range(9)}, "B": 3.0, "T": 2.0}, abs=0.01)


def test_explicit_tabs_and_lead_in_override_the_profile_rule():
    nesting, partset = every_kind_nesting(), every_kind_partset()
    sheet = _export(nesting, partset, "fibre-laser", tabs=3, tab_width=0.8)
    assert _uncut(sheet, nesting, partset, 0.15) == pytest.approx({p: 2.4 for p in "ABCWKJ"}, abs=0.01)
    sheet = _export(nesting, partset, "fibre-laser", tabs=0, lead_in=0.0)
    assert _uncut(sheet, nesting, partset, 0.15) == pytest.approx({p: 0.0 for p in "ABCWKJ"}, abs=0.01)
    rings = _rings(nesting, partset, 0.15)
    assert all(min(r.distance(shapely.Point(s["start"])) for _, _, r, _ in rings) < ROUNDING
               for s in cut_segments(sheet.gcode) if s["comment"].startswith("cut"))


def test_the_plotter_draws_without_lead_ins_or_tabs():
    nesting, partset = every_kind_nesting(), every_kind_partset()
    sheet = _export(nesting, partset, "grbl-plotter")
    assert _uncut(sheet, nesting, partset, 0.0) == pytest.approx({p: 0.0 for p in "ABCWKJ"}, abs=0.01)
    assert "no lead-ins" in sheet.gcode and "no tabs" in sheet.gcode


@pytest.fixture
def pavilion_like(tmp_path):
    """The export benchmark's pavilion job, cut down: strips, clamps and washers shelf-nested on 4 x 2 m sheets."""
    nesting, partset = samplejob.pavilion_job(strips=30, washers=120, clamps=30)
    nesting.gap = 5.8   # its parts stand 6 mm apart: a nesting gap of 5.8 mm and the 0.2 mm kerf, as the validator reads it
    save_parts(partset, tmp_path / "parts.json")
    save_nesting(nesting, tmp_path / "nesting.json")
    return tmp_path, nesting, partset


def test_the_fibre_laser_exports_the_pavilion_like_job_and_prints_its_machine_time(cli, pavilion_like):
    folder, nesting, partset = pavilion_like
    code, out, err = cli("export", folder / "nesting.json", "-o", folder / "out", "--machine", "fibre-laser")
    assert code == 0, err
    assert "machine fibre-laser, kerf 0.15 mm; lead-in 2 mm, pierce clearance 1 mm; tabs 0.5 mm on parts under" in out
    assert "cuts from the DXF in its own CAM" in out
    profile = load_machine("fibre-laser")
    rows = re.findall(r"^(S\d+)\s+(\d+)\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)\s+(\d+):(\d\d):(\d\d)$", out, re.M)
    assert len(rows) == len(nesting.sheets)
    for sheet_id, _, cut_m, _, travel_m, h, m, s in rows:
        text = (folder / "out" / f"nesting_{sheet_id}.gcode").read_text()
        report = check_program(text, profile)
        assert report.problems == []
        printed = 3600 * int(h) + 60 * int(m) + int(s)
        assert printed == pytest.approx(report.summary.time, abs=0.5)   # what gcode-check recomputes from the file
        # at least the cutting at its feeds, the travel at the rapid rate and the dwell of every pierce
        cut_in = sum(sg["length"] for sg in cut_segments(text) if sg["comment"].startswith("cut-inner"))
        cut_out = sum(sg["length"] for sg in cut_segments(text) if sg["comment"].startswith("cut-outer"))
        pierces = text.count("G4 P0.300")
        assert pierces == sum(1 for sg in cut_segments(text) if sg["first"] and sg["comment"].startswith("cut"))
        floor = cut_in / 6000 * 60 + cut_out / 18000 * 60 + float(travel_m) * 1000 / 100000 * 60 + 0.3 * pierces
        assert floor <= printed + 0.5 <= 3 * floor
    doc = ezdxf.readfile(folder / "out" / f"nesting_{rows[0][0]}.dxf")
    auditor = doc.audit()
    assert not auditor.has_errors and not auditor.has_fixes
    assert len(doc.modelspace().query("INSERT")) == len(nesting.sheets[0].placements)


def test_a_cut_with_no_room_for_a_lead_in_is_reported(cli, tmp_path):
    nesting, partset = crowded_job()
    save_parts(partset, tmp_path / "parts.json")
    save_nesting(nesting, tmp_path / "nesting.json")
    code, out, err = cli("export", tmp_path / "nesting.json", "-o", tmp_path / "out", "--no-preview")
    assert code == 0, err
    assert "sheet S1: 1 cut without a lead-in (no room for one 1 mm clear of every part), first on part T" in out
    assert "; lead-in 2 mm, pierce clearance 1 mm; 1 cut without [no room]" in (tmp_path / "out" / "nesting_S1.gcode").read_text()


def test_cutting_settings_come_from_the_job_file_with_units(tmp_path):
    import tomllib

    from fabline.jobs.jobfile import job_from_dict, toolpath_options
    from jobfiles import GOOD

    text = GOOD + '[export]\nlead_in = "3 mm"\npierce_clearance = "0.05 cm"\ntabs_below = "0.2 m"\n'
    spec = job_from_dict(tomllib.loads(text), tmp_path / "job.toml")
    options = toolpath_options(spec.export, load_machine("fibre-laser"))
    assert (options.lead_in, options.pierce_clearance, options.tabs_below) == pytest.approx((3.0, 0.5, 200.0))
    assert (options.tabs, options.tab_width, options.tab_every, options.kerf) == (None, 0.5, 250.0, 0.15)  # the profile's


@pytest.mark.parametrize("edit, message", [
    ("[cutting]\nlead_in = -1\n", "cutting.lead_in: -1 is out of range [0.0, 100.0]"),
    ("[cutting]\ntab_widht = 1\n", "cutting.tab_widht: unknown setting"),
    ('main_output = "svg"\n', "main_output: 'svg' is not one of gcode, dxf"),
    ("[operations.cut-outer]\npierce = 0.3\n", "operations.cut-outer.pierce: a dwell in laser mode"),
])
def test_bad_cutting_settings_name_the_file_and_the_key(tmp_path, edit, message):
    from fabline.errors import FablineError

    (tmp_path / "m.toml").write_text('extends = "grbl-laser"\nname = "m"\n' + edit)
    with pytest.raises(FablineError, match=re.escape(message)):
        load_machine(str(tmp_path / "m.toml"))
