"""CLI for the as-built survey: `fabline survey tags | detect | calibrate | plan | simulate | measure`."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from fabline.cli import hidden_alias
from fabline.cli.units import length_mm, size
from fabline.errors import FablineError
from fabline.fileio import check_outputs
from fabline.units import mm, parse_length


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the `survey` command group."""
    survey = subparsers.add_parser("survey", help="as-built survey with AprilTags: tags, calibration, measurement")
    commands = survey.add_subparsers(dest="survey_command", metavar="SUBCOMMAND", required=True)

    tags = commands.add_parser("tags", help="printable tag sheets (SVG, PDF) and the tag map for a model")
    tags.add_argument("--model", required=True, help="fabline.network/1 model file")
    tags.add_argument("-o", "--output", required=True, help="folder for the sheets and tagmap.json")
    tags.add_argument("--tag-size", type=length_mm, default=65.0, help="edge of the tag's black square")
    tags.add_argument("--mount-offset", type=length_mm, default=20.0, help="tag face above the node along its normal")
    tags.add_argument("--every", type=int, default=1, help="tag every N-th node (supports always)")
    tags.set_defaults(func=_tags)

    detect = commands.add_parser("detect", help="detect AprilTag 36h11 tags in photos (corners, optional poses)")
    detect.add_argument("photos", nargs="+", help="image files")
    detect.add_argument("--camera", help="camera.json, to estimate each tag's pose")
    detect.add_argument("--tag-size", type=length_mm, metavar="MM", help="tag black-square edge, mm, for poses (e.g. 65)")
    detect.add_argument("--json", action="store_true", help="print JSON (the default prints a table)")
    detect.set_defaults(func=_detect)

    calibrate = commands.add_parser("calibrate", help="camera intrinsics from ChArUco photos")
    calibrate.add_argument("photos", nargs="?", help="folder of ChArUco board photos")
    calibrate.add_argument("-o", "--output", help="camera.json to write")
    calibrate.add_argument("--board", default="7x5", help="squares across x down")
    calibrate.add_argument("--square", type=length_mm, default=40.0, help="square edge")
    calibrate.add_argument("--marker", type=length_mm, default=30.0, help="marker edge")
    calibrate.add_argument("--write-board", metavar="PNG", help="write the board image to print, then stop")
    calibrate.set_defaults(func=_calibrate)

    plan = commands.add_parser("plan", help="camera stations that see every node's tag in two photos (and a drawing)")
    plan.add_argument("--model", required=True, help="fabline.network/1 model file")
    plan.add_argument("--tags", help="tagmap.json (default: ids in model node order, 65 mm tags, 20 mm offset)")
    plan.add_argument("--camera", help="camera.json of the survey camera")
    plan.add_argument("--photo", help="a test photo: its size and EXIF 35 mm-equivalent focal length give the camera")
    plan.add_argument("--sensor", type=size("mm"), metavar="WxH", help="sensor size in mm (36x24) or with a unit, with --focal-length and --resolution")
    plan.add_argument("--focal-length", type=length_mm, help="lens focal length in mm or with a unit, with --sensor and --resolution")
    plan.add_argument("--resolution", metavar="WxH", help="image size in px, with --sensor and --focal-length")
    plan.add_argument("--height", type=length_mm, default=1600.0, help="camera height above the ground (lowest node)")
    plan.add_argument("--max-angle", type=float, default=60.0, metavar="DEG",
                      help="largest angle between a tag's normal and the ray to the camera, degrees")
    plan.add_argument("--min-side", type=float, default=16.0, metavar="PX", help="smallest tag side in the photo, px")
    plan.add_argument("--views", type=int, default=2, help="stations each tag must be seen from")
    plan.add_argument("--spacing", type=length_mm, default=1500.0, help="spacing of the candidate stations")
    plan.add_argument("-o", "--output", required=True, help="folder for plan.json and plan.svg")
    plan.add_argument("--survey", metavar="SURVEY_JSON", help="a survey.json: list its unseen nodes with the stations that see them")
    plan.set_defaults(func=_plan)

    simulate = commands.add_parser("simulate", help="render a synthetic photo set of the built structure with known truth")
    simulate.add_argument("--model", required=True, help="fabline.network/1 model file")
    simulate.add_argument("-o", "--output", required=True, help="folder for photos/, camera.json, tagmap.json, truth.json")
    simulate.add_argument("--photos", type=int, default=32, help="number of photos")
    resolution = simulate.add_argument("--resolution", default="6000x4000", metavar="WxH",
                                       help="image size in px (6000x4000: 24 MP)")
    hidden_alias(simulate, resolution, "--size")
    simulate.add_argument("--focal", type=float, help="focal length in px (default 5/6 of the width)")
    simulate.add_argument("--sag", type=length_mm, default=25.0, help="sag of the built shell, zero at supports")
    simulate.add_argument("--noise", type=float, default=2.0, help="sensor noise sigma, grey levels")
    simulate.add_argument("--blur", type=float, default=0.7, help="blur sigma, px")
    simulate.add_argument("--tag-size", type=length_mm, default=65.0, help="tag black-square edge")
    simulate.add_argument("--every", type=int, default=1, help="tag every N-th node (supports always)")
    simulate.add_argument("--coverage", type=float, default=0.45,
                          help="fraction of the model's plan span one photo covers")
    simulate.add_argument("--seed", type=int, default=1, help="random seed of the camera positions and noise")
    simulate.add_argument("--plan", metavar="PLAN_JSON",
                          help="photograph from a plan's stations with its camera (`survey plan`) instead of the "
                               "simulator's own placement (--photos, --resolution and --focal then come from the plan)")
    simulate.set_defaults(func=_simulate)

    measure = commands.add_parser("measure", help="measure every tagged node against the design")
    measure.add_argument("photos", help="folder of survey photos")
    measure.add_argument("--model", required=True, help="fabline.network/1 model file")
    measure.add_argument("--camera", help="camera.json (default: the photos calibrate their cameras themselves)")
    measure.add_argument("--calibrate", action="store_true",
                         help="fit the intrinsics to the survey's photos, starting from --camera (always without it)")
    measure.add_argument("--radial-only", action="store_true",
                         help="self-calibration fits focal length, principal point, k1 and k2 only (not p1, p2, k3)")
    measure.add_argument("--camera-map", metavar="JSON",
                         help="photo file name -> camera name, for photos EXIF does not group (e.g. two phones)")
    measure.add_argument("--tags", help="tagmap.json (default: ids in model node order, 65 mm tags, 20 mm offset)")
    measure.add_argument("-o", "--output", required=True, help="folder for survey.json and the pictures")
    measure.add_argument("--tolerance", type=length_mm, default=20.0, help="pass/fail distance")
    measure.add_argument("--k-sigma", type=float, default=2.0, metavar="K",
                         help="pass: deviation + K sigma within the tolerance; fail: deviation - K sigma beyond; "
                              "uncertain otherwise")
    measure.add_argument("--reference", default="all",
                         help="nodes the registration fits: all, supports, or comma-separated node ids")
    measure.add_argument("--min-views", type=int, default=2, help="photos a tag must be seen in")
    measure.add_argument("--scale-bar", nargs=3, action="append", default=[], metavar=("TAG_A", "TAG_B", "DIST_MM"),
                         help="distance between two tag centres measured on site, mm or with a unit (1.2m); fixes "
                              "the scale (repeatable)")
    measure.add_argument("--scale-min-cell", type=float, default=4.0, metavar="PX",
                         help="tags whose cells are narrower than this in a photo do not set the scale there "
                              "(their detected size is biased), px; 0 lets all set it")
    measure.set_defaults(func=_measure)


