"""Structural formulas against the thesis's reference values (domain.md 6), materials as data, `fabline limits`."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fabline.errors import FablineError
from fabline.mechanics import (Profile, bending_stress, get_material, helix_stresses, limits, load_materials, max_twist,
                               min_bending_radius, parse_profile, twist_shear_stress)
from fabline.mechanics.structure import helix_strains

PROFILE = Profile(100.0, 1.5)


@pytest.fixture
def s235():
    return get_material("steel-s235")


def test_reference_values_of_the_thesis(s235):
    assert round(min_bending_radius(s235, PROFILE)) == 670                      # (6.3)
    sigma = float(bending_stress(s235, PROFILE, 1.0 / 1060.0))
    assert round(sigma, 1) == 148.6 and round(100 * sigma / s235.f_y) == 63    # pavilion's smallest radius
    assert round(max_twist(s235, PROFILE) * 1000.0, 2) == 1.12                 # (6.6), rad/m
    assert round(np.degrees(max_twist(s235, PROFILE) * 1000.0)) == 64
    kappa = 1.12e-3
    eps_min, eps_max = helix_strains(PROFILE, kappa)
    assert round(float(eps_min), 6) == -0.000523 and round(float(eps_max), 6) == 0.001045
    sigma_min, sigma_max = helix_stresses(s235, PROFILE, kappa)
    assert round(float(sigma_min), 2) == -109.76 and round(float(sigma_max), 2) == 219.52
    assert float(sigma_max) == pytest.approx(-2.0 * float(sigma_min))          # sigma_H,max = -2 sigma_H,min
    assert round(-float(eps_min) * 1000.0, 2) == 0.52                          # mm per metre of centre contraction
    assert round(float(twist_shear_stress(s235, PROFILE, kappa))) == 136


def test_limits_table_matches_the_formulas(s235):
    result = limits(s235, PROFILE, radius=1060.0, twist=1.12)
    assert result["min_bending_radius_mm"] == pytest.approx(210000 * 1.5 / (2 * 235))
    assert result["at_radius"]["bending_stress"] == pytest.approx(210000 * 1.5 / 2 / 1060)
    assert result["at_twist"]["helix_stress_max"] == pytest.approx(210000 * 100**2 * 1.12e-3**2 / 12)
    assert result["at_twist"]["shear_stress"] == pytest.approx(81000 * 1.5 * 1.12e-3)


def test_builtin_materials_and_a_user_file(tmp_path):
    materials = load_materials()
    assert {"steel-s235", "stainless"} <= set(materials)
    extra = tmp_path / "m.toml"
    extra.write_text('[beech]\nE = 14000\nG = 1000\nf_y = 100\ndensity = 720\n')
    assert get_material("beech", extra).E == 14000.0
    bad = tmp_path / "bad.toml"
    bad.write_text('[beech]\nE = -1\nG = 1000\nf_y = 100\ndensity = 720\n')
    with pytest.raises(FablineError, match="beech: E must be a positive number"):
        load_materials(bad)
    bad.write_text("[beech\n")
    with pytest.raises(FablineError, match="malformed TOML"):
        load_materials(bad)
    with pytest.raises(FablineError, match="'unobtainium' is not known"):
        get_material("unobtainium")


@pytest.mark.parametrize("text, message", [("100", "expected HEIGHTxTHICKNESS"), ("1.5x100", "not smaller than height"),
                                           ("0x1", "must be positive"), ("axb", "expected")])
def test_bad_profiles_are_named(text, message):
    with pytest.raises(FablineError, match=message):
        parse_profile(text)


def test_limits_command_prints_the_reference_values(cli):
    code, out, err = cli("limits", "--profile", "100x1.5", "--material", "steel-s235", "--radius", "1060", "--twist", "1.12")
    assert code == 0, err
    assert "670.2 mm" in out and "148.6 N/mm2" in out and "1.117 rad/m" in out and "219.52" in out and "-109.76" in out
    code, out, _ = cli("limits", "--json")
    data = json.loads(out)
    assert round(data["min_bending_radius_mm"]) == 670


def test_limits_command_rejects_bad_input(cli):
    code, _, err = cli("limits", "--radius", "-5")
    assert code == 2 and "--radius: must be positive" in err
    code, _, err = cli("limits", "--material", "nothing")
    assert code == 2 and "'nothing' is not known" in err
    code, _, err = cli("limits", "--profile", "1x100")
    assert code == 2 and "profile" in err


def test_per_interval_check_of_a_circular_lamella(s235):
    import sys
    from pathlib import Path
    from fabline.geometry import analyse
    from fabline.mechanics import check_lamella
    from networks import polar_grid

    radius = 1200.0
    geometry = analyse(polar_grid(radius + 350.0 * np.arange(2), 0.25 * np.arange(5)))
    circle = geometry.lamellas["A-000"]
    check = check_lamella(circle, s235, Profile(100.0, 4.0))
    row = check.summary(s235, Profile(100.0, 4.0))
    assert len(row["intervals"]) == 4
    expected = 210000 * 4.0 / (2 * radius) / 235.0  # sigma = E t k_g / 2 with k_g = 1/R; no twist in a plane
    for interval in row["intervals"]:
        assert interval["k_g_per_m"] == pytest.approx(1000.0 / radius, rel=1e-3)  # spline curvature
        assert interval["bending"] == pytest.approx(expected, abs=1e-3) and interval["shear"] == 0.0
    assert len(check.warnings) == 1 and "lamella A-000, nodes" in check.warnings[0] and "(and 3 more intervals)" in check.warnings[0]


def test_lamellas_checked_together_equal_each_checked_alone(enneper, s235):
    """`check_lamellas` works on all lamellas' samples at once: every number of every lamella's check, warnings
    included, must equal the check of that lamella alone, to the last bit."""
    from fabline.geometry import analyse
    from fabline.mechanics.structure import check_lamella, check_lamellas, helix_edge_extension

    profile = Profile(60.0, 2.0)  # thick enough for some intervals to warn
    geometries = list(analyse(enneper).lamellas.values())
    together = check_lamellas(geometries, s235, profile)
    assert len(together) == len(geometries) and any(check.warnings for check in together)
    for geo, check in zip(geometries, together):
        alone = check_lamella(geo, s235, profile)
        assert check.summary(s235, profile) == alone.summary(s235, profile) and check.warnings == alone.warnings
        for name in ("max_k_g", "max_tau_g", "max_k_n"):
            assert np.array_equal(getattr(check, name), getattr(alone, name))
        assert (check.centre_contraction, check.top_extension) == (alone.centre_contraction, alone.top_extension)
        assert check.top_extension == helix_edge_extension(geo, profile.h / 2.0)
        expected_max = [np.abs(geo.k_g[(geo.s >= a) & (geo.s <= b)]).max()
                        for a, b in zip(geo.node_s[:-1], geo.node_s[1:])]
        assert np.array_equal(check.max_k_g, expected_max)  # samples from node to node, both included
