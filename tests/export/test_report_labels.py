"""Every label is on its part: the ids engraved on strips, edge bars and hardware lie inside the part and clear of
its holes, and the ids written on a sheet picture lie inside their part's material (measured in DejaVu Sans)."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from shapely import affinity
from shapely.geometry import LineString, Point, Polygon, box
from shapely.ops import unary_union

from fabline.model.designs import enneper_network
from fabline.nest.layout import Placement, Sheet, place
from fabline.unroll import UnrollOptions, flatten_contour, unroll_network

ENGRAVED_LINE_MM = 0.5  # a laser's engraved line is narrower (0.1 - 0.3 mm): this much either side must stay clear
FONT = "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf"


@pytest.fixture(scope="module")
def parts():
    """A small Enneper patch with edge bars, washers and clamps, and seams (1.2 m sheets) so strips have holes."""
    network = enneper_network(size=(3.0, 3.0), spacing=0.35)
    return unroll_network(network, UnrollOptions(edge_members=True, sheet_length=1200.0)).parts


def _kind(part):
    return "edge" if part.meta.get("member") == "edge" else part.kind


def test_the_design_has_every_kind_of_labelled_part(parts):
    kinds = {_kind(p) for p in parts if len(p.text)}
    assert {"strip", "washer", "clamp", "edge"} <= kinds, kinds
    assert any(p.holes for p in parts if p.kind == "strip"), "seamed strips with screw holes"


def test_engraved_text_is_inside_its_part_and_clear_of_every_hole(parts):
    """Every engraved stroke, widened to a line of ENGRAVED_LINE_MM either side, inside the part's outline and
    disjoint from each of its holes: curved edge bars too (their ids once ran off the bar along a tangent)."""
    bad = []
    for part in parts:
        if not len(part.text):
            continue
        strokes = [LineString(s[:, :2]) if len(s) > 1 else Point(s[0, :2]) for s in part.text]
        engraved = unary_union(strokes).buffer(ENGRAVED_LINE_MM)
        outline = Polygon(flatten_contour(part.outline, 0.01))
        if not outline.contains(engraved):
            bad.append((part.id, "outside"))
        for hole in part.holes:
            if Polygon(flatten_contour(hole, 0.01)).intersects(engraved):
                bad.append((part.id, "over a hole"))
    assert not bad, bad[:10]


def _label_box(label, mm_per_unit):
    """The text's box on the sheet (mm, y up), measured in DejaVu Sans at its font size, rotated as drawn."""
    from PIL import ImageFont

    font = ImageFont.truetype(FONT, 100)
    size = float(label.get("font-size"))
    assert label.get("text-anchor") == "middle" and label.get("dominant-baseline") == "central"
    left, top, right, bottom = (v * size / 100 for v in font.getbbox(label.text, anchor="mm"))
    x, y = float(label.get("x")), float(label.get("y"))
    shape = box(x + left, y + top, x + right, y + bottom)
    transform = label.get("transform")
    if transform:
        angle, cx, cy = (float(v) for v in transform.removeprefix("rotate(").rstrip(")").split())
        assert (cx, cy) == (x, y)
        shape = affinity.rotate(shape, angle, origin=(x, y))
    return shape


def test_sheet_picture_labels_lie_inside_their_part_clear_of_holes(parts):
    """Each part placed at several rotations on a 4 x 2 m sheet picture: its id's box inside the part's material,
    and for strips and edge bars running along the part (within 10 degrees of its outline nearby)."""
    from fabline.jobs.pictures import sheet_svg

    by_id = {p.id: p for p in parts}
    placements = [Placement(p.id, 2000.0, 1000.0, rotation=(37.0 * k) % 360) for k, p in enumerate(parts)]
    picture = sheet_svg(Sheet("S1", 4000.0, 2000.0, placements), by_id)
    root = ET.fromstring(picture)
    scale = 1.0 / float(root.get("data-mm-per-unit"))
    height = float(root.get("height"))
    labels = {t.text: t for t in root.iter("{http://www.w3.org/2000/svg}text")}
    assert sorted(labels) == sorted(by_id)
    bad = []
    for placement in placements:
        part = by_id[placement.part]

        def screen(points):
            xy = place(flatten_contour(points, 0.05)[:, :2], placement)
            return np.column_stack([xy[:, 0] * scale, height - xy[:, 1] * scale])

        material = Polygon(screen(part.outline), [screen(h) for h in part.holes])
        label = _label_box(labels[part.id], 1 / scale)
        if not material.contains(label):
            bad.append((part.id, round(label.difference(material).area / label.area, 3)))
        if part.kind in ("strip", "curved-strip") and labels[part.id].get("transform"):
            centre = label.centroid
            ring = material.exterior
            at = ring.project(centre)
            a, b = ring.interpolate(at - 1.0), ring.interpolate(at + 1.0)
            edge = math.degrees(math.atan2(b.y - a.y, b.x - a.x))
            angle = float(labels[part.id].get("transform").removeprefix("rotate(").split()[0])
            if abs((edge - angle + 90.0) % 180.0 - 90.0) > 10.0:
                bad.append((part.id, "across the part", edge, angle))
    assert not bad, bad[:10]
