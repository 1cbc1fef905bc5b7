"""Self-calibration benchmark: photo sets from cameras unknown to fabline, surveyed without a camera file.

Per set the simulator draws the camera at random (focal length 0.6-1.2 of the width, principal point within 2 %
of the centre, k1, k2, p1, p2, k3); the survey fits them from its own photos. Printed per set: the true and fitted
focal length (error and reported uncertainty), the principal point's error, and the RMS of measured against true
deviations with the fitted camera and, for comparison, with the true camera given (all nodes as reference, the truth
seen through the same rigid fit). The issue's targets: deviation error <= 1 mm RMS, focal length within 0.5 %.
Run: python benchmarks/selfcal_bench.py [--sets 10] [--photos 12] [--size 1600x1200] [--exif]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fabline.jobs.survey_stage import compare_with_truth  # noqa: E402
from fabline.survey import (MeasureOptions, SyntheticSpec, list_photos, load_camera, load_tag_map, measure_survey,  # noqa: E402
                            saddle_network, simulate_survey)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sets", type=int, default=10)
    parser.add_argument("--photos", type=int, default=12)
    parser.add_argument("--size", default="1600x1200")
    parser.add_argument("--exif", action="store_true", help="photos carry EXIF (35 mm-equivalent focal length)")
    args = parser.parse_args()
    width, height = (int(v) for v in args.size.split("x"))
    network = saddle_network(3.0, 0.5, 4.0)
    print(f"self-calibration benchmark: {args.sets} sets of {args.photos} photos {width}x{height}, saddle of "
          f"{len(network.nodes)} nodes, cameras drawn at random, {'with' if args.exif else 'without'} EXIF")
    print(f"  {'seed':>4} {'f true':>8} {'f fit':>8} {'f err %':>8} {'sigma_f':>8} {'c err px':>8} "
          f"{'dev RMS mm':>10} {'known cam':>10} {'CPU s':>6}")
    focal_errors, deviation_errors = [], []
    for seed in range(1, args.sets + 1):
        out = Path(tempfile.mkdtemp(prefix=f"selfcal-{seed}-"))
        spec = SyntheticSpec(photos=args.photos, width=width, height=height, coverage=0.7, sag_mm=25.0, seed=seed,
                             random_camera=True, exif_model="bench phone" if args.exif else None)
        truth = simulate_survey(network, out, spec)
        camera, tag_map = load_camera(out / "camera.json"), load_tag_map(out / "tagmap.json")
        photos = list_photos(out / "photos")
        cpu = time.process_time()
        record = measure_survey(photos, network, None, tag_map, out / "self", MeasureOptions(reference="all", pictures=False))
        seconds = time.process_time() - cpu
        known = measure_survey(photos, network, camera, tag_map, out / "known", MeasureOptions(reference="all", pictures=False))
        [fitted] = record["cameras"]
        focal_error = 100 * (fitted["f_px"] / camera.focal_px - 1)
        centre_error = float(np.hypot(fitted["cx"] - camera.matrix[0, 2], fitted["cy"] - camera.matrix[1, 2]))
        rms = compare_with_truth(record, truth, network)["rms_error_mm"]
        focal_errors.append(abs(focal_error))
        deviation_errors.append(rms)
        print(f"  {seed:>4} {camera.focal_px:>8.1f} {fitted['f_px']:>8.1f} {focal_error:>+8.3f} {fitted['sigma']['f']:>8.3g} "
              f"{centre_error:>8.2f} {rms:>10.3f} {compare_with_truth(known, truth, network)['rms_error_mm']:>10.3f} "
              f"{seconds:>6.1f}")
    print(f"  worst focal length error {max(focal_errors):.3f} % (target 0.5 %), worst deviation error "
          f"{max(deviation_errors):.3f} mm RMS (target 1 mm)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
