"""Asymptotic lamellas (k_n = 0) unroll to exact rectangles: checked on the built-in catenoid, Enneper and helicoid
against their closed-form arc lengths (domain.md 3), and the nest's strip lower bound counts every one of them."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fabline.nest import NestOptions, nest
from fabline.shop.stock import StockItem
from fabline.unroll import UnrollOptions, unroll_network


def _grid_parameters(network, node_id: str) -> tuple[float, float]:
    """(a, b) of a built-in design's node N{i}-{j}: the grid values it was made from (meta["grid"])."""
    i, j = (int(k) for k in node_id[1:].split("-"))
    return network.meta["grid"]["a"][i], network.meta["grid"]["b"][j]


def _closed_form_length_m(network, first: str, last: str) -> float:
    """Arc length (m) along the asymptotic line from node `first` to node `last`, from the surface's closed form."""
    (a0, b0), (a1, b1) = _grid_parameters(network, first), _grid_parameters(network, last)
    meta = network.meta
    if meta["design"] == "catenoid":
        # theta -+ z/w = const: ds = sqrt(2) cosh(z/w) dz, z = w (a - b) / 2
        w = meta["waist_m"]
        z0, z1 = w * (a0 - b0) / 2, w * (a1 - b1) / 2
        return abs(math.sqrt(2) * w * (math.sinh(z1 / w) - math.sinh(z0 / w)))
    if meta["design"] == "enneper":
        # a u-line (v fixed) has ds = 6 c (1 + u^2 + v^2) du; a v-line the same with u and v swapped
        c = meta["scale_m_per_unit"]
        along, fixed = ((a0, a1), b0) if b0 == b1 else ((b0, b1), a0)
        return abs(6 * c * ((along[1] - along[0]) * (1 + fixed**2) + (along[1] ** 3 - along[0] ** 3) / 3))
    # helicoid: a ruling (angle fixed) is straight; a helix at radius rho rises pitch / 2 pi per radian
    p = meta["pitch_m"] / (2 * math.pi)
    if b0 == b1:
        return abs(a1 - a0)
    return math.hypot(a0, p) * abs(b1 - b0)


def _design(request, name):
    return request.getfixturevalue(name)


@pytest.mark.parametrize("name", ["catenoid", "enneper", "helicoid"])
def test_every_asymptotic_lamella_unrolls_to_a_rectangle_of_its_closed_form_length(request, name):
    """Single lamellas (no pair offset), so each strip is the network curve itself: every segment a `strip` whose
    outline is the h-high rectangle (notches aside), the whole strip as long as the closed form plus both ends."""
    network = _design(request, name)
    options = UnrollOptions(pair_spacing=0.0, hardware=False)
    partset = unroll_network(network, options)
    h = options.profile.h
    for part in partset.parts:
        assert part.kind == "strip", f"{part.id} is {part.kind} (in-plane radius {part.meta['in_plane_radius_mm']})"
        outline = np.asarray(part.outline)
        bulges = outline[:, 2] if outline.shape[1] == 3 else np.zeros(len(outline))
        assert set(bulges.tolist()) <= {0.0, -1.0}, f"{part.id}: arcs other than slot ends in a straight strip"
        length = part.meta["length_mm"]
        x, y = outline[:, 0], outline[:, 1]
        assert x.min() == 0.0 and x.max() == pytest.approx(length, abs=1e-3) and np.abs(y).max() == h / 2
        for corner_x in (x.min(), x.max()):  # both ends are straight cuts across the full height
            assert set(y[x == corner_x].tolist()) == {-h / 2, h / 2}, part.id
    lamellas = {lam.id: lam for lam in network.lamellas}
    for row in partset.report["strips"]:
        lam = lamellas[row["lamella"]]
        expected = _closed_form_length_m(network, lam.nodes[0], lam.nodes[-1]) * 1000.0 + 2 * options.end
        assert row["length_mm"] == pytest.approx(expected, abs=0.05e-3 * expected), row["strip"]


@pytest.mark.parametrize("name", ["catenoid", "enneper", "helicoid"])
def test_paired_asymptotic_strips_are_all_straight_and_the_nest_bound_counts_them(request, name):
    """With the default 25 mm pairs every segment is still a rectangle, and the nest's strip lower bound (rows of
    strips on a sheet) is at least the bound recomputed here from the strip lengths alone."""
    network = _design(request, name)
    partset = unroll_network(network, UnrollOptions(hardware=False))
    kinds = {part.kind for part in partset.parts}
    assert kinds == {"strip"}
    if name != "catenoid":
        return  # nesting once is enough; the catenoid is the design whose strips used to drop out of the bound
    options = NestOptions(time_limit=2.0)
    sheet = StockItem("sheet", 4000.0, 2000.0)
    result = nest(partset, [sheet], options)
    spacing = options.clearance
    usable_w, usable_h = sheet.width - 2 * options.margin, sheet.height - 2 * options.margin
    lengths = np.array([p.meta["length_mm"] for p in partset.parts])
    rows = math.ceil(np.sum(lengths + spacing) / (usable_w + spacing))       # each row holds usable_w + spacing
    per_sheet = int((usable_h + spacing) // (options.clearance + partset.profile["h"]))
    assert result.report["lower_bound"]["strip_lp"] >= math.ceil(rows / per_sheet)
    assert result.report["lower_bound"]["strip_lp"] >= 4
