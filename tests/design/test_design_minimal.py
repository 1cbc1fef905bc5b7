"""`fabline design minimal`: the discrete minimal surface between two coaxial circles against the catenoid."""

from __future__ import annotations

import json

import ezdxf
import numpy as np
import pytest
import trimesh
from scipy.optimize import fsolve

from fabline.design import design_asymptotic
from fabline.design import minimal
from fabline.design.minimal import catenoid_waist, coaxial_circles, minimal_surface
from fabline.errors import FablineError


def circle(centre: tuple[float, float], radius: float, height: float, count: int = 400) -> list[list[float]]:
    """A closed circle parallel to the xy plane as a JSON curve (its first point repeated at the end)."""
    angle = np.linspace(0, 2 * np.pi, count + 1)
    return np.stack([centre[0] + radius * np.cos(angle), centre[1] + radius * np.sin(angle), np.full(count + 1, height)], axis=1).tolist()


def independent_waist(radius: float, separation: float) -> float:
    """The stable catenoid's waist from the boundary condition a cosh(h / 2a) = R, solved from a = R (not by the code under test)."""
    return float(fsolve(lambda a: a * np.cosh(separation / 2 / a) - radius, radius)[0])


def catenoid_distance(points: np.ndarray, waist: float) -> np.ndarray:
    """Distance from points near the catenoid r = a cosh(z / a) to it (radial gap times the cosine of its slope)."""
    radial = np.hypot(points[:, 0], points[:, 1]) - waist * np.cosh(points[:, 2] / waist)
    return np.abs(radial) / np.cosh(points[:, 2] / waist)


def test_waist_of_the_catenoid_between_two_circles():
    waist = independent_waist(1.0, 1.0)
    assert waist == pytest.approx(0.848338, abs=1e-6)
    assert catenoid_waist(1.0, 1.0) == pytest.approx(waist, abs=1e-9)


def test_minimal_surface_between_two_circles_lies_within_1_mm_of_the_catenoid():
    mesh = minimal_surface(coaxial_circles(1.0, 1.0), 0.05)
    waist = independent_waist(1.0, 1.0)
    assert catenoid_distance(mesh.vertices, waist).max() < 0.001
    assert catenoid_distance(mesh.triangles_center, waist).max() < 0.001
    angles = np.degrees(trimesh.triangles.angles(mesh.triangles))
    assert angles.min() > 30 and angles.max() < 110  # well-shaped triangles
    assert abs(mesh.area - 2 * np.pi * waist * (0.5 + waist / 2 * np.sinh(1.0 / waist))) < 0.002 * mesh.area


def test_disc_spanning_a_saddle_curve_is_anticlastic_and_traced(tmp_path, cli):
    angle = np.linspace(0, 2 * np.pi, 200, endpoint=False)
    curve = np.stack([np.cos(angle), np.sin(angle), 0.3 * np.cos(2 * angle)], axis=1)
    boundary = tmp_path / "edge.json"
    boundary.write_text(json.dumps({"units": "m", "curves": [np.vstack([curve, curve[:1]]).tolist()]}))
    code, stdout, _ = cli("design", "minimal", "--boundary", boundary, "--mesh-size", "0.06", "-o", tmp_path / "disc.obj")
    assert code == 0 and "1 boundary curve" in stdout
    mesh = trimesh.load(tmp_path / "disc.obj", force="mesh")
    # to first order in the amplitude the minimal disc is the harmonic extension z = 0.3 (x^2 - y^2) of its edge
    x, y, z = mesh.vertices.T
    assert np.abs(z - 0.3 * (x * x - y * y)).max() < 0.02
    network = design_asymptotic(tmp_path / "disc.obj", 0.2).network
    assert network.meta["quality"]["crossing_angles"]["min"] > 85


def test_dxf_circles_give_the_catenoid(tmp_path, cli):
    doc = ezdxf.new()
    doc.header["$INSUNITS"] = 6
    for z in (-0.5, 0.5):
        doc.modelspace().add_circle((0, 0, 0), 1.0).translate(0, 0, z)
    doc.saveas(tmp_path / "rings.dxf")
    code, stdout, _ = cli("design", "minimal", "--boundary", tmp_path / "rings.dxf", "--mesh-size", "0.05", "-o", tmp_path / "tube.ply")
    assert code == 0, stdout
    mesh = trimesh.load(tmp_path / "tube.ply", force="mesh")
    assert catenoid_distance(mesh.vertices, independent_waist(1.0, 1.0)).max() < 0.001


