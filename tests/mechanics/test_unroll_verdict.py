"""One structural verdict: the combined check (von Mises at the face centre, bending plus helix at the edge fibre)
decides pass or fail, in the unroll report, its warnings, the job report's words and colours, and `fabline limits`;
no value over a limit is ever shown rounded down onto it."""

from __future__ import annotations

import math
import re

import pytest

from fabline.mechanics import get_material
from fabline.mechanics.materials import Profile
from fabline.mechanics.structure import percent
from fabline.unroll import UnrollOptions, unroll_network


@pytest.mark.parametrize("value, text", [(1.003, "100.3 %"), (0.997, "99.7 %"), (0.99996, "99.996 %"),
                                         (1.0, "100 %"), (0.5, "50 %"), (1.04, "104 %"), (0.0, "0 %")])
def test_percent_never_rounds_onto_or_across_the_limit(value, text):
    assert percent(value) == text


def test_limits_shows_shear_over_the_limit_and_the_combined_verdict(cli):
    """At 1.12 rad/m the 100 x 1.5 S235 shear is 136.08 / 135.68 = 100.3 %, and with the helix contraction of
    109.76 N/mm2 at the face centre the von Mises stress is 111 % of f_y (thesis 6.6, 6.11)."""
    code, out, _ = cli("limits", "--profile", "100x1.5", "--material", "steel-s235", "--twist", "1.12")
    assert code == 0
    assert "(100.3 %)" in out and "(100 %)" not in out
    tau = 81000 * 1.5 * 1.12e-3
    sigma_min = 0.5 * 210000 * (100**2 + 1.5**2) / 12 * 1.12e-3**2
    combined = math.sqrt(sigma_min**2 + 3 * tau**2) / 235
    assert f"{100 * combined:.0f} % of f_y, OVER YIELD" in out


@pytest.fixture(scope="module")
def pavilion_parts(enneper):
    return unroll_network(enneper, UnrollOptions(material=get_material("stainless"), profile=Profile(100.0, 1.5),
                                                 hardware=False))


def test_the_combined_overstress_of_the_pavilion_centre_fails_and_warns(enneper, pavilion_parts):
    """The Enneper axes are straight (k_g = 0) and twist by k_max = 1.1 /m at the centre: the closed form of the
    face-centre von Mises stress there is the centre lamella's combined utilisation, and it is over yield."""
    stainless = get_material("stainless")
    kappa = enneper.meta["k_max"] / 1000.0
    tau = stainless.G * 1.5 * kappa
    sigma_min = 0.5 * stainless.E * (100**2 + 1.5**2) / 12 * kappa**2
    expected = math.sqrt(sigma_min**2 + 3 * tau**2) / stainless.f_y
    centre = f"A-{enneper.meta['grid']['b'].index(0.0):03d}"
    rows = {row["lamella"]: row for row in pavilion_parts.report["lamellas"]}
    row = rows[centre]
    assert row["utilisation_combined"] == pytest.approx(expected, rel=2e-3) and expected > 1.0
    assert row["utilisation"] == row["utilisation_combined"] and row["governing"] == "combined"
    assert row["passes"] is False
    for other in rows.values():
        assert other["passes"] == (max(other[f"utilisation_{k}"] for k in ("bending", "shear", "helix", "combined")) <= 1.0)
    warning = next(line for line in pavilion_parts.report["warnings"] if line.startswith(f"lamella {centre},"))
    assert "combined stress" in warning and percent(row["utilisation_combined"]) in warning


def test_the_job_report_says_colours_and_lists_by_the_same_rule(pavilion_parts):
    from fabline.jobs.report import _structure_table
    from fabline.mechanics.structure import VERDICT_RULE

    rows = [{k: v for k, v in row.items() if k != "intervals"} for row in pavilion_parts.report["lamellas"]]
    failing = [row["lamella"] for row in rows if not row["passes"]]
    page = _structure_table({"lamellas": rows, "max_utilisation": max(r["utilisation"] for r in rows),
                             "failing": failing, "passes": not failing, "rule": VERDICT_RULE,
                             "verdict": pavilion_parts.report["verdict"]})
    assert failing and f"{len(failing)} of {len(rows)} lamellas exceed yield" in page and "lamellas pass" not in page
    assert "von Mises" in page
    coloured = re.findall(r"<tr class=(\w+)><td>([^<]+)</td>", page)
    assert len(coloured) == len(rows)
    for css, lamella in coloured:
        assert (css == "fail") == (lamella in failing), lamella
