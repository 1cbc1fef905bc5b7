"""Raster nesting: placements keep the clearance (checked with exact shapely distances), lattices are dense."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import shapely
from shapely import affinity

from fabline.nest.raster import Canvas, densest_lattice, make_template, place_copies
from fabline.nest.remnants import largest_empty_rectangle
from fabline.nest.shapes import nest_shapes
from fabline.nest.synthetic import cross_clamp, star_washer

CLEARANCE = 3.2


def placed_polygons(canvas, solid, spots):
    out = []
    for template, i, j in spots:
        x, y = canvas.translation(template, i, j)
        out.append(affinity.translate(affinity.rotate(solid, template.rotation, origin=(0, 0)), x, y))
    return out


@pytest.mark.parametrize("part, use_lattice", [(star_washer("W"), True), (cross_clamp("C"), True),
                                               (cross_clamp("C"), False)])
def test_copies_keep_the_clearance_and_stay_on_the_sheet(part, use_lattice):
    shape = nest_shapes([part])[0]
    res = 1.2
    templates = [make_template(shape.solid, angle, res, CLEARANCE / 2) for angle in (0.0, 30.0, 45.0)]
    canvas = Canvas(700, 500, 10, res)
    canvas.block_polygon(shapely.box(200, 150, 400, 300), CLEARANCE / 2)     # an obstacle already placed
    lattice = densest_lattice(templates[0]) if use_lattice else None
    spots = place_copies(canvas, templates, 500, lattice)
    polygons = placed_polygons(canvas, shape.solid, spots)
    assert len(polygons) > 20
    obstacle = shapely.box(200, 150, 400, 300)
    for a, b in itertools.combinations(polygons, 2):
        assert a.distance(b) >= CLEARANCE - 1e-6
    for p in polygons:
        assert p.distance(obstacle) >= CLEARANCE - 1e-6
        minx, miny, maxx, maxy = p.bounds
        assert minx >= 10 - 1e-6 and miny >= 10 - 1e-6 and maxx <= 690 + 1e-6 and maxy <= 490 + 1e-6


def test_cross_lattice_is_as_dense_as_the_greek_cross_tiling():
    # Five a x a squares tile the plane on the lattice (2a, a), (-a, 2a); grown by the clearance the
    # cross fits a cross of side a + c, so 5 (a + c)^2 per copy is achievable and the raster should get close.
    shape = nest_shapes([cross_clamp("C", span=90.0, arm=30.0)])[0]
    res = 1.0
    lattice = densest_lattice(make_template(shape.solid, 0.0, res, CLEARANCE / 2))
    assert lattice.cell_area * res ** 2 <= 1.02 * 5 * (30.0 + CLEARANCE) ** 2


def test_largest_empty_rectangle_against_brute_force():
    rng = np.random.default_rng(5)
    for _ in range(5):
        free = rng.random((9, 11)) > 0.3
        row, col, rows, cols = largest_empty_rectangle(free)
        assert free[row:row + rows, col:col + cols].all()
        best = max(h * w for r0, c0 in np.ndindex(free.shape)
                   for h in range(1, free.shape[0] - r0 + 1) for w in range(1, free.shape[1] - c0 + 1)
                   if free[r0:r0 + h, c0:c0 + w].all())
        assert rows * cols == best
