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
from fabline.mechanics.materials import get_material
from fabline.model import Lamella, Network, Node
from fabline.nest.layout import Nesting
from fabline.nest.validate import validate_nesting
from fabline.unroll import PartSet, UnrollOptions, flatten_contour, load_parts, unroll_network
from fabline.unroll.edges import BoundaryCurve, boundary_chains, boundary_curves, curve_parts, edge_strips

H, T = 100.0, 1.5
LAYER_OFFSET = {"T": (H + T) / 2.0, "B": -(H + T) / 2.0}  # along the surface normal
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


def enneper(u, v):
    """Position, first and second partials of the Enneper surface (domain.md 3), mm."""
    x = SCALE * np.stack([6 * u * u * v - 2 * v ** 3 - 6 * v, 6 * u * v * v - 2 * u ** 3 - 6 * u, -12 * u * v], -1)
    xu = SCALE * np.stack([12 * u * v, 6 * v * v - 6 * u * u - 6, -12 * v], -1)
    xv = SCALE * np.stack([6 * u * u - 6 * v * v - 6, 12 * u * v, -12 * u], -1)
    xuu = SCALE * np.stack([12 * v, -12 * u, 0 * u], -1)
    xuv = SCALE * np.stack([12 * u, 12 * v, -12 + 0 * u], -1)
    xvv = SCALE * np.stack([-12 * v, 12 * u, 0 * u], -1)
    return x, xu, xv, xuu, xuv, xvv


def circle(phi, offset=0.0):
    """The Enneper circle at angle phi: point, c'(phi), normal, k_g (1/mm) and the speed of the curve `offset` mm
    along the normal, from the closed form (the normal's derivative by a central difference)."""
    u, v = R * np.cos(phi), R * np.sin(phi)
    du, dv = -v, u
    x, xu, xv, xuu, xuv, xvv = enneper(u, v)
    d1 = xu * du[:, None] + xv * dv[:, None]
    d2 = xuu * (du * du)[:, None] + 2 * xuv * (du * dv)[:, None] + xvv * (dv * dv)[:, None] - xu * u[:, None] - xv * v[:, None]
    n = np.cross(xu, xv)
    n /= np.linalg.norm(n, axis=1)[:, None]
    speed = np.linalg.norm(d1, axis=1)
    t = d1 / speed[:, None]
    k_g = np.einsum("ij,ij->i", d2, np.cross(n, t)) / speed ** 2

    def normal(p):
        _, a, b, *_ = enneper(R * np.cos(p), R * np.sin(p))
        m = np.cross(a, b)
        return m / np.linalg.norm(m, axis=1)[:, None]

    dn = (normal(phi + 1e-6) - normal(phi - 1e-6)) / 2e-6
    return x, d1, n, k_g, np.linalg.norm(d1 + offset * dn, axis=1)


@pytest.fixture(scope="module")
def enneper_circle():
    """The circle as a closed boundary curve: nodes every 15 degrees, samples between, one interval more each side."""
    step = 2 * np.pi / NODES
    phi = np.linspace(-step, 2 * np.pi + step, (NODES + 2) * PER + 1)
    x, d1, n, _, _ = circle(phi)
    rows = np.arange(PER, PER * (NODES + 1) + 1, PER)
    ids = [f"C{k:02d}" for k in range(NODES)] + ["C00"]
    curve = BoundaryCurve("E1", ids, True, x, n, d1 / np.linalg.norm(d1, axis=1)[:, None], rows)
    return curve, phi


def test_enneper_circle_bar_curvature_is_the_geodesic_curvature_and_its_length_the_arc_length(enneper_circle):
    curve, phi = enneper_circle
    strips, _ = edge_strips([curve], (H + T) / 2.0)
    inside = slice(curve.node_rows[0], curve.node_rows[-1] + 1)
    for strip in strips:
        offset = LAYER_OFFSET[strip.side]
        _, d1, _, k_g, speed_o = circle(phi[inside], offset)
        expected = k_g * np.linalg.norm(d1, axis=1) / speed_o             # the boundary's turning per bar length
        assert np.abs(expected).max() > 1e-4                                # a real curve: radius under 10 m
        assert np.allclose(strip.geometry.k_n[inside], expected, rtol=2e-3, atol=2e-7), strip.side
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
        _, d1, _, k_g, speed_o = circle(fine, LAYER_OFFSET[side])
        s = cumulative_trapezoid(speed_o, fine, initial=0.0)
        theta = cumulative_trapezoid(k_g * np.linalg.norm(d1, axis=1), fine, initial=0.0)
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


def test_an_imported_network_gets_the_same_boundaries_as_the_design(tmp_path, enneper):
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


def test_pavilion_edge_members_pass_every_lamella_end_and_fit_a_sheet(enneper, pavilion_edges):
    ends = {lam.nodes[0] for lam in enneper.lamellas} | {lam.nodes[-1] for lam in enneper.lamellas}
    on_bars = {n["id"] for p in pavilion_edges.parts for n in p.nodes}
    assert on_bars == ends
    usable = UnrollOptions().usable_length
    for part in pavilion_edges.parts:
        assert len(node_holes(part)) == len(part.nodes)
        assert part.meta["length_mm"] <= usable
        # the chord of a curved bar plus its width fits the usable sheet extent
        points = flatten_contour(part.outline)[:, :2]
        assert np.ptp(points[:, 0]) <= usable + 1e-6
    assert {p.meta["strip"][-1] for p in pavilion_edges.parts} == {"T", "B"}


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
    ends = {lam.nodes[0] for lam in enneper.lamellas} | {lam.nodes[-1] for lam in enneper.lamellas}
    assert rows["edge bolt with nut and spacer tube"]["count"] == len(ends) == 72   # corner nodes hold two members
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
