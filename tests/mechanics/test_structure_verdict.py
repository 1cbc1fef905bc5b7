"""One structural verdict said where the designer looks: the combined limit of a lamella against a hand computation
from domain.md section 6, remedies that (plugged back into the check) land on 100 %, and the design quality report,
`fabline unroll`, `fabline run` and the job report saying the same words for one small design over the limit."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from fabline.design.quality import quality_report, summary_lines
from fabline.geometry import analyse
from fabline.mechanics.materials import Profile, get_material
from fabline.model import save_network
from fabline.model.designs import enneper_network
from fabline.mechanics.structure import (check_lamellas, combined_radius_limit, combined_twist_limit,
                                         structural_verdict, verdict_lines)

STAINLESS = get_material("stainless")
PROFILE = Profile(100.0, 1.5)
SMALL = {"size": (3.0, 3.0), "spacing": 0.4, "k_max": 1.12}  # 14 lamellas, 37 nodes; the centre twists 1.12 rad/m


def hand_utilisation(material, h, t, k_g, kappa):
    """domain.md 6: sigma_b = E t k_g / 2, tau = G t kappa, sigma_H,min = -E i_p^2 kappa^2 / 2 and
    sigma_H,max = E (h^2/4 - i_p^2) kappa^2 / 2 with i_p^2 = h^2/12; the worse of the edge (sigma_b + sigma_H,max)
    and the face centre (von Mises of sigma_b + |sigma_H,min| with tau), over f_y. Curvatures in 1/mm."""
    sigma_b, tau = material.E * t * k_g / 2, material.G * t * kappa
    i_p_sq = h * h / 12
    low, high = -material.E * i_p_sq * kappa ** 2 / 2, material.E * (h * h / 4 - i_p_sq) * kappa ** 2 / 2
    return max(sigma_b + high, math.sqrt((sigma_b - low) ** 2 + 3 * tau ** 2)) / material.f_y


def hand_pure_twist_limit(material, h, t):
    """Face centre in pure twist, (E h^2/24 x)^2 + 3 (G t)^2 x = f_y^2 in x = kappa^2 (the quadratic formula);
    the edge's E h^2/12 kappa^2 stays below f_y there."""
    a, b = (material.E * h * h / 24) ** 2, 3 * (material.G * t) ** 2
    x = (-b + math.sqrt(b * b + 4 * a * material.f_y ** 2)) / (2 * a)
    assert material.E * h * h / 12 * x < material.f_y
    return math.sqrt(x)


@pytest.fixture(scope="module")
def small():
    network = enneper_network(**SMALL)
    checks = check_lamellas(list(analyse(network).lamellas.values()), STAINLESS, PROFILE)
    return network, checks, structural_verdict(checks, STAINLESS, PROFILE, network.meta["k_max"])


def test_the_combined_twist_limit_of_the_pavilion_stainless_by_hand():
    """About 1.053 rad/m for 100 x 1.5 mm stainless (against 1.150 for shear alone); for S235 it is below the
    thesis's 1.12 rad/m, where domain.md's reference stresses give 111 % at the face centre."""
    kappa = hand_pure_twist_limit(STAINLESS, 100.0, 1.5)
    assert kappa * 1000 == pytest.approx(1.0529, abs=5e-4)
    assert combined_twist_limit(STAINLESS, PROFILE) == pytest.approx(kappa, rel=1e-9)
    assert hand_utilisation(STAINLESS, 100.0, 1.5, 0.0, kappa) == pytest.approx(1.0, abs=1e-12)
    s235 = get_material("steel-s235")
    assert combined_twist_limit(s235, PROFILE) * 1000 < 1.12
    assert math.hypot(109.76, math.sqrt(3) * 81000 * 1.5 * 1.12e-3) / 235 == pytest.approx(1.11, abs=0.005)


@pytest.mark.parametrize("radius_mm, twist_per_m", [(5131.0, 1.0245), (2000.0, 0.6), (900.0, 0.3)])
def test_twist_at_a_radius_and_radius_at_a_twist_land_on_100_percent_by_hand(radius_mm, twist_per_m):
    kappa = combined_twist_limit(STAINLESS, PROFILE, 1.0 / radius_mm)
    assert hand_utilisation(STAINLESS, 100.0, 1.5, 1.0 / radius_mm, kappa) == pytest.approx(1.0, abs=1e-9)
    radius = combined_radius_limit(STAINLESS, PROFILE, twist_per_m / 1000)
    assert hand_utilisation(STAINLESS, 100.0, 1.5, 1.0 / radius, twist_per_m / 1000) == pytest.approx(1.0, abs=1e-9)
    assert radius > STAINLESS.E * 1.5 / (2 * STAINLESS.f_y)  # twisted, the strip may bend less than r_min


