"""Unrolled strips against closed forms computed here, not by fabline: arc lengths on Enneper and catenoid
lines, a great circle on a sphere, offset-curve crossings in a polar grid, and the helix of a twisted strip.

`network_of` and `polar_grid` (tests/networks.py) build small test networks from explicit curves.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import quad

from fabline.model import Network
from networks import network_of, polar_grid
from fabline.unroll import PartSet, UnrollOptions, flatten_contour, unroll_network

PER_METRE = 0.05e-3  # 0.05 mm per metre


def strip_positions(partset: PartSet, strip: str) -> tuple[dict[str, float], list[tuple[float, str]]]:
    """Node positions and slot centres of one strip along its own arc length, gathered from all its segments."""
    nodes, slots = {}, []
    for part in partset.parts:
        if part.meta.get("strip") != strip:
            continue
        start = part.meta["strip_range_mm"][0]
        for node in part.nodes:
            nodes[node["id"]] = start + node["s"]
        for slot in part.slots:
            slots.append((start + float(np.mean(slot.outline[:4, 0])), slot.node))
    return nodes, sorted(slots)


def options(**kw) -> UnrollOptions:
    return UnrollOptions(**{"hardware": False, **kw})


@pytest.fixture(scope="module")
def enneper_single(enneper):
    return unroll_network(enneper, options(pair_spacing=0.0))


def enneper_speed(u, v, c):
    return 6 * c * (1 + u * u + v * v)  # ds = 6 c (1 + u^2 + v^2) du along an asymptotic u-line (domain.md 3)


def test_enneper_node_marks_at_the_analytic_arc_lengths(enneper, enneper_single):
    c = enneper.meta["scale_m_per_unit"] * 1000.0
    grid_a, grid_b = enneper.meta["grid"]["a"], enneper.meta["grid"]["b"]
    checked = 0
    for lam in enneper.lamellas:
        marks, _ = strip_positions(enneper_single, lam.id)
        assert set(marks) == set(lam.nodes)
        params = [tuple(int(x) for x in nid[1:].split("-")) for nid in lam.nodes]
        first = lam.nodes[0]
        for nid, (i, j) in zip(lam.nodes[1:], params[1:]):
            i0, j0 = params[0]
            if lam.family == "A":
                exact, _ = quad(lambda u: enneper_speed(u, grid_b[j0], c), grid_a[i0], grid_a[i], epsabs=1e-9, limit=200)
            else:
                exact, _ = quad(lambda v: enneper_speed(grid_a[i0], v, c), grid_b[j0], grid_b[j], epsabs=1e-9, limit=200)
            measured = marks[nid] - marks[first]
            assert abs(measured - exact) <= PER_METRE * exact, (lam.id, nid, measured, exact)
            checked += 1
    assert checked > 400


def test_asymptotic_lamellas_unroll_straight(enneper_single):
    h = 100.0
    strips = [p for p in enneper_single.parts if p.kind in ("strip", "curved-strip")]
    assert strips and all(p.kind == "strip" for p in strips)
    for part in strips:
        outline = flatten_contour(part.outline)
        for sign in (-1.0, 1.0):
            edge = outline[sign * outline[:, 1] > h / 2.0 - 10.0]
            assert np.abs(edge[:, 1] - sign * h / 2.0).max() < 0.01, part.id
        assert outline[:, 0].min() == pytest.approx(0.0, abs=1e-9)
        assert np.abs(outline[:, 1]).max() <= h / 2.0 + 0.01


def test_catenoid_node_marks_at_the_analytic_arc_lengths(catenoid):
    partset = unroll_network(catenoid, options(pair_spacing=0.0))
    a = catenoid.meta["waist_m"] * 1000.0
    for lam in catenoid.lamellas:
        marks, _ = strip_positions(partset, lam.id)
        z = np.array([catenoid.nodes[n].xyz[2] * 1000.0 for n in lam.nodes])
        exact = np.abs(np.sqrt(2) * a * (np.sinh(z / a) - np.sinh(z[0] / a)))  # s = sqrt(2) a sinh(z/a)
        measured = np.array([marks[n] - marks[lam.nodes[0]] for n in lam.nodes])
        assert np.all(np.abs(measured - exact) <= PER_METRE * np.maximum(exact, 1.0)), lam.id


def great_circle(radius: float, angle: float, node_step: float) -> Network:
    count = int(np.ceil(angle * radius / 20.0))
    phi = np.linspace(0.0, angle, count + 1)
    points = radius * np.column_stack([np.cos(phi), np.sin(phi), np.zeros_like(phi)])
    normals = points / radius  # radial: k_n = 1/R, k_g = 0
    node_phi = np.arange(0.0, angle + 1e-9, node_step / radius)
    index = [int(np.argmin(np.abs(phi - p))) for p in node_phi]
    return network_of([("A-000", "A", points, normals, index)], "sphere")


def kasa_radius(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares circle centre of points (algebraic fit) and each point's distance from it."""
    a = np.column_stack([2 * points, np.ones(len(points))])
    b = (points ** 2).sum(axis=1)
    cx, cy, _ = np.linalg.lstsq(a, b, rcond=None)[0]
    return np.array([cx, cy]), np.hypot(points[:, 0] - cx, points[:, 1] - cy)


