"""`fabline survey detect` names the quads it read but does not report as tags (issue 30): a tag with 3 data bits
painted over (tests/survey/test_detect_hard.py's, its code OpenCV's) is listed under `flagged` with why, in the JSON and
in the table, and not among the tags."""

from __future__ import annotations

import json

import cv2
import numpy as np

from .test_detect_hard import _damaged_tag


def test_detect_lists_the_flagged_quads(cli, tmp_path):
    photo = tmp_path / "torn.png"
    cv2.imwrite(str(photo), _damaged_tag(3, 0))
    code, out, err = cli("survey", "detect", photo, "--json")
    assert code == 0, err
    (entry,) = json.loads(out)
    assert entry["tags"] == []
    (quad,) = entry["flagged"]
    assert quad["id"] == 123 and quad["quality"] == "3 bits wrong" and quad["partial"] is False
    # the tag and its quiet zone drawn at 60..180 px in 12 px cells: the black square from 72 to 168 px, its corners at
    # 71.5 and 167.5 (pixel centres on integers)
    assert np.allclose(np.sort(np.ravel(quad["corners_px"])), [71.5] * 4 + [167.5] * 4, atol=0.3)
    code, out, err = cli("survey", "detect", photo)
    assert code == 0, err
    assert "1 quad(s) flagged, not tags: id 123 (3 bits wrong)" in out
