"""Detection benchmark: fabline against pupil-apriltags (quad_decimate 1 and its default 2) per photo size.

Photos are camera-like renders with known truth (tests/survey/detect_scenes.py: tags drawn by OpenCV's aruco, not by
fabline): small (10-20 px), dim, low-contrast, slanted (to 70 degrees), thin-quiet-zone and plain tags over a cluttered
background, lens blur, gamma, noise and JPEG; two tags per photo seen edge-on (4-7 px across), which no detector should
report. Per size and detector: truth tags found, false tags (ids not in the truth, edge-on ones included), and CPU
seconds for the whole set (time.process_time: every thread of the process, OpenCV's included; pupil-apriltags runs one
thread). Runs are interleaved photo by photo and detector by detector, `--repeat` rounds, the least CPU time of each
photo and detector kept: load from other processes falls on all alike. `missed` counts tags pupil-apriltags at
quad_decimate 1 finds that fabline does not.
Run: python benchmarks/detect_bench.py [--photos 3] [--repeat 3] [--sizes 640x480,800x533,...]
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from fabline.survey import detect_tags  # noqa: E402

SIZES = "640x480,800x533,1056x792,1200x1600,4000x3000,6000x4000"


def _load_scenes():
    """The scene renderer, read from its file: tests/ is no package the project installs."""
    spec = importlib.util.spec_from_file_location("detect_scenes", REPO / "tests" / "survey" / "detect_scenes.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["detect_scenes"] = module  # its dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--photos", type=int, default=3, help="photos per size (default 3)")
    parser.add_argument("--repeat", type=int, default=3, help="interleaved rounds, least CPU kept (default 3)")
    parser.add_argument("--sizes", default=SIZES)
    args = parser.parse_args()
    try:
        import pupil_apriltags
    except ImportError:
        print("detect_bench: pupil-apriltags is missing: pip install 'fabline[bench]'", file=sys.stderr)
        return 2
    scenes = _load_scenes()
    detectors = {
        "fabline": lambda image: [d.tag_id for d in detect_tags(image)],
        "pupil qd1": _pupil(pupil_apriltags.Detector(families="tag36h11", quad_decimate=1.0, nthreads=1)),
        "pupil qd2": _pupil(pupil_apriltags.Detector(families="tag36h11", quad_decimate=2.0, nthreads=1)),
    }
    print(f"detection benchmark: {args.photos} camera-like photos per size, least CPU of {args.repeat} interleaved "
          f"rounds (process CPU time, not wall)")
    print(f"  {'size':>9} {'photos':>6} {'tags':>5} | {'fabline found/false':>18} {'missed':>6} {'CPU s':>6} | "
          f"{'pupil qd1 found/false':>21} {'CPU s':>6} | {'pupil qd2 found/false':>21} {'CPU s':>6} | "
          f"{'CPU fabline/qd1':>15}")
    for size in args.sizes.split(","):
        width, height = (int(v) for v in size.split("x"))
        photos = [scenes.render_scene(width, height, seed) for seed in range(args.photos)]
        cpu = {name: [float("inf")] * len(photos) for name in detectors}
        found: dict[str, list[set[int]]] = {name: [set()] * len(photos) for name in detectors}
        for _ in range(args.repeat):
            for k, scene in enumerate(photos):
                for name, detect in detectors.items():
                    start = time.process_time()
                    ids = detect(scene.image)
                    cpu[name][k] = min(cpu[name][k], time.process_time() - start)
                    found[name][k] = set(ids)
        truth = sum(len(scene.tags) for scene in photos)
        row = f"  {size:>9} {len(photos):>6} {truth:>5} |"
        for name in detectors:
            hits = sum(len(ids & set(scene.tags)) for ids, scene in zip(found[name], photos))
            false = sum(len(ids - set(scene.tags)) for ids, scene in zip(found[name], photos))
            width_found = 18 if name == "fabline" else 21
            row += f" {f'{hits}/{false}':>{width_found}}"
            if name == "fabline":
                missed = sum(len(theirs - ours) for ours, theirs in zip(found["fabline"], found["pupil qd1"]))
                row += f" {missed:>6}"
            row += f" {sum(cpu[name]):>6.3f} |"
        row += f" {sum(cpu['fabline']) / sum(cpu['pupil qd1']):>15.2f}"
        print(row, flush=True)
        del photos
    sys.stdout.flush()
    os._exit(0)  # pupil-apriltags' teardown can crash the interpreter (pupil-labs/apriltags issue #39)


def _pupil(detector):
    """pupil-apriltags' ids on a photo, every tag it reports (its default: up to 2 bits corrected)."""
    return lambda image: [r.tag_id for r in detector.detect(image)]


if __name__ == "__main__":
    main()