def _tags(args: argparse.Namespace) -> int:
    from fabline.model import load_network
    from fabline.survey import make_tag_map, write_tag_sheets

    check_outputs(folders=(args.output,), inputs=(args.model,))
    network = load_network(args.model)
    written = write_tag_sheets(make_tag_map(network, args.tag_size, args.mount_offset, args.every), args.output)
    print(f"{len(written) - 2} sheet(s), tags.pdf and tagmap.json written to {args.output}")
    return 0


def _detect(args: argparse.Namespace) -> int:
    from fabline.survey import detect_tags, load_camera, read_gray, tag_pose
    from fabline.survey.tagmap import check_tag_size_mm

    if (args.camera is None) != (args.tag_size is None):
        raise FablineError("poses need both --camera and --tag-size")
    if args.tag_size is not None:
        check_tag_size_mm(args.tag_size)
    camera = load_camera(args.camera) if args.camera else None
    report, failures = [], 0
    for path in args.photos:
        entry: dict = {"file": path}
        notes: list[str] = []
        try:
            gray = read_gray(path, notes)
            if camera is not None:
                camera.check_image(gray.shape, path)
        except FablineError as exc:
            entry["error"] = str(exc)
            failures += 1
            report.append(entry)
            continue
        entry.update({"warnings": notes} if notes else {}, tags=[])
        flagged: list = []
        for det in detect_tags(gray, flagged=flagged):
            # partial: cut by the photo's edge, a corner extrapolated from the edges inside
            tag = {"id": det.tag_id, "corners_px": [[round(x, 3), round(y, 3)] for x, y in det.corners], "partial": det.partial}
            if camera is not None:
                pose = tag_pose(det.corners, camera, args.tag_size)
                tag.update(rotation=[round(v, 6) for v in pose.rotation], translation_mm=[round(v, 3) for v in pose.translation],
                           reprojection_px=round(pose.error_px, 4), ambiguity=round(pose.ambiguity, 4),
                           ambiguous=pose.ambiguous)
            entry["tags"].append(tag)
        # quads that read but are no tags: their code only with more bits corrected, or cells under a pixel across
        entry["flagged"] = [{"id": det.tag_id, "corners_px": [[round(x, 3), round(y, 3)] for x, y in det.corners],
                             "partial": det.partial, "quality": det.quality} for det in flagged]
        report.append(entry)
    if failures == len(report) == 1:
        raise FablineError(report[0]["error"])
    if args.json:
        print(json.dumps(report, indent=1))
    else:
        for entry in report:
            if "error" in entry:
                print(f"{entry['file']}: error: {entry['error']}")
                continue
            ids = [t["id"] for t in entry["tags"]]
            twice = sorted({i for i in ids if ids.count(i) > 1})
            print(f"{entry['file']}: {len(ids)} tag(s)" + (f" {', '.join(map(str, ids))}" if ids else "")
                  + (f"; id(s) {', '.join(map(str, twice))} found more than once" if twice else "")
                  + (f"; {len(entry['flagged'])} quad(s) flagged, not tags: "
                     + ", ".join(f"id {q['id']} ({q['quality']})" for q in entry["flagged"])
                     if entry["flagged"] else ""))
            for note in entry.get("warnings", []):
                print(f"warning: {note}")
    if failures == len(report):
        raise FablineError("no photo could be read")
    return 0


