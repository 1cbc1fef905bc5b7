"""Edge members (issue 17, item 11): the boundary curves as flat curved bars, checked against closed forms.

The bar's in-plane curvature is the boundary's geodesic curvature k_g, computed here from the exact
parametrisations (catenoid parallel circles: k_g = tanh(z/c) / (c cosh(z/c)); an Enneper circle r = const in
the parameter plane: k_g = c''.(n x t) / |c'|^2), its length the boundary's arc length, its holes at the nodes.
"""

from __future__ import annotations

import math

import ezdxf
import numpy as np
import pytest
from scipy.integrate import cumulative_trapezoid, quad

from fabline.errors import FablineError
from fabline.jobs.bom import bill_of_materials
from fabline.mechanics.materials import Profile, get_material
from fabline.model import Lamella, Network, Node
from fabline.nest.layout import Nesting
from fabline.nest.validate import validate_nesting
from fabline.unroll import PartSet, UnrollOptions, flatten_contour, load_parts, unroll_network
from fabline.unroll.edges import BoundaryCurve, boundary_chains, boundary_curves, curve_parts, edge_strips

H, T = 100.0, 1.5
LAYER_OFFSET = {"T": H / 2 + T + T / 2, "B": -(H / 2 + T + T / 2)}  # along the normal: on the node's washer
BOLT = 8.5


def node_holes(part) -> list[np.ndarray]:
    """Centres of the part's bolt holes (the 8.5 mm ones, not the seam screws), in the part's frame."""
    centres = []
    for hole in part.holes:
        points = flatten_contour(hole)[:, :2]
        if abs(np.ptp(points[:, 0]) - BOLT) < 0.05:
            centres.append((points.max(axis=0) + points.min(axis=0)) / 2.0)
    return centres


def arc_radii(contour: np.ndarray) -> np.ndarray:
    """Radius of every arc segment (nonzero bulge) of a closed contour."""
    contour = np.asarray(contour)
    if contour.shape[1] < 3:
        return np.zeros(0)
    chords = np.linalg.norm(np.diff(contour[:, :2], axis=0), axis=1)
    bulge = contour[:-1, 2]
    arcs = np.abs(bulge) > 1e-9
    return chords[arcs] / (2.0 * np.sin(2.0 * np.arctan(np.abs(bulge[arcs]))))


# ---- catenoid: its boundary circles --------------------------------------------------------------------------


@pytest.fixture(scope="module")
def catenoid_edges(catenoid):
    return unroll_network(catenoid, UnrollOptions(edge_members=True, hardware=False))


def test_catenoid_boundaries_are_its_two_end_circles_through_every_lamella_end(catenoid, catenoid_edges):
    chains = boundary_chains(catenoid)
    ends = {lam.nodes[0] for lam in catenoid.lamellas} | {lam.nodes[-1] for lam in catenoid.lamellas}
    assert [closed for _, closed in chains] == [True, True]
    assert {nid for chain, _ in chains for nid in chain} == ends
    for chain, _ in chains:
        z = [catenoid.nodes[nid].xyz[2] for nid in chain]
        assert np.ptp(z) < 1e-9 and chain[0] == chain[-1] and len(set(chain)) == len(chain) - 1
        angles = np.unwrap([math.atan2(*catenoid.nodes[nid].xyz[1::-1]) for nid in chain])
        assert np.all(np.diff(angles) > 0) or np.all(np.diff(angles) < 0)          # in order round the circle


def test_catenoid_edge_bars_are_circles_of_the_geodesic_curvature_with_holes_at_the_nodes(catenoid, catenoid_edges):
    c = catenoid.meta["waist_m"] * 1000.0
    edge_parts = [p for p in catenoid_edges.parts if p.meta.get("member") == "edge"]
    assert {p.meta["strip"] for p in edge_parts} == {"E1-T", "E1-B", "E2-T", "E2-B"}
    for strip in ("E1-T", "E1-B", "E2-T", "E2-B"):
        parts = sorted((p for p in edge_parts if p.meta["strip"] == strip), key=lambda p: p.meta["segment"])
        first = next(n["id"] for n in parts[0].nodes)
        node = catenoid.nodes[first]
        z = node.xyz[2] * 1000.0
        rho = c * math.cosh(z / c)
        k_g = math.tanh(abs(z) / c) / (c * math.cosh(z / c))             # closed form, 1/mm
        rho_o = np.linalg.norm((node.xyz * 1000.0 + LAYER_OFFSET[strip[-1]] * node.normal)[:2])
        kappa = k_g * rho / rho_o                                           # the offset circle's, on its parallel surface
        radius = 1.0 / kappa
        step = rho_o * 2.0 * math.pi / 16                                   # node to node along the bar
        chord = 2.0 * radius * math.sin(step / (2.0 * radius))
        holes = 0
        for part in parts:
            assert part.kind == "curved-strip" and part.lamella == strip[:2]
            radii = arc_radii(part.outline)
            assert radii.size and np.all(np.minimum(abs(radii - radius - H / 2), abs(radii - radius + H / 2)) < 2e-4 * radius)
            centres = node_holes(part)
            holes += len(centres)
            gaps = np.linalg.norm(np.diff(np.array(centres), axis=0), axis=1)
            assert np.allclose(gaps, chord, atol=0.1), (strip, gaps, chord)
        assert holes == 17                                                  # 16 ends, the first again where the ends lap
        row = next(r for r in catenoid_edges.report["edges"]["bars"] if r["strip"] == strip)
        expected = 2.0 * math.pi * rho_o + H                               # the loop and a lap of h/2 past each end
        assert abs(row["length_mm"] - expected) < 0.05e-3 * expected


