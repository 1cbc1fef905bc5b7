"""The verdicts' reach: how many nodes a survey did not measure and where, grouped along the lamellas."""

from __future__ import annotations

import numpy as np

from fabline.survey import saddle_network
from fabline.survey.measure import unseen_regions
from fabline.verdicts import reach_text


def test_unseen_nodes_group_along_lamellas():
    """On the saddle's grid (0.5 m), n00-00 and n00-01 are neighbours on lamella A0; n03-03 stands alone."""
    model = saddle_network(2.0, 0.5, 3.0).in_mm()
    regions = unseen_regions(model, ["n03-03", "n00-00", "n00-01"])
    assert [r["nodes"] for r in regions] == [["n00-00", "n00-01"], ["n03-03"]]
    a, b = model.nodes["n00-00"].xyz, model.nodes["n00-01"].xyz
    assert np.allclose(regions[0]["centre_mm"], (a + b) / 2, atol=0.05)
    assert abs(regions[0]["radius_mm"] - 250.0) < 0.1  # half the 0.5 m spacing
    assert regions[1]["radius_mm"] == 0.0 and unseen_regions(model, []) == []


def test_reach_text_counts_and_places_the_unseen_nodes():
    summary = {"nodes": 440, "not_seen": 12}
    regions = [{"nodes": [f"N{i:03d}" for i in range(9)], "centre_mm": [-3240.0, 4110.0, 500.0], "radius_mm": 1420.0},
               {"nodes": ["N100", "N101"], "centre_mm": [2000.0, -1000.0, 0.0], "radius_mm": 175.0},
               {"nodes": ["N200"], "centre_mm": [0.0, 0.0, 0.0], "radius_mm": 0.0}]
    assert reach_text(summary, regions, most=2) == (
        "12 not seen of 440 nodes: 9 around (-3.2, 4.1) m within 1.4 m (N000, N001, N002, ...); "
        "2 around (2.0, -1.0) m within 0.2 m (N100, N101); 1 more in 1 other group(s)")
    assert reach_text({"nodes": 81, "not_seen": 0}, []) == "every one of the 81 nodes seen"
    assert reach_text(summary, None) == "12 not seen of 440 nodes"


def test_the_report_says_where_the_unseen_nodes_are_beside_the_verdicts():
    from pathlib import Path

    from fabline.jobs.report import _survey_section

    summary = {"nodes": 440, "measured": 428, "passed": 386, "failed": 0, "uncertain": 42, "not_seen": 12,
               "k_sigma": 2.0, "photos": 40, "photos_used": 40, "rms_deviation_mm": 4.04, "max_deviation_mm": 9.96,
               "worst": ["N1-1"], "reprojection_rms_px": 0.3}
    regions = [{"nodes": [f"N{i:03d}" for i in range(12)], "centre_mm": [-3240.0, 4110.0, 500.0], "radius_mm": 1420.0}]
    survey = {"summary": summary, "tolerance_mm": 10.0, "deviation_map": None, "file": "survey.json", "scale": None,
              "reference": "all", "registration_rms_mm": 4.0, "truth": None, "not_seen": {}, "problems": [],
              "not_seen_regions": regions}
    text = _survey_section(survey, Path("."))
    assert ("386 pass, 0 fail, 42 uncertain, 12 not seen of 440 nodes" in text
            and "12 not seen of 440 nodes: 12 around (-3.2, 4.1) m within 1.4 m (N000, N001, N002, ...)" in text)
