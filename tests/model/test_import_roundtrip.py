"""Networks written as CAD curves and imported again, nodes recomputed from the crossings alone.

Truth comes from outside the importer: a hyperbolic paraboloid z = xy/c whose straight rulings are its
asymptotic lines (nodes and normals in closed form), and the built-in Enneper and catenoid designs,
whose reference surfaces the tests mesh themselves from the parametrisations.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from fabline.errors import FablineError
from fabline.model import Lamella, Network, Node
from fabline.model.designs import catenoid_network, catenoid_surface, enneper_network, enneper_surface
from fabline.model.importers import import_model
from fabline.model.writers import write_dxf, write_obj

NODE_TOLERANCE_MM = 0.01
HYPAR_C = 4.0  # z = x y / c, metres


def hypar_point(x, y):
    return np.stack(np.broadcast_arrays(x, y, x * y / HYPAR_C), axis=-1).astype(float)


def hypar_normal(x, y):
    n = np.stack(np.broadcast_arrays(-y / HYPAR_C, -x / HYPAR_C, np.ones_like(x * y)), axis=-1).astype(float)
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


def hypar_network(count: int = 7, spacing: float = 0.5, samples: int = 10) -> Network:
    """Rulings x = const (family B) and y = const (family A) of z = xy/c; nodes at their crossings."""
    coords = spacing * (np.arange(count) - (count - 1) / 2)
    fine = np.linspace(coords[0], coords[-1], (count - 1) * samples + 1)  # contains every node coordinate
    nodes = {}
    for i, x in enumerate(coords):
        for j, y in enumerate(coords):
            nodes[f"N{i}-{j}"] = Node(f"N{i}-{j}", hypar_point(x, y), hypar_normal(x, y))
    lamellas = []
    for j, y in enumerate(coords):
        lamellas.append(Lamella(f"A-{j:03d}", "A", [f"N{i}-{j}" for i in range(count)],
                                hypar_point(fine, y), hypar_normal(fine, y)))
    for i, x in enumerate(coords):
        lamellas.append(Lamella(f"B-{i:03d}", "B", [f"N{i}-{j}" for j in range(count)],
                                hypar_point(x, fine), hypar_normal(x, fine)))
    return Network("m", nodes, lamellas, "hypar")


def grid_mesh(point, a_range, b_range, count: int = 81) -> trimesh.Trimesh:
    """A triangulated parameter grid of a surface, faces wound so their normals follow X_a x X_b."""
    a, b = np.meshgrid(np.linspace(*a_range, count), np.linspace(*b_range, count), indexing="ij")
    index = np.arange(count * count).reshape(count, count)
    p, q, r, s = index[:-1, :-1].ravel(), index[1:, :-1].ravel(), index[1:, 1:].ravel(), index[:-1, 1:].ravel()
    return trimesh.Trimesh(point(a, b).reshape(-1, 3), np.r_[np.c_[p, q, r], np.c_[p, r, s]], process=False)


def hypar_mesh(half: float = 1.8, count: int = 81) -> trimesh.Trimesh:
    return grid_mesh(hypar_point, (-half, half), (-half, half), count)


def assert_same_network(original: Network, imported: Network) -> None:
    """Every node back with its id and kind within 0.01 mm (lamella ends that cross nothing included: the writers
    name every node), the same lamella ids and families, each lamella through the same nodes in order."""
    assert sorted(imported.nodes) == sorted(original.nodes)
    for nid, node in original.nodes.items():
        got = imported.nodes[nid]
        assert np.linalg.norm(got.xyz - node.xyz) * original.mm_per_unit < NODE_TOLERANCE_MM, nid
        assert got.kind == node.kind, nid
    by_id = {lam.id: lam for lam in imported.lamellas}
    assert sorted(by_id) == sorted(lam.id for lam in original.lamellas)
    for lam in original.lamellas:
        got = by_id[lam.id]
        assert got.family == lam.family
        assert got.nodes == lam.nodes


def crossing_nodes(network: Network) -> dict[str, np.ndarray]:
    """The nodes a curves-only import can find: those on two or more lamellas (ends that cross nothing are not nodes)."""
    return {nid: network.nodes[nid].xyz for nid, lams in network.lamellas_at().items() if len(lams) >= 2}


def assert_same_crossings(original: Network, imported: Network) -> None:
    """For curves without named nodes (no node points in the file): the crossing nodes within 0.01 mm, same lamella ids and families, each lamella through the same nodes in order."""
    expected = crossing_nodes(original)
    assert len(imported.nodes) == len(expected)
    ids, xyz, _ = imported.node_array()
    names = list(expected)
    distance, index = cKDTree(np.array([expected[n] for n in names])).query(xyz)
    assert distance.max() * original.mm_per_unit < NODE_TOLERANCE_MM
    assert len(set(index.tolist())) == len(names)
    renamed = {nid: names[k] for nid, k in zip(ids, index)}
    by_id = {lam.id: lam for lam in imported.lamellas}
    assert sorted(by_id) == sorted(lam.id for lam in original.lamellas)
    for lam in original.lamellas:
        got = by_id[lam.id]
        assert got.family == lam.family
        assert [renamed[n] for n in got.nodes] == [n for n in lam.nodes if n in expected]


@pytest.fixture(scope="module")
def hypar_files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("hypar")
    network = hypar_network()
    hypar_mesh().export(folder / "surface.obj")
    write_obj(network, folder / "curves.obj")
    write_dxf(network, folder / "curves.dxf")
    return network, folder


@pytest.mark.parametrize("suffix", ["obj", "dxf"])
def test_hypar_round_trip_gives_the_same_nodes_and_topology(hypar_files, suffix):
    network, folder = hypar_files
    imported, report = import_model(folder / f"curves.{suffix}", surface=folder / "surface.obj", units="m")
    assert_same_network(network, imported)
    assert imported.units == "m" and report.near_misses == [] and report.singularities == 0
    assert all(node.kind == "grid" for node in imported.nodes.values())


@pytest.mark.parametrize("suffix", ["obj", "dxf"])
def test_hypar_normals_come_from_the_surface_on_its_side(hypar_files, suffix):
    network, folder = hypar_files
    imported, _ = import_model(folder / f"curves.{suffix}", surface=folder / "surface.obj", units="m")
    for node in imported.nodes.values():
        assert np.dot(node.normal, hypar_normal(node.xyz[0], node.xyz[1])) > np.cos(np.radians(0.5))
    for lam in imported.lamellas:
        exact = hypar_normal(lam.curve[:, 0], lam.curve[:, 1])
        assert np.einsum("ij,ij->i", lam.normals, exact).min() > np.cos(np.radians(0.5))


def test_flipped_faces_do_not_flip_the_normals(tmp_path):
    """A mesh with some faces wound the wrong way still gives normals on its majority side."""
    mesh = hypar_mesh(count=41)
    faces = mesh.faces.copy()
    faces[::7] = faces[::7, ::-1]
    trimesh.Trimesh(mesh.vertices, faces, process=False).export(tmp_path / "surface.obj")
    write_obj(hypar_network(), tmp_path / "curves.obj")
    imported, _ = import_model(tmp_path / "curves.obj", surface=tmp_path / "surface.obj", units="m")
    for node in imported.nodes.values():
        assert np.dot(node.normal, hypar_normal(node.xyz[0], node.xyz[1])) > np.cos(np.radians(0.5))


def test_surface_faces_in_the_same_obj_give_the_normals(tmp_path):
    network = hypar_network()
    write_obj(network, tmp_path / "both.obj", mesh=hypar_mesh())
    imported, report = import_model(tmp_path / "both.obj")
    assert_same_network(network, imported)
    assert report.surface == str(tmp_path / "both.obj")
    assert any("declares no units; assumed m" in note for note in report.notes)


def test_surface_mesh_in_the_same_dxf_gives_the_normals(tmp_path):
    network = hypar_network()
    write_dxf(network, tmp_path / "both.dxf", mesh=hypar_mesh())
    imported, report = import_model(tmp_path / "both.dxf")
    assert_same_network(network, imported)
    assert report.units == "m" and report.notes == []


def test_near_miss_is_reported_with_both_lamellas_and_the_distance(tmp_path):
    """Lift B-003 by 3 mm along the normal around node N3-5: that crossing becomes a 3 mm near-miss."""
    network = hypar_network()
    lamella = next(lam for lam in network.lamellas if lam.id == "B-003")
    node = network.nodes["N3-5"]
    along = np.linalg.norm(lamella.curve - node.xyz, axis=1)
    lift = np.clip((0.2 - along) / 0.1, 0.0, 1.0)  # 1 within 0.1 m of the node, ramps to 0 at 0.2 m
    lamella.curve = lamella.curve + 0.003 * lift[:, None] * node.normal
    hypar_mesh().export(tmp_path / "surface.obj")
    write_obj(network, tmp_path / "curves.obj")
    imported, report = import_model(tmp_path / "curves.obj", surface=tmp_path / "surface.obj", units="m")
    assert len(imported.nodes) == len(network.nodes) - 1
    assert len(report.near_misses) == 1
    miss = report.near_misses[0]
    assert (miss.lamella_a, miss.lamella_b) == ("A-005", "B-003")
    assert miss.distance_mm == pytest.approx(3.0, abs=1e-6)
    assert np.allclose(miss.xyz, node.xyz + 0.0015 * node.normal, atol=1e-7)
    assert any("near-miss: A-005 and B-003 pass 3.000 mm apart" in line for line in report.summary())


def test_three_lamellas_through_one_point_make_a_singularity(tmp_path):
    """A third lamella (family A) along the diagonal x = y meets an A and a B ruling at every diagonal node."""
    network = hypar_network()
    t = np.linspace(-1.5, 1.5, 61)
    network.lamellas.append(Lamella("A-diag", "A", [], hypar_point(t, t), hypar_normal(t, t)))
    hypar_mesh().export(tmp_path / "surface.obj")
    write_obj(network, tmp_path / "curves.obj")
    imported, report = import_model(tmp_path / "curves.obj", surface=tmp_path / "surface.obj", units="m")
    singular = [n for n in imported.nodes.values() if n.kind == "singularity"]
    assert report.singularities == len(singular) == 7
    assert np.allclose([n.xyz[0] for n in singular], [n.xyz[1] for n in singular], atol=1e-6)
    diagonal = next(lam for lam in imported.lamellas if lam.id == "A-diag")
    # the diagonal crosses each B ruling once: at the 7 grid nodes, nowhere else
    assert len(diagonal.nodes) == 7 and set(diagonal.nodes) == {n.id for n in singular}


def test_tolerance_decides_what_crosses(tmp_path):
    """A 1.8 mm gap is a node with --tolerance 5 (at the midpoint, 0.9 mm off each curve) and a near-miss with the
    default 1 mm; a 3 mm gap would put the node 1.5 mm off both curves, which the model's validation (the same
    for every reader: inspect and unroll would refuse it) does not accept."""
    network = hypar_network(count=3)
    lamella = next(lam for lam in network.lamellas if lam.id == "B-001")
    curve = lamella.curve.copy()
    hypar_mesh().export(tmp_path / "surface.obj")
    for gap, expected in ((0.0018, None), (0.003, r"node N[\d-]+ lies 1\.[45]\d mm off its centreline")):
        lamella.curve = curve + np.array([0.0, 0.0, gap])
        write_obj(network, tmp_path / "curves.obj")
        if expected is not None:
            with pytest.raises(FablineError, match=expected):
                import_model(tmp_path / "curves.obj", surface=tmp_path / "surface.obj", units="m", tolerance_mm=5)
            continue
        imported, _ = import_model(tmp_path / "curves.obj", surface=tmp_path / "surface.obj", units="m",
                                   tolerance_mm=5)
        assert len(imported.nodes) == 9
        with pytest.raises(Exception, match="B-001 .* crosses no lamella"):
            import_model(tmp_path / "curves.obj", surface=tmp_path / "surface.obj", units="m")


def enneper_mesh(network: Network) -> trimesh.Trimesh:
    surface = enneper_surface(network.meta["scale_m_per_unit"])
    half_u, half_v = network.meta["domain"]["u"] * 1.05, network.meta["domain"]["v"] * 1.05
    return grid_mesh(surface.point, (-half_u, half_u), (-half_v, half_v), count=121)


def catenoid_mesh(network: Network) -> trimesh.Trimesh:
    """The catenoid meshed in (z, theta), so faces follow the design's X_a x X_b; the seam at theta = 2 pi
    welds shut when imported."""
    waist, half = network.meta["waist_m"], network.meta["height_m"] * 0.55
    surface = catenoid_surface(waist)

    def point(z, theta):
        return surface.point(theta + z / waist, theta - z / waist)

    return grid_mesh(point, (-half, half), (0.0, 2 * np.pi), count=121)


@pytest.mark.parametrize("design", ["enneper", "catenoid"])
@pytest.mark.parametrize("suffix", ["obj", "dxf"])
def test_design_round_trip_gives_the_same_nodes_and_topology(tmp_path, design, suffix):
    if design == "enneper":
        network = enneper_network(size=(6.0, 8.0), spacing=0.6)
        mesh = enneper_mesh(network)
    else:
        network = catenoid_network(waist=1.0, height=2.0, count=12)
        mesh = catenoid_mesh(network)
    mesh.export(tmp_path / "surface.obj")
    (write_obj if suffix == "obj" else write_dxf)(network, tmp_path / f"curves.{suffix}")
    imported, report = import_model(tmp_path / f"curves.{suffix}", surface=tmp_path / "surface.obj", units="m")
    assert_same_network(network, imported)
    assert report.near_misses == []
    # normals from the test's own mesh agree with the design's closed-form normals (same side, within 1 degree)
    ids, xyz, normals = imported.node_array()
    reference = cKDTree(np.array([n.xyz for n in network.nodes.values()])).query(xyz)[1]
    design_normals = np.array([n.normal for n in network.nodes.values()])[reference]
    assert np.einsum("ij,ij->i", normals, design_normals).min() > np.cos(np.radians(1.0))