def test_catenoid_edge_check_bends_by_the_normal_curvature_and_does_not_twist(catenoid, catenoid_edges):
    c = catenoid.meta["waist_m"] * 1000.0
    material = get_material("steel-s235")
    for row in catenoid_edges.report["edges"]["members"]:
        z = catenoid.nodes[row["nodes"][0]].xyz[2] * 1000.0
        k_n = 1.0 / (c * math.cosh(z / c) ** 2)                            # a principal curvature of the catenoid
        assert row["min_radius_mm"] == pytest.approx(1.0 / k_n, rel=1e-3)
        assert row["max_bending_stress"] == pytest.approx(material.E * T * k_n / 2.0, rel=1e-3)
        assert row["max_twist_rad_per_m"] < 1e-6
        assert row["length_mm"] == pytest.approx(2.0 * math.pi * c * math.cosh(z / c), rel=1e-6)


# ---- Enneper: a circle r = const in the parameter plane ----------------------------------------------------------


SCALE = 1000.0 / (3.0 * 1.1)   # mm per Enneper unit at k_max 1.1 /m
R, NODES, PER = 1.0, 24, 40


def enneper_xyz(u, v):
    """Position, first and second partials of the Enneper surface (domain.md 3), mm."""
    x = SCALE * np.stack([6 * u * u * v - 2 * v ** 3 - 6 * v, 6 * u * v * v - 2 * u ** 3 - 6 * u, -12 * u * v], -1)
    xu = SCALE * np.stack([12 * u * v, 6 * v * v - 6 * u * u - 6, -12 * v], -1)
    xv = SCALE * np.stack([6 * u * u - 6 * v * v - 6, 12 * u * v, -12 * u], -1)
    xuu = SCALE * np.stack([12 * v, -12 * u, 0 * u], -1)
    xuv = SCALE * np.stack([12 * u, 12 * v, -12 + 0 * u], -1)
    xvv = SCALE * np.stack([-12 * v, 12 * u, 0 * u], -1)
    return x, xu, xv, xuu, xuv, xvv


def circle(phi, offset=0.0):
    """The Enneper circle at angle phi: point, c'(phi), normal, k_g (1/mm), the speed of the curve p = c + o n
    `offset` mm along the normal and p's own geodesic curvature on the parallel surface (same normal n),
    p''.(n x p') / |p'|^3, from the closed form (the normal's derivatives by central differences)."""
    u, v = R * np.cos(phi), R * np.sin(phi)
    du, dv = -v, u
    x, xu, xv, xuu, xuv, xvv = enneper_xyz(u, v)
    d1 = xu * du[:, None] + xv * dv[:, None]
    d2 = xuu * (du * du)[:, None] + 2 * xuv * (du * dv)[:, None] + xvv * (dv * dv)[:, None] - xu * u[:, None] - xv * v[:, None]
    n = np.cross(xu, xv)
    n /= np.linalg.norm(n, axis=1)[:, None]
    speed = np.linalg.norm(d1, axis=1)
    t = d1 / speed[:, None]
    k_g = np.einsum("ij,ij->i", d2, np.cross(n, t)) / speed ** 2

    def normal(p):
        _, a, b, *_ = enneper_xyz(R * np.cos(p), R * np.sin(p))
        m = np.cross(a, b)
        return m / np.linalg.norm(m, axis=1)[:, None]

    step = 1e-4
    dn = (normal(phi + step) - normal(phi - step)) / (2 * step)
    ddn = (normal(phi + step) - 2 * n + normal(phi - step)) / step ** 2
    p1, p2 = d1 + offset * dn, d2 + offset * ddn
    speed_o = np.linalg.norm(p1, axis=1)
    k_g_o = np.einsum("ij,ij->i", p2, np.cross(n, p1)) / speed_o ** 3
    return x, d1, n, k_g, speed_o, k_g_o


