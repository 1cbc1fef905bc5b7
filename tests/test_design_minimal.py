"""`fabline design minimal`: the discrete minimal surface between two coaxial circles against the catenoid."""

from __future__ import annotations

import json

import ezdxf
import numpy as np
import pytest
import trimesh
from scipy.optimize import fsolve

from fabline.errors import FablineError
from fabline.model.surfaces import design_asymptotic
from fabline.model.surfaces.minimal import catenoid_waist, coaxial_circles, minimal_surface


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
    ([[[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 0]]] * 3, "3 boundary curves"),
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
    from fabline.model.surfaces.minimal import read_boundaries
    with pytest.raises(FablineError, match=r"ARC #\w+: open curve"):
        read_boundaries(tmp_path / "arc.dxf")
