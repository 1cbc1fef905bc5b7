"""Survey benchmark: a synthetic 24 MP photo set of the pavilion-sized model, surveyed end to end.

Prints detection time per photo (fabline and, when installed, pupil-apriltags), the whole survey time
(wall and CPU: the machine may be shared), tags found against tags visible, false tags, tags found only
where the reconstruction predicted them, and the RMS of recovered against injected deviations
(supports as reference: with small tags kept out of the scale (the default), with every tag setting it,
and with a scale bar between the two farthest support tags; all nodes as reference).
Run: python benchmarks/survey_bench.py [--model FILE] [--photos 32] [--size 6000x4000] [--out DIR [--reuse]]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fabline.fileio import read_json  # noqa: E402
from fabline.model import Network, load_network  # noqa: E402
from fabline.survey import (MeasureOptions, SyntheticSpec, detect_tags, list_photos, load_camera, load_tag_map,  # noqa: E402
                            measure_survey, read_gray, rigid_fit, simulate_survey)


def pavilion_model() -> Network:
    """The pavilion-sized design surveyed by default (the Enneper network, about 9 x 12 m)."""
    from fabline.model.designs import enneper_network

    return enneper_network()


PUPIL_SCRIPT = """
import json, os, sys, time
import cv2
import pupil_apriltags
detector = pupil_apriltags.Detector(families="tag36h11", quad_decimate=1.0)
images = [cv2.imread(path, cv2.IMREAD_GRAYSCALE) for path in sys.argv[1:]]
start = time.perf_counter()
found = [[r for r in detector.detect(image) if r.hamming == 0] for image in images]
seconds = time.perf_counter() - start
# corners in OpenCV's convention (pixel centres on integers): is the whole black square in the photo?
tags = [[[r.tag_id, bool(((r.corners - 0.5) >= 0).all() and ((r.corners - 0.5) <= [image.shape[1] - 1, image.shape[0] - 1]).all())]
         for r in rs] for rs, image in zip(found, images)]