@pytest.fixture(scope="module")
def enneper_circle():
    """The circle as a closed boundary curve: nodes every 15 degrees, samples between, one interval more each side."""
    step = 2 * np.pi / NODES
    phi = np.linspace(-step, 2 * np.pi + step, (NODES + 2) * PER + 1)
    x, d1, n, *_ = circle(phi)
    rows = np.arange(PER, PER * (NODES + 1) + 1, PER)
    ids = [f"C{k:02d}" for k in range(NODES)] + ["C00"]
    curve = BoundaryCurve("E1", ids, True, x, n, d1 / np.linalg.norm(d1, axis=1)[:, None], rows)
    return curve, phi


def test_enneper_circle_bar_curvature_is_the_geodesic_curvature_and_its_length_the_arc_length(enneper_circle):
    curve, phi = enneper_circle
    strips, _ = edge_strips([curve], LAYER_OFFSET["T"])
    inside = slice(curve.node_rows[0], curve.node_rows[-1] + 1)
    for strip in strips:
        offset = LAYER_OFFSET[strip.side]
        _, d1, _, k_g, speed_o, expected = circle(phi[inside], offset)   # the offset curve's own k_g
        assert np.abs(expected).max() > 1e-4                                # a real curve: radius under 10 m
        assert np.allclose(strip.geometry.k_n[inside], expected, rtol=2e-3, atol=2e-7), strip.side
        # not the boundary's turning over the bar's length: that leaves out the change of skew angle
        old = k_g * np.linalg.norm(d1, axis=1) / speed_o
        assert np.abs(old - expected).max() > 10 * np.abs(strip.geometry.k_n[inside] - expected).max()
        arcs = [quad(lambda p: circle(np.array([p]), offset)[4][0], a, b, epsabs=1e-6)[0]
                for a, b in zip(phi[curve.node_rows[:-1]], phi[curve.node_rows[1:]])]
        gaps = np.diff(strip.node_x)
        assert np.all(np.abs(gaps - arcs) < 0.05e-3 * np.array(arcs) + 1e-3), (gaps - arcs)


def test_enneper_circle_bar_holes_lie_at_the_nodes_arc_length_positions(enneper_circle):
    curve, phi = enneper_circle
    parts, report = curve_parts([curve], UnrollOptions(), BOLT)
    assert report["members"][0]["closed"] and len(report["bars"]) == 2
    step = 2 * np.pi / NODES
    fine = np.linspace(-step, 2 * np.pi + step, 200001)
    for side in ("T", "B"):
        # the flat bar from the closed form: turning angle and position integrated along its own arc length
        _, _, _, _, speed_o, k_g_o = circle(fine, LAYER_OFFSET[side])
        s = cumulative_trapezoid(speed_o, fine, initial=0.0)
        theta = cumulative_trapezoid(k_g_o * speed_o, fine, initial=0.0)
        flat = np.column_stack([cumulative_trapezoid(np.cos(theta) * speed_o, fine, initial=0.0),
                                cumulative_trapezoid(np.sin(theta) * speed_o, fine, initial=0.0)])
        at = np.interp(step * np.arange(NODES + 1), fine, s) - np.interp(0.0, fine, s)  # nodes along the bar
        s0 = np.interp(0.0, fine, s)
        mine = [p for p in parts if p.meta["strip"] == f"E1-{side}"]
        assert all(p.meta["length_mm"] <= UnrollOptions().usable_length for p in mine)
        count = 0
        mine.sort(key=lambda p: p.meta["segment"])
        start = mine[0].meta["strip_range_mm"][0] + mine[0].nodes[0]["s"]    # the strip's x of node C00
        for part in mine:
            centres = node_holes(part)
            assert len(centres) == len(part.nodes)
            count += len(centres)
            along = [part.meta["strip_range_mm"][0] + n["s"] for n in part.nodes]
            for (a, b), (xa, xb) in zip(zip(centres[:-1], centres[1:]), zip(along[:-1], along[1:])):
                pa = np.array([np.interp(xa - start + s0, s, flat[:, i]) for i in (0, 1)])
                pb = np.array([np.interp(xb - start + s0, s, flat[:, i]) for i in (0, 1)])
                assert abs(np.linalg.norm(b - a) - np.linalg.norm(pb - pa)) < 0.1
        assert count == NODES + 1 and len(mine) > 1                       # seams lie between nodes; the lap adds one
        xs = sorted({round(p.meta["strip_range_mm"][0] + n["s"], 3) for p in mine for n in p.nodes})
        assert np.allclose(np.array(xs) - start, at, atol=0.1)


# ---- the pavilion: import round trip, nest, DXF, BOM ------------------------------------------------------------


