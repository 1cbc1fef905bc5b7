"""The survey stage's comparison with the truth on hand-made records (no photos): known errors come out exactly."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fabline.errors import FablineError
from fabline.jobs.survey_stage import compare_with_truth
from fabline.survey.camera import parse_resolution
from fabline.survey import sag_field, saddle_network


@pytest.fixture(scope="module")
def shell():
    """A 3 m saddle (corner supports) with a 30 mm sag: ids, kinds, design and built positions in mm."""
    network = saddle_network(3.0, 0.5, 4.0).in_mm()
    ids, design, _ = network.node_array()
    kinds = [network.nodes[n].kind for n in ids]
    return network, ids, design, design + sag_field(design, kinds, 30.0)


def record_and_truth(ids, design, built, measured_deviation, reference, tolerance=10.0):
    distance = np.linalg.norm(measured_deviation, axis=1)
    record = {"tolerance_mm": tolerance, "registration": {"reference": reference},
              "nodes": {n: {"deviation_mm": d.tolist(), "verdict": "pass" if r <= tolerance else "fail"}
                        for n, d, r in zip(ids, measured_deviation, distance)}}
    truth = {"deviation": {"kind": "sag", "amplitude_mm": 30.0},
             "nodes": {n: {"design_mm": p.tolist(), "built_mm": b.tolist()} for n, p, b in zip(ids, design, built)}}
    return record, truth


def test_supports_reference_compares_with_the_injected_sag_itself(shell):
    """Sag zero at the supports: the truth's registration is the identity, the error is exactly the added one."""
    network, ids, design, built = shell
    error = np.zeros((len(ids), 3))
    error[::3, 0] = 1.5  # every third node measured 1.5 mm off along x
    record, truth = record_and_truth(ids, design, built, built - design + error, "supports")
    result = compare_with_truth(record, truth, network)
    assert result["nodes_compared"] == len(ids)
    assert result["rms_error_mm"] == pytest.approx(np.sqrt(np.mean(np.sum(error ** 2, axis=1))), abs=1e-4)
    assert result["max_error_mm"] == pytest.approx(1.5, abs=1e-6)
    true_distance = np.linalg.norm(built - design, axis=1)
    assert result["true_max_deviation_mm"] == pytest.approx(30.0, abs=1e-4)
    assert result["true_failed"] == int((true_distance > 10.0).sum()) > 0
    measured_pass = np.linalg.norm(built - design + error, axis=1) <= 10.0
    assert result["pass_fail_agreement"] == int(np.sum(measured_pass == (true_distance <= 10.0)))
    assert result["wrong_verdicts"] == len(ids) - result["pass_fail_agreement"] and result["uncertain"] == 0


def test_all_nodes_reference_sees_the_truth_through_the_same_rigid_fit(shell):
    """Measured = the built shell rigidly fitted on all nodes (scipy's own solver): nothing is left but rounding."""
    network, ids, design, built = shell
    rotation, _ = Rotation.align_vectors(design - design.mean(axis=0), built - built.mean(axis=0))
    fitted = rotation.apply(built - built.mean(axis=0)) + design.mean(axis=0)
    record, truth = record_and_truth(ids, design, built, fitted - design, "all")
    result = compare_with_truth(record, truth, network)
    assert result["rms_error_mm"] < 1e-6
    assert result["true_rms_deviation_mm"] == pytest.approx(np.sqrt(np.mean(np.sum((fitted - design) ** 2, axis=1))), abs=1e-4)
    assert result["true_max_deviation_mm"] < 30.0  # the fit takes up part of the sag
    # the same measured values judged against the raw sag (supports reference) are wrong by the fit's shift
    record["registration"]["reference"] = "supports"
    assert compare_with_truth(record, truth, network)["rms_error_mm"] > 5.0


@pytest.mark.parametrize("text, expected", [("4000x2667", (4000, 2667)), ("64X64", (64, 64))])
def test_parse_resolution(text, expected):
    assert parse_resolution(text) == expected


@pytest.mark.parametrize("text, message", [("4000", "expected WIDTHxHEIGHT"), ("4000x2667.5", "expected WIDTHxHEIGHT"),
                                           ("63x2000", "at least 64x64")])
def test_parse_resolution_refuses(text, message):
    with pytest.raises(FablineError, match=message):
        parse_resolution(text)
