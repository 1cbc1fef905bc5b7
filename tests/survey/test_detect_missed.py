"""Tags pupil-apriltags (quad_decimate 1) finds on the detection benchmark's camera-like photos (1056 x 792 and
1200 x 1600, tests/survey/detect_scenes.py) that fabline missed (issue 30), each on a crop of its photo around it so the
test is fast: 14-18 px tags on a darker background whose quiet zone's outline aruco finds two cells out, and 60-75 px
tags of 25 grey levels from black to white that only the photo halved twice finds, 4-7 px off. The truth is the render's
own corners (OpenCV's aruco drew the tags)."""

from __future__ import annotations

import numpy as np
import pytest

from .detect_scenes import render_scene
from fabline.survey import detect_tags

# (photo width, height, seed, tag id, crop half-width px): the benchmark's photos and the tags it missed
MISSED = [
    (1056, 792, 1, 451, 48),  # 18 px, dim (10-54 grey levels) on a dark background, slanted 29 degrees
    (1056, 792, 2, 251, 48),  # 18 px, plain, blurred
    (1200, 1600, 0, 24, 48),  # 18 px, dim on a dark background
    (1200, 1600, 1, 256, 48),  # 24 px seen at 58 degrees (14 px across)
    (1056, 792, 0, 257, 384),  # 73 px, 114-139 grey levels
    (1200, 1600, 2, 346, 416),  # 68 px at 30 degrees, 118-143 grey levels
]


@pytest.mark.parametrize("width, height, seed, tag_id, half", MISSED, ids=[f"tag{case[3]}" for case in MISSED])
def test_a_tag_the_reference_finds_is_found(width, height, seed, tag_id, half):
    """On a crop of the photo (inside it, aligned to 4 px, so the pyramid's levels fall on the photo's pixels as on the whole
    photo), the tag is found with its corners within 1 px of the rendered ones, and no tag the render does not hold."""
    scene = render_scene(width, height, seed)
    truth = scene.tags[tag_id]
    x0, y0 = (np.clip(truth.mean(axis=0).astype(int) - half, 0, [width - 2 * half, height - 2 * half]) // 4) * 4
    crop = np.ascontiguousarray(scene.image[y0:y0 + 2 * half, x0:x0 + 2 * half])
    found = {d.tag_id: d.corners + [x0, y0] for d in detect_tags(crop)}
    assert set(found) <= set(scene.tags), f"false tags {set(found) - set(scene.tags)}"
    assert tag_id in found
    assert np.linalg.norm(found[tag_id] - truth, axis=1).max() < 1.0
