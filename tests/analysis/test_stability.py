"""Whether the frame stands: supports that leave a rigid-body motion are refused, and the erection's own stresses
buckle a frame whose cables pull too hard, refused with the pretension it stands with, which is checked by building
the frame just under and just over it."""

import re

import numpy as np
import pytest

from fabline.analysis.frame import FIXED, PINNED, Section, chain
from fabline.analysis.model import ModelOptions, bracing, build
from fabline.analysis.stability import erection_stability
from fabline.errors import FablineError
from fabline.geometry.darboux import analyse
from fabline.mechanics.hardware import load_catalogue
from fabline.mechanics.materials import Profile, get_material
from fabline.model.designs import enneper_network

SECTION = Section(E=210000.0, G=81000.0, h=100.0, t=1.5, density=7850.0)


def bent(n: int = 6):
    """A strip bent up in a quarter circle and back along y: supports on and off one line."""
    theta = np.linspace(0.0, np.pi / 2, n + 1)
    points = np.column_stack([1000 * np.sin(theta), 300 * np.sin(2 * theta), 1000 * (1 - np.cos(theta))])
    return chain(points, np.tile([0.0, 0.0, 1.0], (n + 1, 1)), SECTION)


@pytest.mark.parametrize("supports, free", [({0: PINNED, 6: PINNED}, 1), ({0: FIXED, 6: PINNED}, 0),
                                            ({0: PINNED, 3: PINNED, 6: PINNED}, 0), ({0: PINNED}, 3), ({}, 6)],
                         ids=["two pinned", "one fixed", "three pinned off a line", "one pinned", "none"])
def test_rigid_body_motions_the_supports_leave(supports, free):
    frame = bent()
    frame.supports = supports
    assert frame.rigid_motions() == free


def test_two_pinned_supports_are_refused_naming_them():
    frame = bent()
    frame.supports = {0: PINNED, 6: PINNED}
    with pytest.raises(FablineError, match=r"supports \(2: S:0, S:6\) leave the shell 1 rigid-body motion"):
        erection_stability(frame)


def small_frame(pretension_mm_per_m: float):
    network = enneper_network((3.0, 4.0), 0.35, 1.05).in_mm()
    options = ModelOptions(stations=2, cables=bracing(network), cable=load_catalogue().cable,
                           cable_prestrain=pretension_mm_per_m / 1000.0)
    return build(analyse(network), Section.of(get_material("stainless"), Profile(100.0, 1.5)), options).frame


def test_cables_pulled_too_hard_are_refused_with_the_pretension_the_frame_stands_with():
    """At 5 mm/m the 3 x 4 m design buckles under its erection; the refusal names the pretension where it would buckle,
    and the frame stands at 0.95 of that and is refused at 1.05 of it."""
    with pytest.raises(FablineError) as refused:
        erection_stability(small_frame(5.0))
    said = str(refused.value)
    assert "does not stand" in said and "the cables' pretension (5 mm/m" in said
    limit = float(re.search(r"a pretension under ([0-9.]+) mm/m", said).group(1))
    assert 0.0 < limit < 5.0
    assert erection_stability(small_frame(0.95 * limit)).factor > 1.0
    with pytest.raises(FablineError, match="does not stand"):
        erection_stability(small_frame(1.05 * limit))


def test_couplers_tie_the_pairs_strips_at_their_intervals_middle():
    """Each coupled interval adds one link between the L and R strips' middle stations, a pair spacing apart, halfway
    between the interval's two nodes; with one beam per interval there is no middle and no link."""
    from fabline.unroll.couplers import coupler_intervals

    network = enneper_network((3.0, 4.0), 0.35, 1.05).in_mm()
    section = Section.of(get_material("stainless"), Profile(100.0, 1.5))
    intervals = tuple(coupler_intervals(network, 1))
    plain = build(analyse(network), section, ModelOptions(stations=2)).frame
    coupled = build(analyse(network), section, ModelOptions(stations=2, couplers=intervals)).frame
    named = lambda frame: {(frame.names[a], frame.names[b]) for a, b in frame.links}
    added = named(coupled) - named(plain)
    assert named(plain) <= named(coupled) and len(intervals) > 0 and len(added) == len(intervals)
    position = {name: p for name, p in zip(coupled.names, coupled.xyz)}
    for lamella, first, second in intervals:
        link = [(a, b) for a, b in added if a.startswith(f"{lamella}-L:") and b.startswith(f"{lamella}-R:")]
        assert len(link) == 1, (lamella, first, second)
        a, b = (position[name] for name in link[0])
        assert np.linalg.norm(a - b) == pytest.approx(25.0, rel=0.01)
        middle = (a + b) / 2.0
        assert np.linalg.norm(middle - network.nodes[first].xyz) == pytest.approx(
            np.linalg.norm(middle - network.nodes[second].xyz), rel=0.15)
    single = build(analyse(network), section, ModelOptions(stations=1, couplers=intervals)).frame
    assert len(single.links) == len(build(analyse(network), section, ModelOptions(stations=1)).frame.links)
