"""Detection benchmark: fabline against pupil-apriltags (quad_decimate 1) per photo size, side by side in one run.

Photos are the simulator's (a saddle shell photographed with noise, blur, lighting changes and JPEG compression)
at 640 x 480, 2 MP, 12 MP and 24 MP, the focal length 5/6 of the width, small photos taken closer. Per size and detector: CPU time per
photo, recall of the tags in full view (the truth's `visible`) and false tags (ids not rendered in that photo);
pupil-apriltags counts tags it reads without bit errors. Run: python benchmarks/detect_bench.py [--photos 3]
[--sizes 640x480,1600x1200,4000x3000,6000x4000]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fabline.survey import SyntheticSpec, detect_tags, read_gray, saddle_network, simulate_survey  # noqa: E402

PUPIL_SCRIPT = """
import json, os, sys, time
import cv2
import pupil_apriltags
detector = pupil_apriltags.Detector(families="tag36h11", quad_decimate=1.0, nthreads=1)
images = [cv2.imread(path, cv2.IMREAD_GRAYSCALE) for path in sys.argv[1:]]
start = time.process_time()
found = [[r.tag_id for r in detector.detect(image) if r.hamming == 0] for image in images]
print(json.dumps([time.process_time() - start, found]), flush=True)
os._exit(0)  # the library's teardown can crash (pupil-labs/apriltags issue #39)
"""


def score(found: list[list[int]], truth: dict) -> tuple[int, int, int]:
    """Visible tags found, visible tags, false tags (ids not rendered in the photo) over the photo set."""
    hits = visible = false = 0
    for ids, record in zip(found, truth["photos"]):
        shown = set(map(int, record["visible"]))
        hits += len(shown & set(ids))
        visible += len(shown)
        false += len(set(ids) - set(record["rendered"]))
    return hits, visible, false


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--photos", type=int, default=3)
    parser.add_argument("--sizes", default="640x480,1600x1200,4000x3000,6000x4000")
    args = parser.parse_args()
    network = saddle_network(6.0, 0.4, 5.0)
    print(f"detection benchmark: {args.photos} simulator photos per size, saddle of {len(network.nodes)} tagged nodes")
    print(f"  {'size':>10}  {'fabline CPU s/photo':>19} {'recall':>12} {'false':>5}   "
          f"{'pupil CPU s/photo':>17} {'recall':>12} {'false':>5}")
    for size in args.sizes.split(","):
        width, height = (int(v) for v in size.split("x"))
        out = Path(tempfile.mkdtemp(prefix=f"detect-{size}-"))
        # closer for small photos, so that tags keep at least 12 px sides (a 640 x 480 photo covers a quarter of the shell)
        coverage = 0.6 * min(1.0, width / 2400)
        spec = SyntheticSpec(photos=args.photos, width=width, height=height, focal_px=width * 5 / 6, coverage=coverage,
                             jpeg_quality=90, min_side_px=12.0, seed=4)
        truth = simulate_survey(network, out, spec)
        paths = [out / record["file"] for record in truth["photos"]]
        images = [read_gray(path) for path in paths]
        cpu = time.process_time()
        ours = [[d.tag_id for d in detect_tags(image)] for image in images]
        ours_cpu = (time.process_time() - cpu) / len(images)
        hits, visible, false = score(ours, truth)
        row = f"  {size:>10}  {ours_cpu:>19.3f} {f'{hits}/{visible}':>12} {false:>5}   "
        try:
            done = subprocess.run([sys.executable, "-c", PUPIL_SCRIPT, *map(str, paths)], capture_output=True, text=True,
                                  check=True)
            seconds, theirs = json.loads(done.stdout)
            their_hits, _, their_false = score(theirs, truth)
            row += f"{seconds / len(paths):>17.3f} {f'{their_hits}/{visible}':>12} {their_false:>5}"
        except (subprocess.CalledProcessError, json.JSONDecodeError):
            row += f"{'n/a (pip install fabline[bench])':>36}"
        print(row, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