@pytest.mark.parametrize("curves, words", [
    ([[[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]], "curve 0: open curve"),
    ([], "no curves found"),
    ([[[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 0]]] * 3, "curve 0 and curve 1: their projections"),
    ([circle((0, 0), 2, 0), circle((-0.5, 0), 0.6, 0.3), circle((0.5, 0), 0.6, 0.3)], "curve 1 and curve 2: their projections"),
    ([circle((0, 0), 1, 0), circle((1, 0), 0.5, 0.3), circle((-0.5, 0), 0.2, 0.3)], "curve 0 and curve 1: their projections"),
])
def test_bad_boundaries_are_named_with_exit_2_and_nothing_written(tmp_path, cli, curves, words):
    boundary = tmp_path / "edge.json"
    boundary.write_text(json.dumps({"units": "m", "curves": curves}))
    out = tmp_path / "out.obj"
    code, _, stderr = cli("design", "minimal", "--boundary", boundary, "--mesh-size", "0.1", "-o", out)
    assert code == 2 and words in stderr and len(stderr.strip().splitlines()) == 1, stderr
    assert not out.exists()


def test_an_open_dxf_arc_is_refused(tmp_path):
    doc = ezdxf.new()
    doc.modelspace().add_arc((0, 0), 1.0, 0, 270)
    doc.saveas(tmp_path / "arc.dxf")
    from fabline.design.minimal import read_boundaries
    with pytest.raises(FablineError, match=r"ARC #\w+: open curve"):
        read_boundaries(tmp_path / "arc.dxf")


def mean_curvature(mesh: trimesh.Trimesh) -> np.ndarray:
    """|H| at every vertex from the cotangent formula |sum (cot a + cot b)(x_j - x_i)| / (4 A_i), A_i a third of the
    vertex's triangles' area (numpy here, not the solver's libigl)."""
    v, f = mesh.vertices, mesh.faces
    normal = np.zeros_like(v)
    for k in range(3):
        i, j, l = f[:, k], f[:, (k + 1) % 3], f[:, (k + 2) % 3]
        e1, e2 = v[j] - v[i], v[l] - v[i]
        cot = np.einsum("ij,ij->i", e1, e2) / np.linalg.norm(np.cross(e1, e2), axis=1)  # the angle at i, opposite j-l
        np.add.at(normal, j, cot[:, None] * (v[l] - v[j]))
        np.add.at(normal, l, cot[:, None] * (v[j] - v[l]))
    area = np.bincount(f.ravel(), np.repeat(mesh.area_faces / 3, 3), minlength=len(v))
    return np.linalg.norm(normal, axis=1) / (4 * area)


def interior(mesh: trimesh.Trimesh) -> np.ndarray:
    """Indices of the vertices on no boundary edge."""
    rim = mesh.edges_sorted[trimesh.grouping.group_rows(mesh.edges_sorted, require_count=1)]
    return np.setdiff1d(np.arange(len(mesh.vertices)), rim.ravel())


def test_annulus_between_circles_at_two_heights_is_a_catenoid_piece():
    # circles cut from the catenoid r = cosh z (waist 1 m) at z = 0.2 and z = 1: the outer one spans the inner one's
    # projection, so the surface starts from the flat annulus between them, lifted, and must reach the catenoid
    rings = [np.array(circle((0, 0), np.cosh(z), z, 720))[:-1] for z in (1.0, 0.2)]
    mesh = minimal_surface(rings, 0.05)
    assert catenoid_distance(mesh.vertices, 1.0).max() < 0.001
    assert catenoid_distance(mesh.triangles_center, 1.0).max() < 0.001
    assert np.ptp(mesh.vertices[:, 2]) == pytest.approx(0.8, abs=1e-9)
    assert len(interior(mesh)) > 0.8 * len(mesh.vertices)  # a real surface between the rings, not a strip of rim triangles


def three_loops(size: float) -> trimesh.Trimesh:
    """An outer circle (radius 1.5 m) with two circular openings (0.3 m) raised by 0.4 m, symmetric in x and in y."""
    curves = [circle((0, 0), 1.5, 0.0), circle((-0.6, 0), 0.3, 0.4), circle((0.6, 0), 0.3, 0.4)]
    return minimal_surface([np.array(c)[:-1] for c in curves], size)


def heights(mesh: trimesh.Trimesh, xy: np.ndarray) -> np.ndarray:
    """The surface's height over points (it is a graph over the xy plane here), by linear interpolation."""
    from scipy.interpolate import LinearNDInterpolator
    return LinearNDInterpolator(mesh.vertices[:, :2], mesh.vertices[:, 2])(xy)


def test_three_loops_span_a_minimal_surface_that_converges_under_refinement():
    coarse, fine = three_loops(0.1), three_loops(0.05)
    assert trimesh.Trimesh(fine.vertices, fine.faces).is_winding_consistent
    assert len(trimesh.graph.connected_components(fine.face_adjacency)) == 1
    rim = fine.edges_sorted[trimesh.grouping.group_rows(fine.edges_sorted, require_count=1)]
    assert len(np.unique(rim)) == len(rim)  # three closed boundary loops, no pinched vertex
    h_coarse, h_fine = mean_curvature(coarse)[interior(coarse)], mean_curvature(fine)[interior(fine)]
    assert h_fine.mean() < 0.5 * h_coarse.mean() and h_fine.mean() < 0.002 and h_fine.max() < 0.1  # 1/m
    # the same surface at both sizes, and it keeps the arrangement's two mirror symmetries
    y = np.linspace(-1.4, 1.4, 15)
    probes = np.r_[np.c_[np.zeros_like(y), y], np.c_[y, np.full_like(y, 0.45)], np.c_[y, np.full_like(y, -0.45)]]
    probes = probes[np.hypot(np.abs(probes[:, 0]) - 0.6, probes[:, 1]) > 0.35]
    fine_z = heights(fine, probes)
    assert np.abs(fine_z - heights(coarse, probes)).max() < 0.002
    assert np.abs(fine_z - heights(fine, probes * [-1, 1])).max() < 0.001
    assert np.abs(fine_z - heights(fine, probes * [1, -1])).max() < 0.001
    squashed = trimesh.Trimesh(fine.vertices * [1, 1, 0.5], fine.faces, process=False)  # not minimal: the measure sees it
    assert mean_curvature(squashed)[interior(fine)].mean() > 10 * h_fine.mean()


def test_three_dxf_loops_then_network_then_parts(tmp_path, cli):
    doc = ezdxf.new()
    doc.header["$INSUNITS"] = 6
    doc.modelspace().add_circle((0, 0, 0), 2.0)
    for x in (-0.8, 0.8):
        doc.modelspace().add_circle((x, 0, 0), 0.4).translate(0, 0, 0.5)
    doc.saveas(tmp_path / "oculi.dxf")
    code, stdout, stderr = cli("design", "minimal", "--boundary", tmp_path / "oculi.dxf", "--mesh-size", "0.1", "-o", tmp_path / "shell.obj")
    assert code == 0 and "3 boundary curves" in stdout, stderr
    code, stdout, stderr = cli("design", "asymptotic", "--surface", tmp_path / "shell.obj", "--units", "m", "--spacing", "0.4",
                               "-o", tmp_path / "shell.network.json")
    assert code == 0, stderr
    network = json.loads((tmp_path / "shell.network.json").read_text())
    assert len(network["lamellas"]) >= 8
    assert network["meta"]["quality"]["crossing_angles"]["min"] > 75
    code, stdout, stderr = cli("unroll", tmp_path / "shell.network.json", "-o", tmp_path / "parts.json")
    assert code == 0 and (tmp_path / "parts.json").exists(), stderr


def steep_annulus(monkeypatch, rounds: int) -> trimesh.Trimesh:
    """The annulus between z = 1 and z = 0.2 on the catenoid r = cosh z, whose flat start is stretched five times near
    the inner ring (the surface rises steeply there), with `rounds` remeshing rounds."""
    monkeypatch.setattr(minimal, "REMESH_ROUNDS", rounds)
    return minimal_surface([np.array(circle((0, 0), np.cosh(z), z, 720))[:-1] for z in (1.0, 0.2)], 0.05)


def boundary_vertices(mesh: trimesh.Trimesh) -> np.ndarray:
    """Positions of the vertices on edges that have one face, sorted; and asserts every other edge has two."""
    edges, counts = np.unique(mesh.edges_sorted, axis=0, return_counts=True)
    assert set(counts) == {1, 2}  # manifold: no edge in three faces
    points = mesh.vertices[np.unique(edges[counts == 1])]
    return points[np.lexsort(points.T)]


def test_remeshing_keeps_triangles_well_shaped_where_the_start_tears_them(monkeypatch):
    rounds = minimal.REMESH_ROUNDS
    torn, remeshed = steep_annulus(monkeypatch, 0), steep_annulus(monkeypatch, rounds)
    angles = {name: np.degrees(trimesh.triangles.angles(mesh.triangles)) for name, mesh in (("torn", torn), ("remeshed", remeshed))}
    assert (angles["torn"].min(axis=1) < 30).mean() > 0.05 and angles["torn"].max() > 130  # the case needs remeshing
    assert (angles["remeshed"].min(axis=1) < 30).mean() < 0.01 and angles["remeshed"].min() > 20
    assert angles["remeshed"].max() < 110
    edges = remeshed.edges_unique_length
    assert np.percentile(edges, 5) > 0.8 * 0.05 * 0.8 and np.percentile(edges, 95) < 4 / 3 * 0.05
    # a manifold, consistently oriented annulus (Euler number 0) whose boundary is the given rings' points, untouched
    assert remeshed.is_winding_consistent
    assert len(remeshed.vertices) - len(remeshed.edges_unique) + len(remeshed.faces) == 0
    rim = boundary_vertices(remeshed)
    assert np.array_equal(rim, boundary_vertices(torn))
    assert set(np.round(rim[:, 2], 12)) == {0.2, 1.0}
    assert np.abs(np.hypot(rim[:, 0], rim[:, 1]) - np.cosh(rim[:, 2])).max() < 1e-4  # on the 720-gons
    assert catenoid_distance(torn.vertices, 1.0).max() > 0.001 > catenoid_distance(remeshed.vertices, 1.0).max()
