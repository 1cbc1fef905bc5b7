"""Seams wherever the geometry allows a valid joint: the overlap may hold slots (both layers are cut at the same strip
stations, so their slots line up), seams shift and shorten within their limits, and when none fits the error says
which limit fails. The manual's helicoid (docs/model.md) (nodes 250 mm apart, which used to fail) is the test case."""

from __future__ import annotations

import numpy as np
import pytest
from shapely.geometry import Point, Polygon

from fabline.errors import FablineError
from fabline.unroll import UnrollOptions, flatten_contour, unroll_network


@pytest.fixture(scope="module")
def helicoid_parts(helicoid):
    options = UnrollOptions(hardware=False)
    return options, unroll_network(helicoid, options)


def _seam_pairs(partset):
    """(first segment, second segment, seam join meta) for every seam of every strip."""
    parts = {p.id: p for p in partset.parts}
    for part in partset.parts:
        end = part.meta["joins"]["end"]
        if end and end["kind"] == "seam":
            yield part, parts[end["part"]], end


def test_the_readme_helicoid_unrolls_with_seams(cli, tmp_path):
    model, parts = tmp_path / "helicoid.network.json", tmp_path / "parts.json"
    assert cli("design", "helicoid", "--pitch", "6", "--radius", "3", "--turns", "0.5", "-o", model)[0] == 0
    code, out, err = cli("unroll", model, "-o", parts)
    assert code == 0, err
    assert "no seam fits" not in err


def test_overlapping_segments_have_their_slots_at_the_same_strip_stations(helicoid_parts):
    options, partset = helicoid_parts
    seams = list(_seam_pairs(partset))
    assert seams
    shared_slots = 0
    for first, second, join in seams:
        a0, a1 = first.meta["strip_range_mm"][0], second.meta["strip_range_mm"][0]
        overlap = (a1, first.meta["strip_range_mm"][1])
        assert overlap[1] - overlap[0] == pytest.approx(join["overlap_mm"], abs=2e-3)
        assert options.shortest_overlap - 1e-6 <= join["overlap_mm"] <= options.overlap + 1e-6

        def slots_in_overlap(part, start):
            xs = [start + float(np.mean(np.asarray(slot.outline)[:-1, 0])) for slot in part.slots]
            return sorted(x for x in xs if overlap[0] < x < overlap[1])

        a, b = slots_in_overlap(first, a0), slots_in_overlap(second, a1)
        assert a == pytest.approx(b, abs=2e-3)
        shared_slots += len(a)
    assert shared_slots > 0  # the short helicoid intervals need seams whose overlap holds slots


def test_screw_holes_and_overlap_ends_keep_a_web_from_every_slot(helicoid_parts):
    options, partset = helicoid_parts
    for part in partset.parts:
        if not part.holes:
            continue
        slots = [Polygon(flatten_contour(np.asarray(slot.outline))) for slot in part.slots]
        length = part.meta["length_mm"]
        for hole in part.holes:
            centre = np.asarray(hole)[:4, :2].mean(axis=0)
            circle = Point(centre).buffer(options.screw_hole / 2.0, quad_segs=32)
            assert min((circle.distance(s) for s in slots), default=np.inf) >= options.web - 1e-3, part.id
        for slot in slots:
            xmin, _, xmax, _ = slot.bounds
            assert xmin >= options.web - 1e-3 and length - xmax >= options.web - 1e-3, part.id


def test_when_no_seam_fits_the_error_names_the_limit(helicoid):
    with pytest.raises(FablineError) as error:
        unroll_network(helicoid, UnrollOptions(min_overlap=150.0, hardware=False))
    message = str(error.value)
    assert "no seam fits" in message and "shortened down to 150 mm (min overlap)" in message
    # the helicoid's 152.8 mm intervals at B-005 hold no 150 mm overlap clear of its node marks by 1.5 mm each side
    assert "lamella B-005" in message and "N005-000..N005-001 (152.8 mm)" in message
    assert "the overlap would cover a node mark" in message and "\n" not in message