def test_an_imported_network_gets_the_same_boundary_chains_as_the_designs_nodes(tmp_path, enneper):
    from fabline.model.designs import enneper_mesh
    from fabline.model.importers import import_model
    from fabline.model.writers import write_obj

    write_obj(enneper, tmp_path / "pavilion.obj", mesh=enneper_mesh(enneper))
    imported, _ = import_model(tmp_path / "pavilion.obj", units="m")
    assert "design" not in imported.meta                                     # read as any CAD network
    designed, read = boundary_chains(enneper), boundary_chains(imported)
    curves = boundary_curves(imported)                                       # a spline through the nodes, normals from them
    assert all(np.allclose(curve.points[curve.node_rows], [imported.in_mm().nodes[n].xyz for n in curve.node_ids])
               for curve in curves)
    assert len(read) == len(designed) and sum(len(c) for c, _ in designed) > 60

    def key(chain):  # the same nodes in the same order, up to where a loop starts and its direction
        ring = chain[:-1] if chain[0] == chain[-1] else chain
        return min(tuple(ring[k:] + ring[:k]) for ring in (ring, ring[::-1]) for k in range(len(ring)))

    assert sorted(key(c) for c, _ in read) == sorted(key(c) for c, _ in designed)


@pytest.fixture(scope="module")
def pavilion_edges(enneper):
    partset = unroll_network(enneper, UnrollOptions(edge_members=True, hardware=False))
    edges = [p for p in partset.parts if p.meta.get("member") == "edge"]
    return PartSet(edges, partset.profile, partset.material, "pavilion", partset.report)


def polyline_distance(points: np.ndarray, line: np.ndarray) -> np.ndarray:
    """Each point's distance to the polyline `line` (to its segments, not only its vertices)."""
    a, d = line[:-1], np.diff(line, axis=0)
    out = []
    for p in points:
        t = np.clip(np.einsum("ij,ij->i", p - a, d) / np.einsum("ij,ij->i", d, d), 0.0, 1.0)
        out.append(np.linalg.norm(a + t[:, None] * d - p, axis=1).min())
    return np.array(out)


def enneper_parameters(points_mm: np.ndarray, scale_mm: float) -> np.ndarray:
    """The Enneper parameters (u, v) of surface points (mm), by Newton steps on the closed form from (0, 0)
    continued outwards: the inverse the tests judge the edge by, not the code's."""
    from scipy.optimize import least_squares

    out = []
    for p in points_mm / scale_mm:
        guess = np.array([-p[1], -p[0]]) / 6.0                  # x ~ -6 v, y ~ -6 u near the centre
        fit = least_squares(lambda q: np.array([6 * q[0] ** 2 * q[1] - 2 * q[1] ** 3 - 6 * q[1],
                                                6 * q[0] * q[1] ** 2 - 2 * q[0] ** 3 - 6 * q[0],
                                                -12 * q[0] * q[1]]) - p, guess, xtol=1e-15, ftol=1e-15)
        out.append(fit.x)
    return np.array(out)


def test_pavilion_lamellas_run_on_to_the_domain_ellipse_where_the_edge_bars_hold_them(enneper, pavilion_edges):
    from fabline.unroll.edges import extend_to_edge

    scale = enneper.meta["scale_m_per_unit"] * 1000.0
    hu, hv = enneper.meta["domain"]["u"], enneper.meta["domain"]["v"]
    extended = extend_to_edge(enneper, UnrollOptions()).in_mm()
    curve = boundary_curves(enneper)[0]
    at = dict(zip(curve.node_ids, curve.points[curve.node_rows]))
    assert curve.closed and len(boundary_curves(enneper)) == 1 and len(at) == 2 * len(enneper.lamellas)
    ends = []
    for lam, original in zip(extended.lamellas, enneper.lamellas):
        assert lam.nodes == original.nodes                                      # the same nodes, longer lamellas
        for mark, end in ((1, lam.curve[0]), (2, lam.curve[-1])):
            assert np.linalg.norm(at[f"{lam.id}.{mark}"] - end) < 1e-6      # the bar's hole is the lamella's end
            ends.append(end)
    uv = enneper_parameters(np.array(ends), scale)
    rho = np.hypot(uv[:, 0] / hu, uv[:, 1] / hv)
    assert np.ptp(rho) < 1e-7 and 1.0 <= rho[0] < 1.01                        # on the domain's ellipse, scaled
    # each end still on its grid line: A lamellas keep v (or u, whichever their nodes share), B the other
    for lam, (first, last) in zip(extended.lamellas, uv.reshape(-1, 2, 2)):
        nodes = enneper_parameters(np.array([extended.nodes[n].xyz for n in lam.nodes[:2]]), scale)
        fixed = int(np.argmin(np.abs(nodes[1] - nodes[0])))
        assert abs(first[fixed] - nodes[0, fixed]) < 1e-7 and abs(last[fixed] - nodes[0, fixed]) < 1e-7
    # no node lies under a bar or within 15 mm of its edge: every bar hole is a lamella's, every node's bolt clear
    xyz = np.array([n.xyz for n in extended.nodes.values()])
    assert polyline_distance(xyz, curve.points).min() >= H / 2 + 15.0 - 0.05
    usable = UnrollOptions().usable_length
    assert {n["id"] for p in pavilion_edges.parts for n in p.nodes} == set(at)
    for part in pavilion_edges.parts:
        assert len(node_holes(part)) == len(part.nodes)
        assert part.meta["length_mm"] <= usable
        points = flatten_contour(part.outline)[:, :2]
        assert np.ptp(points[:, 0]) <= usable + 1e-6
    assert {p.meta["strip"][-1] for p in pavilion_edges.parts} == {"T", "B"}


