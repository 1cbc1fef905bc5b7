"""The simulator streams: one photo's buffers at a time, bounded work per tag however near the lens, and the same
photos as before for the same seed. Timed and size goals live in benchmarks/survey_memory_bench.py."""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
import tracemalloc

import numpy as np

import fabline.survey.simulate as simulate
from fabline.model import save_network
from fabline.survey import SyntheticSpec, saddle_network, simulate_survey


def _pixels_digests(monkeypatch, tmp_path) -> list[str]:
    """The first 16 hex digits of each photo's 8-bit pixels' SHA-256, as `simulate_survey` hands them to the encoder."""
    found = []
    monkeypatch.setattr(simulate, "write_image", lambda path, image, params=(): found.append(
        hashlib.sha256(np.ascontiguousarray(image).tobytes()).hexdigest()[:16]))
    spec = SyntheticSpec(photos=3, width=800, height=600, focal_px=700, coverage=0.8, seed=3)
    simulate_survey(saddle_network(2.0, 0.5, 3.0), tmp_path, spec)
    return found


def test_the_same_seed_gives_the_photos_the_renderer_gave_before_it_streamed(monkeypatch, tmp_path):
    """Digests made by the renderer before the streaming change (commit aebd6f3), with this environment's OpenCV and
    numpy: an upgrade of either may change them legitimately, a change of the renderer's arithmetic must not."""
    assert _pixels_digests(monkeypatch, tmp_path) == ["4e5b83831fd1c1ca", "3f0dfd53a7bb8fd0", "24e516afc25dae1d"]


def test_a_tag_at_the_lens_renders_in_bounded_memory():
    """A black square 20000 px a side over a 600 x 400 photo: the old renderer built a texture of 80000 x 80000 texels
    (25 GB) for it; now the work is bands of at most FINE_BAND_PX supersampled pixels and the photo is the tag's
    black square everywhere."""
    photo = np.full((400, 600), 100.0, dtype=np.float32)
    corners = np.array([[-10500.0, -10500.0], [9500.0, -10500.0], [9500.0, 9500.0], [-10500.0, 9500.0]])
    tracemalloc.start()
    simulate._render_tag(photo, 0, corners, 1.0)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert peak < 400e6, peak
    # the photo lies inside one cell of the tag (2500 px each, edges at -500 and 2000 px): one level throughout
    assert np.ptp(photo) < 1e-3 and photo[0, 0] in (np.float32(25.0), np.float32(220.0))


def test_bands_render_what_one_warp_renders(monkeypatch):
    """A tag whose supersampled window is larger than FINE_BAND_PX, rendered in bands and (band limit lifted) at once."""
    corners = np.array([[150.3, 80.7], [1100.2, 95.1], [1090.5, 1050.2], [140.1, 1060.8]])
    banded = np.full((1200, 1300), 100.0, dtype=np.float32)
    simulate._render_tag(banded, 7, corners, 0.9)
    assert (1060 * 960 * simulate.SUPERSAMPLE**2) > simulate.FINE_BAND_PX  # it did render in bands
    monkeypatch.setattr(simulate, "FINE_BAND_PX", 2**40)
    whole = np.full((1200, 1300), 100.0, dtype=np.float32)
    simulate._render_tag(whole, 7, corners, 0.9)
    assert np.max(np.abs(banded - whole)) < 1e-3


def _peak_rss_mb(model, folder, photos: int) -> float:
    """Peak resident set (MB) of one `fabline survey simulate` subprocess (its own rusage, by os.wait4)."""
    process = subprocess.Popen([sys.executable, "-m", "fabline", "survey", "simulate", "--model", str(model), "-o",
                                str(folder), "--photos", str(photos), "--resolution", "2400x1600", "--coverage", "0.5"],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    _, status, usage = os.wait4(process.pid, 0)
    assert os.waitstatus_to_exitcode(status) == 0
    return usage.ru_maxrss / 1024


def test_memory_does_not_grow_with_the_photo_count(tmp_path):
    """2 and 8 photos of 3.8 MP: the peak is one photo's buffers (a float32 photo, its label map, the blur), not eight."""
    model = tmp_path / "saddle.network.json"
    save_network(saddle_network(4.0, 0.35, 4.0), model)
    few, many = _peak_rss_mb(model, tmp_path / "two", 2), _peak_rss_mb(model, tmp_path / "eight", 8)
    one_photo = 2400 * 1600 * 4 / 2**20  # MB of one float32 photo
    assert many < few + 2 * one_photo, (few, many)
