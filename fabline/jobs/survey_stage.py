"""The job's survey stage: a synthetic photo set of the job's own shell, measured like real photos, checked against truth.

With `survey.simulate` the job renders photos of its network deformed by the survey simulator's sag field,
measures them with `measure_survey` exactly as a real photo set is measured, and compares the measured
deviations with the injected ones. With `survey.result` the report shows an existing `survey.json` instead.
"""

from __future__ import annotations

import shutil
import time
from collections import Counter
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from fabline.errors import FablineError
from fabline.fileio import read_json
from fabline.survey.camera import parse_resolution

if TYPE_CHECKING:
    from fabline.model import Network

SURVEY_FOLDER = "survey"
"""The survey's folder inside the job's output folder: photos/, camera.json, tagmap.json, truth.json, survey.json."""


def simulate_and_measure(network: "Network", folder: Path, settings: dict[str, Any],
                         say: Callable[[str], None] = lambda text: None) -> dict[str, Any]:
    """Render the photo set into `folder` (replacing an earlier survey there), measure it, compare with the truth.

    `settings` is a checked `[survey]` table with `simulate = true`; returns the report's survey entry.
    """
    from fabline.survey import (MeasureOptions, SyntheticSpec, list_photos, load_camera, load_tag_map, measure_survey,
                                simulate_survey)

    width, height = parse_resolution(settings["resolution"])
    spec = SyntheticSpec(photos=settings["photos"], width=width, height=height, focal_px=width * 5 / 6,
                         coverage=settings["coverage"], sag_mm=settings["sag_mm"], seed=settings["seed"])
    fresh = folder.with_name(folder.name + ".new")  # photos of an earlier, larger set must not be measured
    shutil.rmtree(fresh, ignore_errors=True)
    started = time.perf_counter()
    spec, poses = planned(network, fresh, spec, settings["plan"], say)
    truth = simulate_survey(network, fresh, spec, poses=poses)
    shutil.rmtree(folder, ignore_errors=True)
    fresh.rename(folder)
    rendered = time.perf_counter()
    views = sum(len(photo["visible"]) for photo in truth["photos"])
    seen = views_per_tag(truth)
    tagged = [node["tag"] for node in truth["nodes"].values() if node["tag"] is not None]
    twice = sum(seen[tag] >= 2 for tag in tagged)
    source = " from the plan's stations" if poses else ""
    say(f"survey: {spec.photos} photos of {spec.width} x {spec.height} px{source} with {views} tag views rendered in "
        f"{rendered - started:.1f} s -> {folder / 'photos'}; {twice} of {len(tagged)} tagged nodes in 2 or more photos")
    bars = scale_bars(truth, settings["scale_bars"])
    options = MeasureOptions(tolerance_mm=settings["tolerance_mm"], reference=settings["reference"],
                             scale_bars=tuple(bars))
    try:
        record = measure_survey(list_photos(folder / "photos"), network, load_camera(folder / "camera.json"),
                                load_tag_map(folder / "tagmap.json"), folder, options)
    except FablineError as exc:
        raise FablineError(f"survey: measuring the simulated photo set in {folder}: {exc}") from None
    entry = survey_entry(record, folder / "survey.json")
    entry["simulated"] = {"photos": spec.photos, "resolution": f"{spec.width}x{spec.height}", "coverage": spec.coverage,
                          "plan": str(folder / "plan.json") if poses else None, "tagged_nodes": len(tagged),
                          "seen_twice": twice,
                          "sag_mm": spec.sag_mm, "seed": spec.seed, "tag_views": views,
                          "scale_bars": [{"tags": [a, b], "distance_mm": length} for a, b, length in bars],
                          "truth": str(folder / "truth.json"), "render_s": round(rendered - started, 3),
                          "measure_s": round(time.perf_counter() - rendered, 3)}
    entry["truth"] = compare_with_truth(record, truth, network)
    return entry


def planned(network: "Network", folder: Path, spec, plan: bool | str, say: Callable[[str], None]):
    """The photo set's spec and poses from the job's `survey.plan`: none (False: the simulator places its cameras),
    stations planned from the design with the spec's camera and tags (True: `fabline survey plan`'s defaults, plan.json
    and plan.svg into `folder`), or a plan file's camera and stations (copied into `folder` as plan.json)."""
    from dataclasses import replace

    from fabline.survey import make_tag_map
    from fabline.survey.photos import check_simulation
    from fabline.survey.plan import load_plan_poses, plan_survey, save_plan, write_plan_svg

    if plan is False:
        return spec, None
    folder.mkdir(parents=True, exist_ok=True)
    if plan is True:
        tag_map = make_tag_map(network.in_mm(), spec.tag_size_mm, spec.mount_offset_mm, spec.every)
        stations = plan_survey(network, tag_map, spec.camera())
        save_plan(stations, network.name, folder / "plan.json")
        write_plan_svg(network, stations, folder / "plan.svg")
        tagged = len(stations.seen_by)
        say(f"survey: planned {len(stations.stations)} stations (of {stations.candidates} candidates) that see "
            f"{tagged - len(stations.short)} of {tagged} tagged nodes from 2 or more (plan.json, plan.svg in the survey folder)")
    else:
        shutil.copyfile(plan, folder / "plan.json")
    camera, poses = load_plan_poses(folder / "plan.json")
    check_simulation(camera.width, camera.height, len(poses), spec.seed,
                     {"resolution": "survey.plan: camera", "photos": "survey.plan: stations", "seed": "survey.seed"})
    return replace(spec, photos=len(poses), width=camera.width, height=camera.height, focal_px=camera.focal_px), poses