def test_limits_names_the_combined_twist_limit_beside_the_shear_one(cli):
    code, out, _ = cli("limits", "--material", "stainless", "--profile", "100x1.5")
    pure = hand_pure_twist_limit(STAINLESS, 100.0, 1.5) * 1000
    assert code == 0 and f"1.150 rad/m (65.9 deg/m) by shear alone; {pure:.3f} rad/m by the combined check" in out


def test_no_radius_passes_a_twist_over_the_pure_twist_limit():
    assert combined_radius_limit(STAINLESS, PROFILE, 1.1e-3) is None
    assert combined_twist_limit(STAINLESS, PROFILE, 1.0 / 600.0) == 0.0  # bent below r_min = 652 mm


def test_the_verdict_names_the_failing_lamellas_and_the_worst_ones_limits_by_hand(small):
    network, checks, verdict = small
    hand = {c.lamella: max(hand_utilisation(STAINLESS, 100.0, 1.5, g, k) for g, k in zip(c.max_k_g, c.max_tau_g))
            for c in checks}
    assert verdict["failing"] == [name for name, use in hand.items() if use > 1.0] and not verdict["passes"]
    worst = max(hand, key=hand.get)
    assert verdict["lamella"] == worst and verdict["max_utilisation"] == pytest.approx(hand[worst], abs=1e-4)
    assert verdict["twist_rad_per_m"] == pytest.approx(1.12, abs=1e-4) and verdict["radius_mm"] is None  # the straight axis
    limits = verdict["limits"]
    pure = hand_pure_twist_limit(STAINLESS, 100.0, 1.5) * 1000
    assert limits["twist_at_radius_rad_per_m"] == pytest.approx(pure, rel=1e-9)
    assert limits["twist_straight_rad_per_m"] == pytest.approx(pure, rel=1e-9)
    assert limits["radius_at_twist_mm"] is None  # 1.12 rad/m alone exceeds yield
    assert limits["radius_untwisted_mm"] == pytest.approx(200000 * 1.5 / (2 * 230))
    assert limits["shear_alone_twist_rad_per_m"] == pytest.approx(230 / math.sqrt(3) / (77000 * 1.5) * 1000)
    head, limit, remedies = verdict_lines(verdict)
    assert head.startswith(f"structure: {len(verdict['failing'])} of {len(checks)} lamellas exceed yield")
    assert all(name in head for name in verdict["failing"])
    assert f"in pure twist {pure:.3f} rad/m" in limit and "shear alone would allow 1.150" in limit
    assert "remedies" in remedies


def test_each_remedy_plugged_back_into_the_check_gives_100_percent(small):
    """Curvatures scaled, a thinner strip, a lower strip, a higher f_y: each checked again from the geometry."""
    network, checks, verdict = small
    r = verdict["remedies"]
    geometries = list(analyse(network).lamellas.values())

    def worst(material, profile):
        return max(c.utilisation for c in check_lamellas(geometries, material, profile))

    k_g = np.concatenate([c.max_k_g for c in checks]) * r["scale"]
    twist = np.concatenate([c.max_tau_g for c in checks]) * r["scale"]
    assert max(hand_utilisation(STAINLESS, 100.0, 1.5, g, k) for g, k in zip(k_g, twist)) == pytest.approx(1.0, abs=1e-6)
    assert r["k_max_per_m"] == pytest.approx(r["scale"] * SMALL["k_max"]) and r["k_max_of"] == "design"
    assert worst(STAINLESS, Profile(100.0, r["t_mm"])) == pytest.approx(1.0, abs=1e-6)
    assert worst(STAINLESS, Profile(r["h_mm"], 1.5)) == pytest.approx(1.0, abs=1e-6)
    assert worst(replace(STAINLESS, f_y=r["f_y"]), PROFILE) == pytest.approx(1.0, abs=1e-6)
    assert 1.3 < r["t_mm"] < 1.5 and 60 < r["h_mm"] < 100 and 230 < r["f_y"] < 260
    # the design rebuilt on its footprint at the printed (rounded down) k_max passes
    printed = float(verdict_lines(verdict)[2].split("k_max ")[1].split(" ")[0])
    rebuilt = enneper_network(**{**SMALL, "k_max": printed})
    assert max(c.utilisation for c in check_lamellas(list(analyse(rebuilt).lamellas.values()), STAINLESS, PROFILE)) <= 1.0