def _calibrate(args: argparse.Namespace) -> int:
    from fabline.survey import BoardSpec, calibrate, list_photos, save_camera, write_board

    try:
        columns, rows = (int(v) for v in args.board.lower().split("x"))
    except ValueError:
        raise FablineError(f"--board {args.board!r}: expected squares as NxM, e.g. 7x5") from None
    spec = BoardSpec(columns, rows, args.square, args.marker)
    check_outputs(files=(args.write_board or args.output,))
    if args.write_board:
        write_board(spec, args.write_board)
        print(f"board written to {args.write_board}: print at {columns * args.square:g} x {rows * args.square:g} mm")
        return 0
    if not args.photos or not args.output:
        raise FablineError("calibrate needs a folder of board photos and -o camera.json (or --write-board)")
    camera, skipped = calibrate(list_photos(args.photos), spec)
    for reason in skipped:
        print(f"skipped {reason}")
    save_camera(camera, args.output)
    print(f"camera {camera.width} x {camera.height} px, fx {camera.matrix[0, 0]:.1f} fy {camera.matrix[1, 1]:.1f}, "
          f"reprojection error {camera.reprojection_error_px:.3f} px -> {args.output}")
    return 0


def _resolution(text: str) -> tuple[int, int]:
    """A `--resolution WxH` in pixels, at least 64 x 64; anything else raises naming the option."""
    from fabline.survey.camera import parse_resolution

    try:
        return parse_resolution(text)
    except FablineError as exc:
        raise FablineError(f"--resolution {exc}") from None


def _simulate(args: argparse.Namespace) -> int:
    from fabline.model import load_network
    from fabline.survey import SyntheticSpec, simulate_survey
    from fabline.survey.photos import check_simulation

    width, height = _resolution(args.resolution)
    if args.photos < 2:
        raise FablineError("--photos must be at least 2")
    check_simulation(width, height, args.photos, args.seed, {"resolution": "--resolution", "photos": "--photos", "seed": "--seed"})
    if not 0 < args.coverage <= 2:
        raise FablineError(f"--coverage must be in (0, 2], got {args.coverage}")
    check_outputs(folders=(args.output,), inputs=(args.model, args.plan))
    poses = None
    if args.plan:
        from fabline.survey.plan import load_plan_poses

        planned, poses = load_plan_poses(args.plan)
        width, height, args.focal, args.photos = planned.width, planned.height, planned.focal_px, len(poses)
        check_simulation(width, height, args.photos, args.seed, {"resolution": f"{args.plan}: camera", "photos":
                         f"{args.plan}: stations", "seed": "--seed"})
    spec = SyntheticSpec(photos=args.photos, width=width, height=height, focal_px=args.focal or width * 5 / 6,
                         sag_mm=args.sag, noise_sigma=args.noise, blur_sigma=args.blur, tag_size_mm=args.tag_size,
                         every=args.every, coverage=args.coverage, seed=args.seed)
    truth = simulate_survey(load_network(args.model), args.output, spec, poses=poses)
    visible = sum(len(p["visible"]) for p in truth["photos"])
    print(f"{len(truth['photos'])} photos, {visible} tag views written to {args.output}")
    return 0


