"""Washers and clamps carry their node's id, engraved inside the part clear of its holes, when they have room."""

from __future__ import annotations

import numpy as np
import pytest
from shapely.geometry import LineString, Polygon

from fabline.mechanics.materials import Profile
from fabline.unroll import UnrollOptions, flatten_contour, unroll_network
from fabline.unroll.strokes import layout


@pytest.fixture(scope="module")
def hardware(enneper):
    return [p for p in unroll_network(enneper, UnrollOptions()).parts if p.kind in ("washer", "clamp")]


def test_short_ids_drop_the_n_and_leading_zeros():
    from fabline.unroll.hardware import short_id

    assert [short_id(n) for n in ("N012-007", "N000-010", "N07", "X-001")] == ["12-7", "0-10", "7", "X-1"]


def test_every_washer_and_clamp_is_engraved_with_its_node_id_inside_the_part(hardware):
    from fabline.unroll.hardware import short_id

    kinds = {p.kind for p in hardware}
    assert kinds == {"washer", "clamp"}
    for part in hardware:
        strokes = list(part.text)
        glyphs = layout(short_id(part.meta["node"]))
        assert len(strokes) == len(glyphs.starts), part.id
        solid = Polygon(flatten_contour(part.outline), [flatten_contour(h) for h in part.holes])
        inner = solid.buffer(-1.0)  # at least a millimetre of material around every stroke
        assert all(inner.contains(LineString(s)) for s in strokes if len(s) > 1), part.id
        points = np.concatenate(strokes)
        extent = np.linalg.norm(points.max(axis=0) - points.min(axis=0))
        assert extent > 3 * 1.5, part.id  # readable: well above the smallest engraved height


def test_the_id_is_the_node_ids_glyphs_scaled_and_placed(hardware):
    """The engraved strokes are `layout(node id)` scaled by one cap height and moved rigidly (same shape)."""
    from fabline.unroll.hardware import short_id

    part = next(p for p in hardware if p.kind == "clamp")
    glyphs = layout(short_id(part.meta["node"]))
    points = part.text.points
    reference = glyphs.points
    # a rigid motion with one scale maps the layout onto the strokes: compare the distance matrices' ratio
    d_part = np.linalg.norm(points[:, None] - points[None], axis=-1)
    d_ref = np.linalg.norm(reference[:, None] - reference[None], axis=-1)
    mask = d_ref > 1e-6
    ratio = d_part[mask] / d_ref[mask]
    assert ratio.std() < 1e-9 * ratio.mean() and ratio.mean() >= 1.5


def test_hardware_too_small_for_an_id_is_left_blank(enneper):
    parts = unroll_network(enneper, UnrollOptions(profile=Profile(20.0, 0.5), pair_spacing=0.0, overlap=60.0,
                                                  screw_hole=1.0, bolt_square=2.0)).parts
    washers = [p for p in parts if p.kind == "washer"]
    assert washers and all(len(p.text) == 0 for p in washers)


def test_clamp_arms_fold_up_between_the_washer_and_the_cable_hole(enneper, hardware):
    """Each clamp has one engraved fold line straight across each arm, past the washer it lies on and short of the
    cable hole and the node id, so the bent-up tip holds the cable hole facing along the diagonal."""
    from fabline.unroll.hardware import CABLE_HOLE, HardwareSizes

    options = UnrollOptions()
    sizes = HardwareSizes.of(options.profile, options.pair_spacing, options.bolt_square)
    for part in (p for p in hardware if p.kind == "clamp"):
        folds = [np.asarray(line) for line in part.marks]
        assert len(folds) == 4 and len(part.meta["folds"]) == 4
        solid = Polygon(flatten_contour(part.outline))
        holes = [Polygon(flatten_contour(h)) for h in part.holes[1:]]  # the four cable holes (the first is the bolt's)
        text = LineString(np.concatenate(list(part.text)))
        for line in folds:
            fold = LineString(line)
            middle = line.mean(axis=0)
            assert np.linalg.norm(middle) == pytest.approx(sizes.washer_reach + 1.0, abs=1e-9)
            assert abs(np.dot(line[1] - line[0], middle)) < 1e-9           # across the arm
            assert solid.contains(fold)
            assert min(fold.distance(h) for h in holes) >= CABLE_HOLE / 2.0 and fold.distance(text) > 0.5