def test_pavilion_edge_bars_turn_one_way_as_the_closed_form_edge_does(enneper, pavilion_edges):
    scale = enneper.meta["scale_m_per_unit"] * 1000.0
    hu, hv = enneper.meta["domain"]["u"], enneper.meta["domain"]["v"]
    curve = boundary_curves(enneper)[0]
    rho = np.hypot(*(enneper_parameters(curve.points[curve.node_rows[:1]], scale)[0] / [hu, hv]))
    strips, _ = edge_strips([curve], LAYER_OFFSET["T"])
    inside = slice(curve.node_rows[0], curve.node_rows[-1] + 1)
    for strip in strips:
        k = strip.geometry.k_n[inside]
        assert np.all(np.sign(k) == np.sign(k[0])), strip.side               # no change of sign round the loop
    # the closed form: the ellipse u = rho hu cos p, v = rho hv sin p, p''s geodesic curvature on the parallel surface
    phi = np.linspace(0.0, 2 * np.pi, 3601)
    u, v = rho * hu * np.cos(phi), rho * hv * np.sin(phi)
    x, xu, xv, xuu, xuv, xvv = enneper_xyz(u, v)
    scale_fix = scale / SCALE                                                  # the fixture's k_max is not the test's
    du, dv = -rho * hu * np.sin(phi), rho * hv * np.cos(phi)
    d1 = (xu * du[:, None] + xv * dv[:, None]) * scale_fix
    d2 = (xuu * (du * du)[:, None] + 2 * xuv * (du * dv)[:, None] + xvv * (dv * dv)[:, None]
          - xu * (rho * hu * np.cos(phi))[:, None] - xv * (rho * hv * np.sin(phi))[:, None]) * scale_fix
    n = np.cross(xu, xv)
    n /= np.linalg.norm(n, axis=1)[:, None]
    k_g = np.einsum("ij,ij->i", d2, np.cross(n, d1)) / np.linalg.norm(d1, axis=1) ** 3
    assert np.all(np.sign(k_g) == np.sign(k_g[0]))
    centre = edge_strips([curve], 0.0)[0][0].geometry.k_n[inside]
    assert np.abs(centre).max() == pytest.approx(np.abs(k_g).max(), rel=2e-3)
    assert np.abs(centre).min() == pytest.approx(np.abs(k_g).min(), rel=2e-2, abs=2e-6)


def test_pavilion_edge_members_nest_without_overlap_export_a_clean_dxf_and_count_in_the_bom(cli, tmp_path, enneper,
                                                                                          pavilion_edges):
    from fabline.unroll import save_parts

    save_parts(pavilion_edges, tmp_path / "parts.json")
    code, out, err = cli("nest", tmp_path / "parts.json", "-o", tmp_path / "nesting.json", "--sheet", "4000x2000",
                         "--time-limit", "2")
    assert code == 0, err
    from fabline.nest import load_nesting

    nesting = load_nesting(tmp_path / "nesting.json")
    partset = load_parts(tmp_path / "parts.json")
    assert validate_nesting(nesting, partset) == []
    code, out, err = cli("export", tmp_path / "nesting.json", "--dxf", tmp_path / "dxf")
    assert code == 0, err
    files = sorted((tmp_path / "dxf").glob("*.dxf"))
    assert files
    for path in files:
        assert not ezdxf.readfile(path).audit().has_errors
    bom = bill_of_materials(nesting, partset, get_material("stainless"))
    rows = {row["item"]: row for row in bom["hardware"]}
    assert rows["edge bolt with nut and spacer tube"]["count"] == 2 * len(enneper.lamellas)   # one per lamella end
    area = sum(p.meta["length_mm"] for p in partset.parts) * H               # less holes, plus the curved ends
    assert bom["edge_members"]["bars"] == len(partset.parts)
    assert bom["edge_members"]["mass_kg"] == pytest.approx(area * T * 7900e-9, rel=0.02)


def test_edge_members_are_off_by_default_and_leave_the_lamella_parts_alone(enneper, pavilion_edges):
    plain = unroll_network(enneper, UnrollOptions(hardware=False))
    assert not any(p.meta.get("member") for p in plain.parts) and "edges" not in plain.report
    assert plain.report["summary"]["strips"] == 116


# ---- the structural check and bad input ------------------------------------------------------------------------


