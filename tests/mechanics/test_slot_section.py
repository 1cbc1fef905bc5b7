"""The net section at a slot (issue 28, item 7) against hand computations, and how unroll reports it."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from fabline.errors import FablineError
from fabline.mechanics import get_material
from fabline.mechanics.materials import Profile
from fabline.mechanics.slots import check_slots
from fabline.mechanics.structure import check_lamella, verdict_lines
from fabline.unroll import UnrollOptions, unroll_network
from networks import polar_grid

PROFILE = Profile(100.0, 1.5)


def lamella(k_g: list[float], tau_g: list[float]) -> SimpleNamespace:
    """A straight 2 m lamella with nodes N0, N1, N2 at 0, 1000, 2000 mm and these curvatures (1/mm) at 0..2000 mm,
    sampled every 500 mm."""
    s = np.linspace(0.0, 2000.0, 5)
    return SimpleNamespace(s=s, k_g=np.array(k_g), tau_g=np.array(tau_g), k_n=np.zeros(5),
                           node_ids=["N0", "N1", "N2"], node_s=np.array([0.0, 1000.0, 2000.0]),
                           lamella=SimpleNamespace(id="L"), length=2000.0)


def test_a_slot_by_hand():
    """S235, 100 x 1.5, slot depth 51 mm (h/2 + 1): h_net = 49 mm. At N1 k_g = 1/2000 /mm, tau_g = 0.5 /m.
    By hand: sigma_b = 210000 x 1.5 / (2 x 2000) = 78.75, x 100/49 = 160.714; tau = 81000 x 1.5 x 0.0005 = 60.75,
    x 100/49 = 123.980; helix at the free edge (r = 50) 0.5 x 210000 x (2500 - 833.333) x 0.5e-3^2 = 43.750, at the
    slot root (r = 1, the fibre nearest the axis) 0.5 x 210000 x (1 - 833.333) x 0.25e-6 = -21.849.
    Edge 160.714 + 43.750 = 204.464; root sqrt((160.714 + 21.849)^2 + 3 x 123.980^2) = 281.857 N/mm2: 119.94 %."""
    s235 = get_material("steel-s235")
    geo = lamella([0.0, 0.0, 1.0 / 2000.0, 0.0, 0.0], [0.0, 0.0, 0.5e-3, 0.0, 0.0])
    check = check_slots(geo, ["N1"], s235, PROFILE, 51.0)
    assert check.net_height == 49.0 and check.node_ids == ["N1"]
    assert check.use["bending"][0] == pytest.approx(160.714 / 235.0, abs=1e-5)
    assert check.use["shear"][0] == pytest.approx(123.980 / (235.0 / math.sqrt(3.0)), abs=1e-5)
    assert check.use["helix"][0] == pytest.approx(43.750 / 235.0, abs=1e-5)
    assert check.use["combined"][0] == pytest.approx(281.857 / 235.0, abs=1e-5)
    assert check.summary()["slot_utilisation"] == 1.1994 and check.summary()["slot_node"] == "N1"


def test_the_node_takes_its_own_curvature_not_its_intervals_maximum():
    """The slot at N1 sees k_g interpolated at 1000 mm (1/4000), though its intervals reach 1/1000 at 500 mm."""
    s235 = get_material("steel-s235")
    geo = lamella([0.0, 1.0 / 1000.0, 1.0 / 4000.0, 0.0, 0.0], [0.0] * 5)
    check = check_slots(geo, ["N1"], s235, PROFILE, 51.0)
    assert check.k_g[0] == pytest.approx(1.0 / 4000.0)
    assert check.utilisation == pytest.approx(210000 * 1.5 / (2 * 4000) * 100 / 49 / 235)


def test_the_slot_governs_a_bent_ring_and_the_verdict_says_local_yielding():
    """Circles of 1200 and 1550 mm bent about the weak axis, radial lines straight: between joints the 1200 mm ring
    is at E t k / 2 / f_y = 55.9 %, at a slot x 100/49 = 114.1 %: over yield there alone, said as local yielding at
    the joints; unroll goes on with a warning (as over yield between joints does), `strict` refuses."""
    network = polar_grid(1200.0 + 350.0 * np.arange(2), 0.25 * np.arange(4))
    parts = unroll_network(network, UnrollOptions(pair_spacing=0.0))
    rows = {row["lamella"]: row for row in parts.report["lamellas"]}
    inner = rows["A-000"]
    between = 210000 * 1.5 / (2 * 1200) / 235
    assert inner["utilisation"] == pytest.approx(between, rel=1e-3) and inner["passes"] is True
    assert inner["slot_utilisation"] == pytest.approx(between * 100 / 49, rel=1e-3) and inner["slot_passes"] is False
    assert inner["slot_node"] in next(lam for lam in network.lamellas if lam.id == "A-000").nodes
    assert rows["A-001"]["slot_utilisation"] == pytest.approx(210000 * 1.5 / (2 * 1550) / 235 * 100 / 49, rel=1e-3)
    assert rows["B-000"]["slot_utilisation"] == pytest.approx(0.0, abs=1e-6)  # straight and untwisted
    verdict = parts.report["verdict"]
    assert verdict["passes"] is True and verdict["slots"]["over"] == ["A-000"]
    lines = verdict_lines(verdict)
    assert "all 6 lamellas pass the combined check" in lines[0] and "at the slots 1 of 6 lamellas exceed yield locally" in lines[0]
    assert "local yielding of the lamella at the joints" in lines[1] and "washers' restraint ignored" in lines[1]
    assert any("slot at node" in w and "local yielding at the joint" in w for w in parts.report["warnings"])
    with pytest.raises(FablineError, match="slot at node"):
        unroll_network(network, UnrollOptions(pair_spacing=0.0, strict=True))


def test_the_slot_does_not_govern_where_the_curvature_peaks_between_joints():
    """A lamella whose k_g peaks between nodes (1/700 /mm at 500 mm) and is low at its slot node N1 (1/8000): the
    slot's 21.4 % stays under the lamella's own 95.7 % between the joints."""
    s235 = get_material("steel-s235")
    geo = lamella([0.0, 1.0 / 700.0, 1.0 / 8000.0, 0.0, 0.0], [0.0] * 5)
    check = check_slots(geo, ["N1"], s235, PROFILE, 51.0)
    between = 210000 * 1.5 / (2 * 700) / 235
    assert check_lamella(geo, s235, PROFILE).utilisation == pytest.approx(between)
    assert check.utilisation == pytest.approx(210000 * 1.5 / (2 * 8000) * 100 / 49 / 235)
    assert check.utilisation < between


def test_a_passing_slot_verdict_is_said_within_yield():
    network = polar_grid(3000.0 + 350.0 * np.arange(2), 0.1 * np.arange(4))
    parts = unroll_network(network, UnrollOptions(pair_spacing=0.0))
    lines = verdict_lines(parts.report["verdict"])
    assert parts.report["verdict"]["slots"]["passes"] is True
    assert "at the slots within yield" in lines[0] and "every lamella's net section at its slots" in lines[1]
    assert not any("slot at node" in w for w in parts.report["warnings"])


def test_lamellas_without_slots_have_no_slot_verdict():
    """One straight lamella crosses nothing: no slot node, no slot line in the verdict."""
    from networks import network_of

    x = np.linspace(0.0, 2000.0, 41)
    points = np.column_stack([x, np.zeros_like(x), np.zeros_like(x)])
    network = network_of([("A-000", "A", points, np.tile([0.0, 0.0, 1.0], (41, 1)), [0, 20, 40])])
    parts = unroll_network(network, UnrollOptions(pair_spacing=0.0))
    row = parts.report["lamellas"][0]
    assert row["slot_nodes"] == 0 and row["slot_node"] is None and row["slot_passes"] is True
    assert parts.report["verdict"]["slots"] is None
    assert len(verdict_lines(parts.report["verdict"])) == 1 and "slot" not in verdict_lines(parts.report["verdict"])[0]