def _plan_camera(args: argparse.Namespace):
    """The survey camera from --camera, --photo (size and EXIF), or --sensor, --focal-length and --resolution."""
    import numpy as np

    from fabline.survey import Camera, load_camera

    given = [name for name, value in (("--camera", args.camera), ("--photo", args.photo),
                                      ("--sensor", args.sensor or args.focal_length or args.resolution)) if value]
    if len(given) != 1:
        raise FablineError("plan needs the camera one way: --camera camera.json, --photo PHOTO (EXIF focal length), or "
                           "--sensor WxH --focal-length F --resolution WxH")
    if args.camera:
        return load_camera(args.camera)
    if args.photo:
        from fabline.survey.photos import check_photo, header_size
        from fabline.survey.selfcal import exif_camera, initial_camera

        check_photo(args.photo)
        photo_size = header_size(args.photo)
        if photo_size is None:
            raise FablineError(f"--photo {args.photo}: not a JPEG or PNG whose size can be read")
        exif = exif_camera(args.photo)
        if "focal_35mm" not in exif:
            raise FablineError(f"--photo {args.photo}: no EXIF 35 mm-equivalent focal length; give --camera or --sensor, "
                               "--focal-length and --resolution")
        return initial_camera(photo_size, exif, [], 65.0)[0]
    if not (args.sensor and args.focal_length and args.resolution):
        raise FablineError("--sensor, --focal-length and --resolution go together (e.g. --sensor 36x24mm "
                           "--focal-length 35mm --resolution 6000x4000)")
    width, height = _resolution(args.resolution)
    if not args.focal_length > 0:
        raise FablineError("--focal-length must be more than 0")
    focal = args.focal_length * width / args.sensor[0]
    matrix = np.array([[focal, 0, (width - 1) / 2], [0, focal * (height / args.sensor[1]) / (width / args.sensor[0]),
                                                     (height - 1) / 2], [0, 0, 1]])
    return Camera(matrix, np.zeros(5), width, height)


def _plan(args: argparse.Namespace) -> int:
    from fabline.fileio import read_json
    from fabline.model import load_network
    from fabline.survey import load_tag_map, make_tag_map
    from fabline.survey.plan import PlanOptions, plan_survey, save_plan, unseen_with_stations, write_plan_svg

    camera = _plan_camera(args)
    check_outputs(folders=(args.output,), inputs=(args.model, args.tags, args.camera, args.photo, args.survey))
    if not 0 < args.max_angle < 90 or not args.min_side > 0 or args.views < 1 or not args.spacing >= 100:
        raise FablineError("--max-angle must be between 0 and 90 degrees, --min-side more than 0 px, --views at least 1 "
                           "and --spacing at least 100 mm")
    network = load_network(args.model)
    tag_map = load_tag_map(args.tags) if args.tags else make_tag_map(network)
    from fabline.survey.tagmap import check_tag_map

    check_tag_map(tag_map, network.in_mm())
    survey = read_json(args.survey) if args.survey else None
    if survey is not None and (not isinstance(survey, dict) or survey.get("schema") != "fabline.survey/1"):
        raise FablineError(f"--survey {args.survey}: not a fabline.survey/1 file")
    options = PlanOptions(height_mm=args.height, max_angle_deg=args.max_angle, min_side_px=args.min_side,
                          views=args.views, spacing_mm=args.spacing)
    plan = plan_survey(network, tag_map, camera, options)
    out = Path(args.output)
    data = save_plan(plan, network.name, out / "plan.json")
    write_plan_svg(network, plan, out / "plan.svg")
    print(f"{'station':>7}  {'x m':>7} {'y m':>7} {'z m':>6}  {'where':<6} {'facing':>7} {'down':>5}  nodes seen")
    for station in data["stations"]:
        x, y, z = (v / 1000 for v in station["position_mm"])
        print(f"{station['station']:>7}  {x:>7.2f} {y:>7.2f} {z:>6.2f}  {station['where']:<6} {station['azimuth_deg']:>6.0f}d "
              f"{station['tilt_deg']:>4.0f}d  {len(station['nodes'])}")
    tagged = len(plan.seen_by)
    print(f"{len(plan.stations)} stations at {args.height / 1000:g} m (of {plan.candidates} candidates) see "
          f"{tagged - len(plan.short)} of {tagged} tagged nodes from {args.views} or more stations -> {out / 'plan.json'}, "
          f"{out / 'plan.svg'}")
    if plan.short:
        listed = ", ".join(f"{nid} ({n})" for nid, n in list(plan.short.items())[:20])
        print(f"warning: {len(plan.short)} node(s) seen from fewer than {args.views} stations at this height (from how "
              f"many): {listed}{', ...' if len(plan.short) > 20 else ''}; try a greater --height or another camera")
    if survey is not None:
        unseen = unseen_with_stations(plan, survey)
        print(f"{len(unseen)} node(s) not measured in {args.survey}" + (":" if unseen else ""))
        for nid, why, stations in unseen:
            if nid not in plan.seen_by:
                print(f"  {nid} ({why})")
                continue
            where = f"stations {', '.join(map(str, stations))}" if stations else "no station at this height"
            print(f"  {nid} ({why}): seen from {where}")
    return 0