def views_per_tag(truth: dict[str, Any]) -> Counter:
    """How many photos of a simulated set show each tag in full view."""
    return Counter(int(tag) for photo in truth["photos"] for tag in photo["visible"])


def scale_bars(truth: dict[str, Any], count: int, min_photos: int = 3) -> list[tuple[int, int, float]]:
    """`count` (0 to 2) simulated tape measurements on site: the true distance between the tag centres farthest
    apart along x, then along y, among the tags that are in full view in at least `min_photos` photos."""
    if not count:
        return []
    seen = views_per_tag(truth)
    candidates = [(node["tag"], node["tag_centre_mm"]) for node in truth["nodes"].values()
                  if node["tag"] is not None and seen[node["tag"]] >= min_photos]
    if len(candidates) < 2:
        raise FablineError(f"survey.scale_bars: fewer than 2 tags are in full view in {min_photos} photos; "
                           "take more photos or set scale_bars = 0")
    tags = [tag for tag, _ in candidates]
    centres = np.array([centre for _, centre in candidates], dtype=float)
    bars = []
    for axis in range(count):
        a, b = int(np.argmin(centres[:, axis])), int(np.argmax(centres[:, axis]))
        bars.append((tags[a], tags[b], round(float(np.linalg.norm(centres[a] - centres[b])), 3)))
    return bars


def compare_with_truth(record: dict[str, Any], truth: dict[str, Any], network: "Network") -> dict[str, Any]:
    """Measured against injected deviations on every measured node.

    The truth is seen through the survey's own registration (the built positions rigidly fitted to the
    design on the same reference nodes), so what remains is the measuring error alone; with the supports
    as reference and a sag that is zero there, that fit is the identity and the truth is the injected field.
    """
    from fabline.survey import register

    ids = list(record["nodes"])
    measured = np.array([record["nodes"][n]["deviation_mm"] for n in ids], dtype=float).reshape(-1, 3)
    design = np.array([truth["nodes"][n]["design_mm"] for n in ids], dtype=float).reshape(-1, 3)
    built = np.array([truth["nodes"][n]["built_mm"] for n in ids], dtype=float).reshape(-1, 3)
    reference = record["registration"]["reference"]
    if reference == "all":
        mask = np.ones(len(ids), dtype=bool)
    elif reference == "supports":
        mask = np.array([network.nodes[n].kind == "support" for n in ids], dtype=bool)
    else:
        mask = np.isin(ids, reference)
    rotation, translation, _ = register(built, design, mask)
    true_deviation = built @ rotation.T + translation - design
    error = np.linalg.norm(measured - true_deviation, axis=1)
    true_distance = np.linalg.norm(true_deviation, axis=1)
    true_pass = true_distance <= record["tolerance_mm"]
    verdict = np.array([record["nodes"][n]["verdict"] for n in ids])
    return {"injected": truth["deviation"], "nodes_compared": len(ids),
            "rms_error_mm": round(float(np.sqrt(np.mean(error ** 2))), 4),
            "max_error_mm": round(float(error.max()), 4), "worst_node": ids[int(np.argmax(error))],
            "true_rms_deviation_mm": round(float(np.sqrt(np.mean(true_distance ** 2))), 4),
            "true_max_deviation_mm": round(float(true_distance.max()), 4),
            "true_failed": int((~true_pass).sum()),
            "pass_fail_agreement": int(np.sum(np.where(true_pass, verdict == "pass", verdict == "fail"))),
            "uncertain": int(np.sum(verdict == "uncertain")),
            "wrong_verdicts": int(np.sum(np.where(true_pass, verdict == "fail", verdict == "pass")))}


def survey_entry(record: dict[str, Any], path: Path) -> dict[str, Any]:
    """The report's survey entry for a `fabline.survey/1` record read from (or written to) `path`."""
    picture = path.with_name("deviation_map.png")
    try:
        return {"file": str(path), "deviation_map": str(picture) if picture.is_file() else None,
                "tolerance_mm": record["tolerance_mm"], "reference": record["registration"]["reference"],
                "registration_rms_mm": record["registration"]["rms_mm"], "scale": record.get("scale"),
                "summary": record["summary"],
                "not_seen": record["not_seen"], "not_seen_regions": record.get("not_seen_regions"), "problems": [p["problem"] for p in record["problems"]],
                "simulated": None, "truth": None}
    except (KeyError, TypeError) as exc:
        raise FablineError(f"{path}: not a complete fabline.survey/1 record (missing {exc})") from None


def load_survey_result(path: str | Path) -> dict[str, Any]:
    """The report's survey entry for an existing `survey.json` (from `fabline survey measure`)."""
    path = Path(path)
    record = read_json(path)
    if not isinstance(record, dict) or record.get("schema") != "fabline.survey/1":
        raise FablineError(f"{path}: not a fabline.survey/1 file (schema {record.get('schema') if isinstance(record, dict) else None!r})")
    return survey_entry(record, path)
