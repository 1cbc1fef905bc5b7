"""Built-in designs and lamella geometry against closed forms that the tests compute on their own.

Truth here is independent of fabline's code: the Enneper and catenoid parametrisations written out
again, arc lengths by scipy's adaptive quadrature of the analytic speed, and the analytic |k1|.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import quad

from fabline.geometry import analyse, lamella_geometry
from fabline.model import Lamella, Network, Node

ARC_TOLERANCE = 0.05e-3  # 0.05 mm per metre


def enneper_point(u, v, c):
    return c * np.array([6 * u * u * v - 2 * v**3 - 6 * v, 6 * u * v * v - 2 * u**3 - 6 * u, -12 * u * v])


def enneper_speed(u, v, c):
    """|X_u| = |X_v| = 6c(1 + u^2 + v^2): the conformal factor (domain.md 3)."""
    return 6 * c * (1 + u * u + v * v)


def node_params(network: Network, nid: str) -> tuple[float, float]:
    i, j = (int(x) for x in nid[1:].split("-"))
    return network.meta["grid"]["a"][i], network.meta["grid"]["b"][j]


def test_enneper_nodes_lie_on_the_closed_form_surface(enneper):
    c = enneper.meta["scale_m_per_unit"]
    for nid, node in list(enneper.nodes.items())[::7]:
        u, v = node_params(enneper, nid)
        assert np.allclose(node.xyz, enneper_point(u, v, c), atol=1e-9)


def test_enneper_node_arc_lengths_match_the_integral(enneper):
    c = enneper.meta["scale_m_per_unit"]
    geometry = analyse(enneper)
    checked = 0
    for lam in enneper.lamellas:
        geo = geometry.lamellas[lam.id]
        params = [node_params(enneper, n) for n in lam.nodes]
        for k in range(len(params) - 1):
            (u0, v0), (u1, v1) = params[k], params[k + 1]
            if lam.family == "A":  # u varies, v fixed
                exact, _ = quad(lambda u: enneper_speed(u, v0, c), u0, u1, epsabs=1e-13)
            else:
                exact, _ = quad(lambda v: enneper_speed(u0, v, c), v0, v1, epsabs=1e-13)
            measured_m = (geo.node_s[k + 1] - geo.node_s[k]) / 1000.0
            assert abs(measured_m - exact) <= ARC_TOLERANCE * exact, (lam.id, k, measured_m, exact)
            checked += 1
    assert checked > 400


def test_catenoid_node_arc_lengths_match_closed_form(catenoid):
    a = catenoid.meta["waist_m"]
    geometry = analyse(catenoid)
    for lam in catenoid.lamellas:
        z = np.array([catenoid.nodes[n].xyz[2] for n in lam.nodes])
        exact = np.abs(np.diff(np.sqrt(2) * a * np.sinh(z / a)))  # s = sqrt(2) a sinh(z/a) along an asymptotic line
        measured = np.diff(geometry.lamellas[lam.id].node_s) / 1000.0
        assert np.all(np.abs(measured - exact) <= ARC_TOLERANCE * exact), lam.id


@pytest.mark.parametrize("design", ["enneper", "catenoid", "helicoid"])
def test_asymptotic_designs_have_zero_normal_curvature_and_right_angles(design, request):
    network = request.getfixturevalue(design)
    geometry = analyse(network)
    max_k_n = max(np.abs(g.k_n).max() for g in geometry.lamellas.values()) * 1000.0
    assert max_k_n < 1e-3
    angles = np.array(list(geometry.crossing_angles.values()))
    assert len(angles) > 100
    assert np.all(np.abs(angles - 90.0) < 0.1)


def geodesic_torsion_at_nodes(network: Network):
    geometry = analyse(network)
    for lam in network.lamellas:
        geo = geometry.lamellas[lam.id]
        tau_g = geo.fit.frame(geo.fit.parameter_at(geo.node_s))["tau_g"] * 1000.0
        for nid, value in zip(lam.nodes, tau_g):
            yield nid, value


def test_enneper_geodesic_torsion_equals_k1(enneper):
    c = enneper.meta["scale_m_per_unit"]
    for nid, tau_g in geodesic_torsion_at_nodes(enneper):
        u, v = node_params(enneper, nid)
        k1 = 1.0 / (3 * c * (1 + u * u + v * v) ** 2)
        assert abs(abs(tau_g) - k1) <= 0.01 * k1, nid


def test_catenoid_geodesic_torsion_equals_k1(catenoid):
    a = catenoid.meta["waist_m"]
    for nid, tau_g in geodesic_torsion_at_nodes(catenoid):
        k1 = 1.0 / (a * np.cosh(catenoid.nodes[nid].xyz[2] / a) ** 2)
        assert abs(abs(tau_g) - k1) <= 0.01 * k1, nid


def test_pavilion_design_is_sized_like_the_reference(enneper):
    xyz = np.array([n.xyz for n in enneper.nodes.values()])
    extent = np.ptp(xyz, axis=0)
    assert extent[0] == pytest.approx(9.0, rel=0.08) and extent[1] == pytest.approx(12.0, rel=0.08)
    geometry = analyse(enneper)
    assert max(np.abs(g.tau_g).max() for g in geometry.lamellas.values()) * 1000 == pytest.approx(1.1, rel=0.01)


def circle_lamella(radius_mm: float, arc: float, normals: str, samples: int = 200) -> Network:
    """A circle of radius R in the xy plane; normals 'radial' (a great circle on a sphere) or 'up' (a plane)."""
    t = np.linspace(0, arc, samples)
    curve = radius_mm * np.stack([np.cos(t), np.sin(t), 0 * t], axis=1)
    n = curve / radius_mm if normals == "radial" else np.tile([0.0, 0.0, 1.0], (samples, 1))
    nodes = {f"n{k}": Node(f"n{k}", curve[k], n[k], "grid") for k in (0, samples // 2, samples - 1)}
    return Network("mm", nodes, [Lamella("A-1", "A", list(nodes), curve, n)])


def test_great_circle_on_a_sphere_bends_in_the_normal_direction_only():
    radius = 5000.0
    network = circle_lamella(radius, 1.2, "radial")
    geo = lamella_geometry(network.lamellas[0], network)
    assert np.allclose(np.abs(geo.k_n), 1 / radius, rtol=1e-5)
    assert np.abs(geo.k_g).max() < 1e-9 and np.abs(geo.tau_g).max() < 1e-9
    assert geo.length == pytest.approx(radius * 1.2, rel=1e-9)


def test_circle_in_a_plane_bends_sideways_only():
    network = circle_lamella(2000.0, 2.0, "up")
    geo = lamella_geometry(network.lamellas[0], network)
    assert np.allclose(np.abs(geo.k_g), 1 / 2000.0, rtol=1e-4)
    assert np.abs(geo.k_n).max() < 1e-9


def test_helix_on_a_cylinder_has_the_textbook_curvatures():
    """Helix of radius r and slope angle alpha on a cylinder: k_n = cos^2(alpha)/r, tau_g = sin(alpha)cos(alpha)/r, k_g = 0."""
    r, pitch = 1000.0, 3000.0
    t = np.linspace(0, 4 * np.pi, 800)
    curve = np.stack([r * np.cos(t), r * np.sin(t), pitch * t / (2 * np.pi)], axis=1)
    normals = np.stack([np.cos(t), np.sin(t), 0 * t], axis=1)
    nodes = {"a": Node("a", curve[0], normals[0]), "b": Node("b", curve[-1], normals[-1])}
    network = Network("mm", nodes, [Lamella("A-1", "A", ["a", "b"], curve, normals)])
    geo = lamella_geometry(network.lamellas[0], network)
    alpha = np.arctan(pitch / (2 * np.pi * r))
    inner = slice(20, -20)
    assert np.allclose(np.abs(geo.k_n[inner]), np.cos(alpha) ** 2 / r, rtol=1e-4)
    assert np.allclose(np.abs(geo.tau_g[inner]), np.sin(alpha) * np.cos(alpha) / r, rtol=1e-4)
    assert np.abs(geo.k_g[inner]).max() < 1e-8
    assert geo.length == pytest.approx(4 * np.pi * np.hypot(r, pitch / (2 * np.pi)), rel=1e-7)


def test_two_strips_beside_lines_crossing_at_60_degrees_cross_where_the_hand_computation_says():
    # in the plane z = 0: strip i is the line y = 12.5 beside the x axis, strip j runs 12.5 mm to the right of the
    # line at 60 degrees through the node; they meet at (12.5 sqrt 3, 12.5), 12.5 sqrt 3 from the node along both
    from fabline.geometry.offsets import strip_crossing_offsets

    t_j = np.array([[0.5, np.sqrt(3) / 2, 0.0]])
    a, b = strip_crossing_offsets(np.array([[1.0, 0.0, 0.0]]), t_j, np.array([[0.0, 0.0, 1.0]]), np.array([12.5]),
                                  np.array([-12.5]))
    assert a[0] == pytest.approx(12.5 * np.sqrt(3)) and b[0] == pytest.approx(12.5 * np.sqrt(3))
    crossing = np.array([12.5 * np.sqrt(3), 12.5, 0.0])
    beside_j = np.cross([0.0, 0.0, 1.0], t_j[0])  # u_j = n x t_j, the side +offset lies on
    assert np.allclose(b[0] * t_j[0] - 12.5 * beside_j, crossing)