def test_great_circle_unrolls_to_an_arc_of_the_sphere_radius():
    radius, h = 5000.0, 100.0
    network = great_circle(radius, 2.0, 350.0)
    partset = unroll_network(network, options(pair_spacing=0.0))
    parts = [p for p in partset.parts if p.lamella == "A-000"]
    assert len(parts) >= 3 and all(p.kind == "curved-strip" for p in parts)
    for part in parts:
        outline = flatten_contour(part.outline, 0.001)
        turn = int(np.argmax(outline[:, 0]))          # counter-clockwise: bottom edge first, then the top edge
        rings = np.sort([kasa_radius(edge)[1].mean() for edge in (outline[1:turn - 1], outline[turn + 2:-2])])
        assert abs(rings.mean() - radius) <= 1e-3 * radius, part.id
        assert rings[1] - rings[0] == pytest.approx(h, abs=0.5)
        assert part.meta["in_plane_radius_mm"] == pytest.approx(radius, rel=1e-3)
    marks, _ = strip_positions(partset, "A-000")
    lam = network.lamellas[0]
    exact = radius * np.array([np.arctan2(network.nodes[n].xyz[1], network.nodes[n].xyz[0]) for n in lam.nodes])
    measured = np.array([marks[n] for n in lam.nodes])
    assert np.abs((measured - measured[0]) - exact).max() <= PER_METRE * exact[-1]


def test_pair_slots_at_the_exact_crossings_of_offset_curves():
    radii, angles, half = 3000.0 + 350.0 * np.arange(5), 0.1 * np.arange(9), 12.5
    network = polar_grid(radii, angles)
    partset = unroll_network(network, options())
    rows = {row["strip"]: row for row in partset.report["strips"]}
    for i, r in enumerate(radii):
        for side, rho in (("L", r - half), ("R", r + half)):  # u = n x t points inwards on a ccw circle
            _, slots = strip_positions(partset, f"A-{i:03d}-{side}")
            # slots where the circle of radius rho meets the lines d/2 beside each radial line
            exact = np.sort(np.concatenate([rho * (angles + np.arcsin(e / rho)) for e in (half, -half)]))
            measured = np.array([x for x, _ in slots])
            assert len(measured) == len(exact)
            assert np.abs((measured - measured[0]) - (exact - exact[0])).max() < 0.01, (i, side)
            # node distances change by (d/2) times the integral of k_g = angle / r * r
            expected = -half * angles[-1] if side == "L" else half * angles[-1]
            assert rows[f"A-{i:03d}-{side}"]["node_distance_change_total_mm"] == pytest.approx(expected, abs=0.01)
    for j in range(len(angles)):
        for side, e in (("L", half), ("R", -half)):
            _, slots = strip_positions(partset, f"B-{j:03d}-{side}")
            rho = np.sort(np.concatenate([radii - half, radii + half]))
            exact = np.sqrt(rho ** 2 - e ** 2)
            measured = np.array([x for x, _ in slots])
            assert np.abs((measured - measured[0]) - (exact - exact[0])).max() < 0.01, (j, side)


def twisted_strip(kappa: float, length: float, node_step: float) -> Network:
    """A straight lamella whose normals turn about it at a constant rate: tau_g = kappa, k_g = k_n = 0."""
    s = np.linspace(0.0, length, int(length / 10.0) + 1)
    points = np.column_stack([s, np.zeros_like(s), np.zeros_like(s)])
    normals = np.column_stack([np.zeros_like(s), -np.sin(kappa * s), np.cos(kappa * s)])
    index = [int(k) for k in np.round(np.arange(0.0, length + 1e-9, node_step) / 10.0)]
    return network_of([("A-000", "A", points, normals, index)], "twist")