def test_helicoid_end_rulings_twist_by_the_closed_form_and_warn_over_the_limit(helicoid):
    partset = unroll_network(helicoid, UnrollOptions(edge_members=True, hardware=False))
    edges = partset.report["edges"]
    p = helicoid.meta["pitch_m"] / (2 * math.pi)
    material = get_material("steel-s235")
    rulings = [row for row in edges["members"] if len(row["nodes"]) == 17]
    assert len(rulings) == 2
    for row in rulings:                                 # a ruling's geodesic torsion p / (p^2 + rho^2) is 1/p on the axis
        assert row["max_twist_rad_per_m"] == pytest.approx(1.0 / p, rel=1e-3)
        assert row["max_shear_stress"] == pytest.approx(material.G * T * (1e-3 / p), rel=1e-3)
        assert row["max_in_plane_curvature_per_m"] < 1e-6   # straight in the sheet
    assert edges["warnings"] and all(w.startswith("edge member E") for w in edges["warnings"])
    assert set(edges["warnings"]) <= set(partset.report["warnings"])


def test_an_end_with_no_boundary_is_refused_naming_lamella_and_node():
    x = np.linspace(0.0, 2000.0, 9)
    line = np.column_stack([x, np.zeros(9), np.zeros(9)])
    cross = np.array([[1000.0, -250.0, 0.0], [1000.0, 0.0, 0.0], [1000.0, 250.0, 0.0]])
    up = np.tile([0.0, 0.0, 1.0], (9, 1))
    nodes = {f"a{k}": Node(f"a{k}", line[k], up[k]) for k in range(9)}
    nodes.update({"b0": Node("b0", cross[0], up[0]), "b1": Node("b1", cross[2], up[0])})
    network = Network("mm", nodes, [Lamella("A-000", "A", [f"a{k}" for k in range(9)], line, up),
                                    Lamella("B-000", "B", ["b0", "a4", "b1"], cross, up[:3])])
    with pytest.raises(FablineError) as err:
        unroll_network(network, UnrollOptions(edge_members=True, pair_spacing=0.0, hardware=False))
    message = str(err.value)
    assert "lamella A-000" in message and "end node a0" in message and "\n" not in message


def test_the_command_line_and_the_job_file_switch_edge_members(cli, tmp_path, catenoid):
    from fabline.jobs.jobfile import load_job_file
    from fabline.model import save_network

    save_network(catenoid, tmp_path / "cat.json")
    code, out, err = cli("unroll", tmp_path / "cat.json", "-o", tmp_path / "parts.json", "--edge-members",
                         "--edge-width", "80", "--no-hardware")
    assert code == 0, err
    assert "edge members: 2 boundary curves, 4 bars 80 x 1.5 mm, 8.5 mm bolt holes" in out
    parts = load_parts(tmp_path / "parts.json")
    edges = [p for p in parts.parts if p.meta.get("member") == "edge"]
    assert edges and all(abs(np.ptp(arc_radii(p.outline)) - 80.0) < 0.01 for p in edges)   # outer less inner edge
    assert parts.report["options"]["edge_members"] is True and parts.report["options"]["edge_width_mm"] == 80.0
    # a narrower bar still sits on the 100 mm lamellas' edges, (100 + 1.5)/2 off the surface, lapping 40 mm each side
    for row in parts.report["edges"]["bars"]:
        node = catenoid.nodes[next(m for m in parts.report["edges"]["members"] if m["edge"] == row["edge"])["nodes"][0]]
        rho_o = np.linalg.norm((node.xyz * 1000.0 + LAYER_OFFSET[row["strip"][-1]] * node.normal)[:2])
        assert abs(row["length_mm"] - (2.0 * math.pi * rho_o + 80.0)) < 0.05e-3 * row["length_mm"]
    code, out, err = cli("unroll", tmp_path / "cat.json", "-o", tmp_path / "p2.json", "--edge-members",
                         "--edge-width", "-3")
    assert code == 2 and "--edge-width: must be positive, got -3" in err and len(err.strip().splitlines()) == 1
    spec = load_job_file(__import__("pathlib").Path(__file__).resolve().parents[2] / "jobs" / "pavilion.toml")
    assert spec.unroll["edge_members"] is True


def test_the_job_report_lists_the_edge_members_check(catenoid_edges):
    from fabline.jobs.report import _edge_table

    html = _edge_table(catenoid_edges.report["edges"])
    assert html.startswith("<h2>Edge members</h2>") and html.count("<tr class=ok>") == 2
    assert "4 bars of 100 x 1.5 mm" in html and "16 (loop)" in html and _edge_table(None) == ""


# ---- issue 28: the bars developed exactly, in their own layer, one bolt per axis, every lamella end fixed ----------


