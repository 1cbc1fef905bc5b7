"""The bracing cables: one run along every diagonal through the clamps, checked against the Enneper grid's own
node numbering (an independent way to find the diagonals), chord lengths worked out here, and the cut-length rule."""

from __future__ import annotations

import re

import numpy as np
import pytest

from fabline.errors import FablineError
from fabline.unroll import UnrollOptions, unroll_network
from fabline.unroll.cables import parse_pretension
from fabline.unroll.parts import load_parts, save_parts

H, T = 100.0, 1.5
LIFT = H / 2 + 2 * T + (15.0 - 6.5 - 1.0)  # half height, top washer, clamp plate, the folded tip's hole height


@pytest.fixture(scope="module")
def pavilion(enneper):
    return unroll_network(enneper, UnrollOptions(cable_pretension=2.0, cable_end_allowance=100.0))


def _grid(node: str) -> tuple[int, int]:
    a, b = re.fullmatch(r"N(\d+)-(\d+)", node).groups()
    return int(a), int(b)


def _runs_by_numbering(enneper, clamped: set[str]) -> list[list[str]]:
    """The diagonals from the design's grid numbers N<i>-<j>: a step is (i+1, j+1) or (i+1, j-1) between clamp nodes
    whose quad's two other corners exist; maximal chains of such steps, each as its node list."""
    ids = set(enneper.nodes)
    name = {_grid(n): n for n in ids}
    chains = []
    for dj in (1, -1):
        steps = {}
        for node in clamped:
            i, j = _grid(node)
            nxt = name.get((i + 1, j + dj))
            if nxt in clamped and (i + 1, j) in name and (i, j + dj) in name:
                steps[node] = nxt
        starts = set(steps) - set(steps.values())
        for start in starts:
            chain = [start]
            while chain[-1] in steps:
                chain.append(steps[chain[-1]])
            chains.append(chain)
    return chains


def test_cables_run_along_every_clamped_diagonal_as_the_grid_numbers_say(enneper, pavilion):
    clamped = {p.meta["node"] for p in pavilion.parts if p.kind == "clamp"}
    expected = _runs_by_numbering(enneper, clamped)
    got = pavilion.cables
    assert sorted(sorted(c) for c in expected) == sorted(sorted(r["nodes"]) for r in got)
    assert len(got) == 36
    # every clamp holds one or two cables (two where both its diagonals go on): its cable holes are used
    through = {}
    for run in got:
        for node in run["nodes"]:
            through[node] = through.get(node, 0) + 1
    assert set(through) == clamped and set(through.values()) <= {1, 2}
    assert sum(v == 2 for v in through.values()) > 0.8 * len(clamped)


def test_cable_lengths_are_the_chords_through_the_lifted_clamp_points(enneper, pavilion):
    mm = enneper.in_mm()
    total = 0.0
    for run in pavilion.cables:
        points = [mm.nodes[n].xyz + LIFT * mm.nodes[n].normal for n in run["nodes"]]
        chords = [float(np.linalg.norm(b - a)) for a, b in zip(points[:-1], points[1:])]
        assert run["geometric_length_mm"] == pytest.approx(sum(chords), abs=0.1)
        assert run["clamp_positions_mm"] == pytest.approx(np.concatenate([[0.0], np.cumsum(chords)]), abs=0.1)
        # cut: 2 mm/m shorter, plus 100 mm beyond each end clamp
        assert run["cut_length_mm"] == pytest.approx(sum(chords) * 0.998 + 200.0, abs=0.1)
        assert [a["part"] for a in run["anchors"]] == [f"C-{run['nodes'][0]}", f"C-{run['nodes'][-1]}"]
        total += sum(chords)
    summary = pavilion.report["cables"]
    assert summary["geometric_length_m"] == pytest.approx(total / 1000.0, abs=0.005)
    assert summary["clamp_lift_mm"] == pytest.approx(LIFT)
    # the done-when: the cut total within 10 % of the geometric one
    assert abs(summary["cut_length_m"] - summary["geometric_length_m"]) < 0.1 * summary["geometric_length_m"]
    # every end anchors where the diagonal leaves the grid: the run cannot go on past it
    ends = {lam.nodes[0] for lam in enneper.lamellas} | {lam.nodes[-1] for lam in enneper.lamellas}
    anchors = [a for run in pavilion.cables for a in run["anchors"]]
    assert sum(a["on_boundary"] for a in anchors) == sum(a["node"] in ends for a in anchors) > len(anchors) / 2


def test_cables_go_through_parts_json_and_back(pavilion, tmp_path):
    save_parts(pavilion, tmp_path / "parts.json")
    again = load_parts(tmp_path / "parts.json")
    assert again.cables == pavilion.cables


def test_no_hardware_no_cables(enneper):
    plain = unroll_network(enneper, UnrollOptions(hardware=False))
    assert plain.cables == [] and "cables" not in plain.report


@pytest.mark.parametrize("text, strain", [("1 mm/m", 1.0), ("0.1 %", 1.0), (2, 2.0), ("1.5permille", 1.5),
                                          ("0", 0.0)])
def test_pretension_forms(text, strain):
    assert parse_pretension(text, "x") == pytest.approx(strain)


@pytest.mark.parametrize("text", ["tight", "-1 mm/m", "15 %", True, "1 mm"])
def test_bad_pretension_is_one_line_naming_the_key(text):
    with pytest.raises(FablineError, match=r"^unroll.cable_pretension: ") as caught:
        parse_pretension(text, "unroll.cable_pretension")
    assert "\n" not in str(caught.value)