def test_a_twist_whose_helix_stress_alone_exceeds_yield_has_no_thinner_strip():
    """At 1.5 rad/m the helix edge stress E h^2 kappa^2 / 12 = 375 N/mm2 > 230 whatever t; the shear and bending
    stress sqrt(3) G t kappa = 300 N/mm2 > 230 whatever h: only the curvature and f_y remedies remain."""
    network = enneper_network(**{**SMALL, "k_max": 1.5})
    checks = check_lamellas(list(analyse(network).lamellas.values()), STAINLESS, PROFILE)
    verdict = structural_verdict(checks, STAINLESS, PROFILE, 1.5)
    assert 200000 * 100 ** 2 / 12 * 1.5e-3 ** 2 > 230 and math.sqrt(3) * 77000 * 1.5 * 1.5e-3 > 230
    assert verdict["remedies"]["t_mm"] is None and verdict["remedies"]["h_mm"] is None
    text = verdict_lines(verdict)[2]
    assert "no thinner strip" in text and "no lower strip" in text and "f_y 375 N/mm2" in text


def test_design_unroll_run_and_report_say_the_same_verdict(small, tmp_path, cli):
    network, checks, verdict = small
    design_said = verdict_lines(verdict)
    assert not verdict["passes"]
    quality = quality_report(network, material="stainless", profile="100x1.5")
    assert quality["structure"] == verdict
    lines = summary_lines(quality, "m")
    assert lines[-3:] == design_said
    assert f"combined limit there {verdict['limits']['twist_at_radius_rad_per_m']:.3f} rad/m" in lines[-5]

    model = tmp_path / "small.network.json"
    save_network(network, model)
    code, out, _ = cli("unroll", model, "-o", tmp_path / "parts.json", "--material", "stainless", "--no-hardware")
    unrolled = json.loads((tmp_path / "parts.json").read_text())["report"]["verdict"]
    verdict = {**verdict, "slots": unrolled["slots"]}  # the slots are unroll's (their depth is its choice)
    said = verdict_lines(verdict)
    assert said[0].startswith(design_said[0] + "; at the slots ") and said[1].startswith("  at the joints: ")
    assert said[2:] == design_said[1:]
    assert code == 0 and out.splitlines()[-4:] == said

    job = tmp_path / "small.toml"
    job.write_text('name = "small"\nstages = ["unroll", "report"]\n[model]\ndesign = "enneper"\n[model.options]\n'
                   f'size = [3.0, 3.0]\nspacing = {SMALL["spacing"]}\nk_max = {SMALL["k_max"]}\n'
                   '[lamella]\nmaterial = "stainless"\nprofile = "100x1.5"\n[output]\nfolder = "out"\n', encoding="utf-8")
    code, out, _ = cli("run", job)
    printed = out.splitlines()
    assert code == 0 and printed[printed.index(said[0]) + 1:printed.index(said[0]) + 4] == said[1:]
    assert printed[-5:-1] == said  # the summary at the end says it again, above the report's path
    data = json.loads((tmp_path / "out" / "report.json").read_text())
    assert verdict_lines(data["structure"]["verdict"]) == said
    page = (tmp_path / "out" / "report.html").read_text()
    import html

    for line in said:
        assert html.escape(line.strip().removeprefix("structure: ")) in page
    summary = page[page.index("<table id=summary"):page.index("</table>", page.index("<table id=summary"))]
    assert html.escape(said[0].removeprefix("structure: ")) in summary and "class=fail" in summary


def test_the_example_job_passes_its_own_structural_check():
    """jobs/pavilion.toml: the 9 x 12 m Enneper pavilion in 100 x 1.5 mm stainless, at a k_max its centre
    lamellas' pure twist can take (1.05 < 1.053 rad/m)."""
    from pathlib import Path

    from fabline.jobs.jobfile import load_job_file
    from fabline.jobs.pipeline import build_network
    from fabline.mechanics.materials import parse_profile

    spec = load_job_file(Path(__file__).resolve().parents[2] / "jobs" / "pavilion.toml")
    network = build_network(spec)
    material, profile = get_material(spec.lamella["material"]), parse_profile(spec.lamella["profile"])
    checks = check_lamellas(list(analyse(network).lamellas.values()), material, profile)
    verdict = structural_verdict(checks, material, profile, network.meta["k_max"])
    assert spec.model["options"]["size"] == (9.0, 12.0) and len(network.lamellas) == 58
    assert verdict["passes"] and 0.99 < verdict["max_utilisation"] <= 1.0
    assert network.meta["k_max"] < hand_pure_twist_limit(material, profile.h, profile.t) * 1000


def test_a_network_file_from_before_the_combined_check_is_not_read_as_combined(small):
    network, _, _ = small
    old = quality_report(network, material="stainless")
    del old["structure"]
    lines = summary_lines(old, "m")
    assert lines[-1].startswith("structural check: not in this file") and not any("combined" in line for line in lines)