def unfolded_centreline(points: np.ndarray, normals: np.ndarray, half: float = 0.5) -> np.ndarray:
    """An independent development of a bar: the narrow strip p +- half b (b = n x t, t by differences of p)
    triangulated and laid flat triangle by triangle (each new vertex placed by its two edge lengths, on the far
    side of the shared edge), an exact isometry of the triangulated strip; the flat centreline at every point."""
    t = np.gradient(points, axis=0)
    b = np.cross(normals, t)
    b /= np.linalg.norm(b, axis=1)[:, None]
    verts = np.empty((2 * len(points), 3))
    verts[0::2], verts[1::2] = points + half * b, points - half * b
    flat = np.zeros((len(verts), 2))
    flat[1] = [0.0, -2.0 * half]
    cross = lambda a, c: a[0] * c[1] - a[1] * c[0]  # noqa: E731
    for k in range(2, len(verts)):
        a, c = flat[k - 2], flat[k - 1]
        da, dc = np.linalg.norm(verts[k] - verts[k - 2]), np.linalg.norm(verts[k] - verts[k - 1])
        base = c - a
        length = np.linalg.norm(base)
        e, perp = base / length, np.array([-base[1], base[0]]) / length
        x = (da ** 2 - dc ** 2 + length ** 2) / (2.0 * length)
        y = math.sqrt(max(da ** 2 - x ** 2, 0.0))
        away = -np.sign(cross(base, flat[k - 3] - a)) if k >= 3 else 1.0
        flat[k] = a + x * e + away * y * perp
    return (flat[0::2] + flat[1::2]) / 2.0


def rigid_misfit(a: np.ndarray, b: np.ndarray) -> float:
    """The largest distance between point sets a and b after the best rigid motion of a onto b (Kabsch)."""
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    u, _, vt = np.linalg.svd((a - ca).T @ (b - cb))
    r = u @ np.diag([1.0, np.sign(np.linalg.det(u @ vt))]) @ vt
    return float(np.linalg.norm((a - ca) @ r - (b - cb), axis=1).max())


@pytest.fixture(scope="module")
def pavilion_full(enneper):
    return unroll_network(enneper, UnrollOptions(edge_members=True))


def test_pavilion_edge_bar_holes_match_an_independent_triangle_strip_development(enneper):
    from scipy.interpolate import make_interp_spline

    curves = boundary_curves(enneper)
    parts, _ = curve_parts(curves, UnrollOptions(), BOLT)
    strips = {s.id: s for s in edge_strips(curves, LAYER_OFFSET["T"])[0]}
    worst = {}
    for curve in curves:
        arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(curve.points, axis=0), axis=1))])
        fine = np.unique(np.concatenate([np.arange(0.0, arc[-1], 2.0), arc[curve.node_rows], arc[-1:]]))
        normals = make_interp_spline(arc, curve.normals, k=3)(fine)
        normals /= np.linalg.norm(normals, axis=1)[:, None]
        rows = np.searchsorted(fine, arc[curve.node_rows] - 1e-9)
        points = make_interp_spline(arc, curve.points, k=3)(fine)
        for side, offset in LAYER_OFFSET.items():
            flat = unfolded_centreline(points + offset * normals, normals)
            for part in (p for p in parts if p.meta["strip"] == f"{curve.id}-{side}"):
                # node k of the part: the curve's node at the same place along the strip (a loop's first comes twice)
                node_x = strips[part.meta["strip"]].node_x
                at = [rows[int(np.argmin(abs(node_x - part.meta["strip_range_mm"][0] - n["s"])))] for n in part.nodes]
                centres = np.array(node_holes(part))
                assert len(centres) == len(part.nodes) >= 2
                worst[part.id] = rigid_misfit(centres, flat[at])
    assert len(worst) > 30 and max(worst.values()) < 0.5, max(worst.items(), key=lambda kv: kv[1])


def test_pavilion_edge_bars_lie_on_the_washers_clear_of_washers_and_clamps(enneper, pavilion_full):
    from fabline.unroll.edges import extend_to_edge
    from fabline.unroll.hardware import HardwareSizes

    parts = pavilion_full.parts
    washer_layer = (H / 2.0, H / 2.0 + T)                                   # on the lamellas' edges, one sheet thick
    for row in pavilion_full.report["edges"]["bars"]:
        bar = (abs(row["offset_mm"]) - T / 2.0, abs(row["offset_mm"]) + T / 2.0)   # the bar's own thickness
        assert bar[0] >= washer_layer[1] - 1e-9 and bar[0] - washer_layer[1] < 1e-6   # resting on the washers
    # a clamp reaches 65 mm from its node and folds its tips up: none lies within that of a bar's edge
    reach = HardwareSizes.of(Profile(H, T), 25.0, BOLT).clamp_reach
    network = extend_to_edge(enneper, UnrollOptions()).in_mm()
    centre = boundary_curves(enneper)[0].points
    def distance(nodes):  # noqa: E306
        return polyline_distance(np.array([network.nodes[n].xyz for n in nodes]), centre)
    clamped = [p.meta["node"] for p in parts if p.kind == "clamp"]
    assert distance(clamped).min() >= H / 2.0 + reach
    plain = {p.meta["node"] for p in unroll_network(enneper, UnrollOptions()).parts if p.kind == "clamp"}
    dropped = sorted(plain - set(clamped))
    assert set(clamped) <= plain and dropped and distance(dropped).max() < H / 2.0 + reach + 10.0  # the bars' reach