print(json.dumps([seconds, tags]), flush=True)
os._exit(0)  # the library's teardown can crash (pupil-labs/apriltags issue #39)
"""


def _pupil_apriltags(paths: list[Path]):
    """Seconds, and per photo the tag ids with their whole black square in the photo and those cut by its border,
    from the AprilTag 3 reference detector, run in a child process; None if absent."""
    try:
        import pupil_apriltags  # noqa: F401
    except ImportError:
        return None
    done = subprocess.run([sys.executable, "-c", PUPIL_SCRIPT, *map(str, paths)], capture_output=True, text=True, check=True)
    seconds, tags = json.loads(done.stdout)
    return seconds, [{t for t, whole in found if whole} for found in tags], [{t for t, whole in found if not whole} for found in tags]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", help="fabline.network/1 file (default: the built-in pavilion design)")
    parser.add_argument("--photos", type=int, default=32)
    parser.add_argument("--size", default="6000x4000")
    parser.add_argument("--out", help="folder for the photo set and the survey (default: a temporary folder)")
    parser.add_argument("--reuse", action="store_true", help="survey the photo set already rendered in --out (skip rendering)")
    args = parser.parse_args()
    width, height = (int(v) for v in args.size.split("x"))
    network = load_network(args.model) if args.model else pavilion_model()
    out = Path(args.out or tempfile.mkdtemp(prefix="survey-bench-"))
    spec = SyntheticSpec(photos=args.photos, width=width, height=height, focal_px=width * 5 / 6,
                         every=1 if len(network.nodes) <= 587 else 2)
    rows = []
    if args.reuse and (out / "set" / "truth.json").is_file():
        truth = read_json(out / "set" / "truth.json")
        rows.append(("render photo set", "reused", f"{len(truth['photos'])} photos in {out / 'set'}"))
    else:
        start = time.perf_counter()
        truth = simulate_survey(network, out / "set", spec)
        rows.append(("render photo set", f"{time.perf_counter() - start:.1f} s", f"{args.photos} photos {width}x{height}"))

    photos = list_photos(out / "set" / "photos")
    sample = photos[:3]
    start, cpu = time.perf_counter(), time.process_time()
    for path in sample:
        detect_tags(read_gray(path))
    per_photo, cpu_per_photo = (time.perf_counter() - start) / len(sample), (time.process_time() - cpu) / len(sample)
    rows.append(("detect, fabline", f"{per_photo:.2f} s/photo", f"OpenCV quads + edge refinement (CPU {cpu_per_photo:.2f} s/photo)"))
    reference = _pupil_apriltags(sample)
    if reference is None:
        rows.append(("detect, pupil-apriltags", "n/a", "not installed (pip install fabline[bench])"))
    else:
        seconds, tags, cut = reference
        ours = [{d.tag_id for d in detect_tags(read_gray(path))} for path in sample]
        missed = sum(len(theirs - mine) for theirs, mine in zip(tags, ours))
        cut_missed = sum(len(theirs - mine) for theirs, mine in zip(cut, ours))
        rows.append(("detect, pupil-apriltags", f"{seconds / len(sample):.2f} s/photo",
                     f"reference, quad_decimate 1: {sum(map(len, tags))} tags, {missed} of them missed by fabline; "
                     f"{sum(map(len, cut))} more with a corner outside the photo, {cut_missed} of them missed"))

    camera, tag_map = load_camera(out / "set" / "camera.json"), load_tag_map(out / "set" / "tagmap.json")
    start, cpu = time.perf_counter(), time.process_time()
    record = measure_survey(photos, network, camera, tag_map, out / "survey", MeasureOptions(reference="supports"))
    rows.append(("whole survey (measure)", f"{time.perf_counter() - start:.1f} s",
                 f"detect + adjust + second look + adjust + register + pictures (CPU {time.process_time() - cpu:.1f} s)"))
    small = record["scale"]["observations_without_scale"]

    visible = sum(len(p["visible"]) for p in truth["photos"])
    found = sum(len(set(map(int, p["visible"])) & set(r["tags"])) for p, r in zip(truth["photos"], record["photos"]))
    false = sum(len(set(r["tags"]) - set(p["rendered"])) for p, r in zip(truth["photos"], record["photos"]))
    rows.append(("visible tags found", f"{found} / {visible}", f"{false} false tags, "
                 f"{record['summary']['tags_found_where_predicted']} tags found where the reconstruction predicted them"))
    ids = list(record["nodes"])
    recovered = np.array([record["nodes"][n]["deviation_mm"] for n in ids])
    injected = np.array([truth["nodes"][n]["deviation_mm"] for n in ids])
    rms = float(np.sqrt(np.mean(np.sum((recovered - injected) ** 2, axis=1))))
    rows.append(("deviation error, RMS", f"{rms:.3f} mm", f"{len(ids)} of {len(network.nodes)} nodes, reference = supports, "
                 f"{small} observations with cells < {record['scale']['min_cell_px']:g} px kept out of the scale"))
    record_every = measure_survey(photos, network, camera, tag_map, out / "survey-every",
                                  MeasureOptions(reference="supports", pictures=False, scale_min_cell_px=0.0))
    ids_every = list(record_every["nodes"])
    recovered_every = np.array([record_every["nodes"][n]["deviation_mm"] for n in ids_every])
    injected_every = np.array([truth["nodes"][n]["deviation_mm"] for n in ids_every])
    rms_every = float(np.sqrt(np.mean(np.sum((recovered_every - injected_every) ** 2, axis=1))))
    rows.append(("deviation error, RMS", f"{rms_every:.3f} mm", f"{len(ids_every)} nodes, reference = supports, every tag sets the scale"))
    built = np.array([truth["nodes"][n]["built_mm"] for n in ids])
    design = np.array([truth["nodes"][n]["design_mm"] for n in ids])
    rotation, translation = rigid_fit(built, design)
    sigma = np.array([np.linalg.norm(record["nodes"][n]["sigma_mm"]) for n in ids])
    rows.append(("node sigma, median", f"{np.median(sigma):.3f} mm", f"reprojection RMS {record['summary']['reprojection_rms_px']} px"))
    record_all = measure_survey(photos, network, camera, tag_map, out / "survey-all", MeasureOptions(pictures=False))
    recovered_all = np.array([record_all["nodes"][n]["deviation_mm"] for n in ids])
    rms_all = float(np.sqrt(np.mean(np.sum((recovered_all - (built @ rotation.T + translation - design)) ** 2, axis=1))))
    rows.append(("deviation error, RMS", f"{rms_all:.3f} mm", "reference = all nodes (truth fitted the same way)"))
    supports = [n for n in ids if network.nodes[n].kind == "support" and truth["nodes"][n]["tag"] is not None]
    centres = np.array([truth["nodes"][n]["tag_centre_mm"] for n in supports])
    gaps = np.linalg.norm(centres[:, None] - centres[None], axis=2)
    a, b = np.unravel_index(np.argmax(gaps), gaps.shape)
    bar = (truth["nodes"][supports[a]]["tag"], truth["nodes"][supports[b]]["tag"], round(float(gaps[a, b]), 1))
    record_bar = measure_survey(photos, network, camera, tag_map, out / "survey-bar",
                                MeasureOptions(reference="supports", pictures=False, scale_bars=(bar,)))
    recovered_bar = np.array([record_bar["nodes"][n]["deviation_mm"] for n in ids])
    rms_bar = float(np.sqrt(np.mean(np.sum((recovered_bar - injected) ** 2, axis=1))))
    rows.append(("deviation error, RMS", f"{rms_bar:.3f} mm",
                 f"reference = supports, scale bar tags {bar[0]}-{bar[1]} {bar[2]:g} mm (factor {record_bar['scale']['factor']:.6f})"))
    width_col = max(len(r[0]) for r in rows)
    print(f"survey benchmark: {network.name or 'model'}, {len(network.nodes)} nodes, {len(tag_map.node_of_tag)} tags, output {out}")
    for name, value, note in rows:
        print(f"  {name:<{width_col}}  {value:>18}  {note}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