def test_twist_compensation_and_helix_edge_lengths():
    kappa, length, h = 1.0e-3, 3000.0, 100.0
    network = twisted_strip(kappa, length, 300.0)
    plain = unroll_network(network, options(pair_spacing=0.0))
    compensated = unroll_network(network, options(pair_spacing=0.0, compensate_twist=True))
    plain_marks, _ = strip_positions(plain, "A-000")
    comp_marks, _ = strip_positions(compensated, "A-000")
    ids = sorted(plain_marks, key=plain_marks.get)
    plain_s = np.array([plain_marks[n] for n in ids])
    comp_s = np.array([comp_marks[n] for n in ids])
    assert np.allclose(plain_s - plain_s[0], np.arange(len(ids)) * 300.0, atol=1e-3)
    centre_strain = -0.5 * (h * h / 12.0) * kappa ** 2          # eps_H,min (6.9)
    assert np.allclose(comp_s - comp_s[0], np.arange(len(ids)) * 300.0 / (1.0 + centre_strain), atol=1e-3)
    row = plain.report["lamellas"][0]
    helix = length * (np.sqrt(1.0 + (kappa * h / 2.0) ** 2) - 1.0)  # domain.md (6.7) at r = h/2
    assert row["helix_top_edge_extension_mm"] == pytest.approx(helix, abs=2e-3)
    assert row["helix_bottom_edge_extension_mm"] == pytest.approx(helix, abs=2e-3)
    assert compensated.report["strips"][0]["twist_compensation_mm"] == pytest.approx(-centre_strain * length, rel=1e-3)


def test_straight_outline_shortcut_equals_the_general_construction():
    from fabline.unroll.flat import FlatCentreline, Notches, strip_outline

    centre = FlatCentreline.build(np.array([10.0, 500.0]), np.zeros(2), 0.01)
    top, bottom = Notches(np.array([100.0, 300.0]), 3.0, 51.0), Notches(np.array([200.0]), 3.0, 51.0)
    fast = strip_outline(centre, 10.0, 500.0, 100.0, top, bottom)
    centre.straight = False  # the general (curved) construction on the same straight centreline
    general = strip_outline(centre, 10.0, 500.0, 100.0, top, bottom)
    assert fast.shape == general.shape == (17, 3)
    assert np.array_equal(fast, general)


def test_straightness_follows_the_integrated_centreline_not_the_largest_curvature():
    """Constant curvature k over L strays k L^2 / 8 from its chord (closed form); curvature noise of alternating
    sign, large enough to fail the quick k_max L^2 / 8 bound, never adds up to a bend and stays a rectangle."""
    from fabline.unroll.flat import FlatCentreline, stays_straight

    x = np.linspace(0.0, 3000.0, 301)
    bend = 8.0 * 0.01 / 3000.0 ** 2                   # sagitta of exactly the 0.01 mm tolerance
    noise = 1e-8 * np.where(np.arange(301) % 2, 1.0, -1.0)
    rows = np.array([np.full(301, 0.9 * bend), np.full(301, 1.1 * bend), noise, noise + 1.1 * bend])
    assert 1e-8 * 3000.0 ** 2 / 8.0 > 0.01            # the quick bound alone would call the noise curved
    assert stays_straight(np.tile(x, (4, 1)), rows, 0.01).tolist() == [True, False, True, False]
    for row, straight in zip(rows, (True, False, True, False)):
        centre = FlatCentreline.build(x, row, 0.01)
        assert centre.straight == straight
        if not straight:
            assert np.abs(centre.at(np.array([1500.0]))[0][0, 1]) == pytest.approx(1.1 * 0.01, rel=1e-3)
    # a padded row (last station repeated) decides as the unpadded one
    padded = np.concatenate([x, [x[-1]] * 5]), np.concatenate([noise, [noise[-1]] * 5])
    assert stays_straight(padded[0][None], padded[1][None], 0.01)[0]


def test_a_model_read_from_a_file_unrolls_its_asymptotic_strips_straight_in_one_batch(enneper):
    """Coordinates and normals rounded to 1e-6 (1 um, as CAD writes them) leave k_n noise the quick bound calls curved:
    every asymptotic segment must still be found straight by the batch test, agreeing with the one-by-one construction."""
    from fabline.geometry import analyse
    from fabline.model.network import Lamella, Network
    from fabline.unroll.batch import straight_flags
    from fabline.unroll.pieces import segment_part
    from fabline.unroll.seams import split_strip
    from fabline.unroll.stations import strip_stations

    rounded = [Lamella(lam.id, lam.family, lam.nodes, np.round(lam.curve, 6), np.round(lam.normals, 6))
               for lam in enneper.lamellas]
    opts = UnrollOptions()
    segments = [s for strip in strip_stations(analyse(Network("m", enneper.nodes, rounded)), opts)
                for s in split_strip(strip, opts, 20.0)]
    noisy = max(np.abs(s.strip.geometry.k_n).max() * (s.end - s.start) ** 2 / 8.0 for s in segments)
    assert noisy > opts.straight_tolerance             # the quick bound fails on the read-back model
    flags = straight_flags(segments, opts)
    assert flags.all()
    assert all(segment_part(s, opts).kind == "strip" for s in segments[::7])