def test_every_lamella_end_strip_has_an_end_fix_hole_between_its_last_slot_and_its_end(enneper, pavilion_full):
    options = UnrollOptions()
    strips = [p for p in pavilion_full.parts if p.kind in ("strip", "curved-strip") and not p.meta.get("member")]
    ends = {(lam.id, lam.nodes[0]) for lam in enneper.lamellas} | {(lam.id, lam.nodes[-1]) for lam in enneper.lamellas}
    found = set()
    for part in strips:
        length = part.meta["length_mm"]
        centres = np.array(node_holes(part)).reshape(-1, 2)
        for centre in centres:
            assert abs(centre[1]) < 1e-6 or part.kind == "curved-strip"          # on a straight strip's centreline
            # its place along the strip: the first or the last node's side, end/2 from the strip's end
            at_start = part.meta["segment"] == 1 and abs(centre[0] - options.end / 2.0) < 1.0
            at_end = part.meta["segment"] == part.meta["segments"] and abs(centre[0] - (length - options.end / 2.0)) < 1.0
            assert at_start or at_end, (part.id, centre)
            node = part.nodes[0]["id"] if at_start else part.nodes[-1]["id"]
            found.add((part.lamella, node, part.meta["side"]))
            slots = [flatten_contour(s.outline)[:, 0] for s in part.slots]
            gap = min(min(abs(xs - centre[0]).min() for xs in slots), centre[0], length - centre[0])
            assert gap > BOLT / 2.0 + 1.0                                          # clear of slots and the end
    assert {(lam, node) for lam, node, _ in found} == ends
    assert len(found) == 2 * len(ends)                                              # both strips of every pair


def test_the_bom_counts_one_bolt_per_axis_and_a_cleat_per_lamella_end(enneper, catenoid, pavilion_full):
    from fabline.jobs.bom import hardware

    for network, partset in ((enneper, pavilion_full), (catenoid, unroll_network(catenoid, UnrollOptions(
            edge_members=True)))):
        parts = partset.parts
        rows = {row["item"]: row for row in hardware(parts, 5.5)}
        washer_nodes = {p.meta["node"] for p in parts if p.kind == "washer"}
        edge_nodes = {n["id"] for p in parts if p.meta.get("member") == "edge" for n in p.nodes}
        axes = washer_nodes | edge_nodes                                        # every bolt axis: a node or a bar hole
        bolts = rows["carriage bolt with nut"]["count"] + rows["edge bolt with nut and spacer tube"]["count"]
        assert bolts == len(axes)
        assert rows["end-fix bolt with nut and square tube cleat"]["count"] == 2 * len(network.lamellas)
    # the catenoid's bars run through its end nodes, which have washers: there the edge bolt is the node's bolt
    assert edge_nodes & washer_nodes and bolts < len(washer_nodes) + len(edge_nodes)


def test_a_diamond_domain_gets_one_bar_per_side_lapping_at_bolted_corners():
    from fabline.model.designs import enneper_network

    network = enneper_network((6.0, 6.0), 0.35, 1.1, boundary="diamond")
    partset = unroll_network(network, UnrollOptions(edge_members=True, hardware=False))
    curves = boundary_curves(network)
    corners = [c.node_ids[0] for c in curves]
    assert [(c.node_ids[-1], c.closed) for c in curves] == [(k, False) for k in corners[1:] + corners[:1]]
    ends = {f"{lam.id}.{k}" for lam in network.lamellas for k in (1, 2)}
    # the diamond's corners lie on its axes, where the middle lamellas of both families end: their bolts
    assert {n for c in curves for n in c.node_ids} == ends and len(set(corners)) == 4
    for curve in curves:
        inside = slice(curve.node_rows[0], curve.node_rows[-1] + 1)
        for strip in edge_strips([curve], LAYER_OFFSET["T"])[0]:
            k = strip.geometry.k_n[inside]
            assert np.all(np.sign(k) == np.sign(k[0]))                          # one sign from corner to corner
        # the corner: where the domain's straight sides meet, the curve turns through a kink between bars
        u_hat = curve.tangents[curve.node_rows[-1]]
        following = curves[(curves.index(curve) + 1) % 4]
        assert np.degrees(np.arccos(np.dot(u_hat, following.tangents[following.node_rows[0]]))) > 30.0
    bars = [p for p in partset.parts if p.meta.get("member") == "edge"]
    for corner in corners:                                                       # both bars hold the corner bolt
        holding = {p.lamella for p in bars if any(n["id"] == corner for n in p.nodes)}
        assert len(holding) == 2