def _scale_bar(values: list[str]) -> tuple[int, int, float]:
    """Parse one `--scale-bar TAG_A TAG_B DIST_MM`; a non-number raises naming the bar."""
    try:
        return int(values[0]), int(values[1]), parse_length(values[2], "mm")
    except ValueError:
        raise FablineError(f"--scale-bar {' '.join(values)}: expected two tag ids and a distance in mm "
                           "(or with a unit: 1.2m)") from None


def _camera_map(path: str) -> dict[str, str]:
    """A `--camera-map` file: a JSON object of photo file names to camera names; anything else raises naming it."""
    from fabline.fileio import read_json

    data = read_json(path)
    if not isinstance(data, dict) or not all(isinstance(v, str) and v for v in data.values()):
        raise FablineError(f"{path}: a camera map is a JSON object of photo file names to camera names")
    return data


def _measure(args: argparse.Namespace) -> int:
    from fabline.model import load_network
    from fabline.survey import MeasureOptions, list_photos, load_camera, load_tag_map, make_tag_map, measure_survey

    check_outputs(folders=(args.output,), inputs=(args.model, args.camera, args.tags))
    network = load_network(args.model)
    tag_map = load_tag_map(args.tags) if args.tags else make_tag_map(network)
    reference = args.reference if args.reference in ("all", "supports") else [n.strip() for n in args.reference.split(",") if n.strip()]
    options = MeasureOptions(tolerance_mm=args.tolerance, reference=reference, min_views=args.min_views,
                             scale_bars=tuple(_scale_bar(values) for values in args.scale_bar),
                             scale_min_cell_px=args.scale_min_cell, k_sigma=args.k_sigma, calibrate=args.calibrate,
                             radial_only=args.radial_only, camera_map=_camera_map(args.camera_map) if args.camera_map else None)
    camera = load_camera(args.camera) if args.camera else None
    record = measure_survey(list_photos(args.photos), network, camera, tag_map, args.output, options)
    for problem in record["problems"]:
        print(f"warning: {problem['problem']}")
    for fitted in record["cameras"] or []:
        sigma = {k: float("inf") if v is None else v for k, v in fitted["sigma"].items()}
        print(f"camera {fitted['name']} ({fitted['photos']} photos, from {fitted['initial']}): f {fitted['f_px']} "
              f"+/- {sigma.get('f', 0):.3g} px, principal point ({fitted['cx']}, {fitted['cy']}) +/- "
              f"({sigma.get('cx', 0):.2g}, {sigma.get('cy', 0):.2g}) px, k1 {fitted['distortion'][0]:.4f} "
              f"+/- {sigma.get('k1', 0):.2g}, k2 {fitted['distortion'][1]:.4f} +/- {sigma.get('k2', 0):.2g}")
    from fabline.verdicts import reach_text, verdict_text

    s = record["summary"]
    print(f"{s['measured']} of {s['nodes']} nodes measured from {s['photos_used']} of {s['photos']} photos: "
          f"RMS deviation {mm(s['rms_deviation_mm'])} mm, max {mm(s['max_deviation_mm'])} mm; at {record['tolerance_mm']:g} mm "
          f"({s['k_sigma']:g} sigma) {verdict_text(s)}; {s['tags_found_where_predicted']} tag view(s) "
          f"found where the reconstruction predicted them -> {Path(args.output) / 'survey.json'}")
    print(f"not seen: {reach_text(s, record['not_seen_regions'])}")
    return 0
