"""Job files (`jobs/*.toml`): what to build, from what, on which machine, into which folder; checked key by key.

Every mistake is one line naming the file and the key path (`pavilion.toml: machine.port: expected a
string, got integer`). Paths in a job file are relative to the file's folder; every output lands inside
`output.folder`, and a name that would put one outside it is refused.
"""

from __future__ import annotations

import inspect
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from fabline.errors import FablineError
from fabline.fileio import parse_toml, read_text, vet_input
from fabline.units import job_length, parse_load

if TYPE_CHECKING:  # the nesting stage pulls in shapely; a job file is read before any stage runs
    from fabline.export import ToolpathOptions
    from fabline.machine.profile import MachineProfile
    from fabline.model_units import Length
    from fabline.nest.nester import NestOptions
    from fabline.unroll.options import UnrollOptions

STAGES = ("unroll", "analyse", "assembly", "nest", "export", "stream", "survey", "report")
"""Pipeline stages after the model, in the order they run; a job lists the ones it wants."""

DEFAULT_STAGES = ("unroll", "nest", "export", "stream", "report")
"""The stages of a job that does not list its own; `survey` joins them when the job sets `survey.simulate`."""
DEFAULT_PORT = "sim://grbl"
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]*")
NAME_MAX = 100
"""Characters a job's name may have: it starts output file names (`NAME_SHEET-ID_all-sheets.dxf`, temp files with
their prefix), which must stay under the file systems' 255 bytes."""
"""Bytes a job file may have (a job file is a page of TOML; anything larger is a mistake or an attack)."""
_TYPE_NAMES = {str: "a string", int: "an integer", float: "a number", bool: "true or false", list: "a list",
               dict: "a table", object: "a number or a string", (bool, str): "true, false or a string"}


@dataclass(frozen=True)
class Key:
    """One allowed key of a table: its type, whether it must be given, and its default; a length key (`unit` set)
    takes a number in that unit or a string with a unit (`"25 cm"`), as the command line's option does."""

    kind: type | tuple[type, ...]
    required: bool = False
    default: Any = None
    unit: str | None = None


def Length(default: float | None = None) -> Key:
    """A length key in mm."""
    return Key(float, default=default, unit="mm")


SCHEMA: dict[str, Any] = {
    "name": Key(str, required=True),
    "description": Key(str, default=""),
    "stages": Key(list, default=list(DEFAULT_STAGES)),
    "model": {"design": Key(str), "file": Key(str), "mesh": Key(str), "options": Key(dict, default={})},
    "lamella": {"material": Key(str, default="stainless"), "profile": Key(str, default="100x1.5"),
                "materials_file": Key(str)},
    "stock": {"sheet": Key(str, default="4000x2000"), "count": Key(int), "file": Key(str),
              "plate_sheet": Key(str, default="2000x1000")},
    # [unroll], [nest] and [export] hold every option of `fabline unroll`, `nest` and `export` under its own name
    # (--pair-spacing is unroll.pair_spacing); a key left out takes the command's default (None here)
    "unroll": {"pair_spacing": Length(), "slot_clearance": Length(), "slot_width": Length(),
               "overlap": Length(), "min_overlap": Length(), "screw_hole": Length(),
               "sheet_length": Length(), "sheet_margin": Length(),
               "end_length": Length(), "compensate_twist": Key(bool), "singularity": Key(str),
               "hardware": Key(bool), "text_height": Length(), "min_crossing_angle": Key(float),
               "strict": Key(bool), "previews": Key(bool, default=False), "edge_members": Key(bool),
               "edge_width": Length(), "cable_pretension": Key(object), "cable_end_allowance": Length(),
               "supports": Key(bool), "support_plate": Length(), "support_material": Key(str),
               "support_height": Length(), "couplers": Key(int)},
    "nest": {"kerf": Length(0.2), "gap": Length(3.0), "sheet_margin": Length(10.0),
             "rotations": Key(int, default=4), "time_limit": Key(float, default=10.0),
             "common_line": Key(bool, default=False), "fill_holes": Key(bool, default=False),
             "remnants_first": Key(bool, default=False), "remnant_min": Key(str, default="400x200"),
             "stock_out": Key(str), "svg": Key(bool, default=False)},
    "export": {"kerf": Length(), "lead_in": Length(), "pierce_clearance": Length(), "tabs": Key(int),
               "tab_width": Length(), "tabs_below": Length(), "tab_every": Length(),
               "optimise": Key(bool, default=True), "previews": Key(bool, default=True)},
    "machine": {"profile": Key(str, default="grbl-laser"), "port": Key(str), "ports": Key(list),
                "time_scale": Key(float, default=1.0)},
    "output": {"folder": Key(str, required=True), "report": Key(str, default="report.html")},
    # the assembly plan (fabline.assembly): `segments` of them, or the fewest no larger than `max_segment`
    "assembly": {"segments": Key(int), "max_segment": Length()},
    "survey": {"result": Key(str), "simulate": Key(bool, default=False), "photos": Key(int), "resolution": Key(str),
               "coverage": Key(float), "sag_mm": Length(), "seed": Key(int), "tolerance_mm": Length(),
               "reference": Key(str), "scale_bars": Key(int), "plan": Key((bool, str))},
    # the analyse stage's settings, `fabline analyse`'s options under their own names (--no-buckling is buckling)
    "analysis": {"snow": Key(object, default=0.75), "wind": Key(object, default=0.5), "person": Key(object, default=1000.0),
                 "gamma_g": Key(float, default=1.35), "gamma_q": Key(float, default=1.5),
                 "supports": Key(str, default="pinned"), "stations": Key(int, default=2),
                 "buckling": Key(bool, default=True)},
}

ALIASES = {"nest": {"margin": "sheet_margin"}}
"""Old key names that still work, per table: old -> canonical (the command line's option name)."""

SIMULATED_SURVEY_DEFAULTS = {"photos": 12, "resolution": "3600x2400", "coverage": 0.7, "sag_mm": 25.0, "seed": 1,
                             "tolerance_mm": 20.0, "reference": "all", "scale_bars": 0, "plan": False}
"""The `[survey]` keys of a simulated survey (`simulate = true`) and their defaults; they mean nothing without it."""


@dataclass
class JobSpec:
    """A checked job file: the raw tables with defaults filled in and paths resolved against the file's folder."""

    path: Path
    name: str
    description: str
    stages: tuple[str, ...]
    model: dict[str, Any]
    lamella: dict[str, Any]
    stock: dict[str, Any]
    nest: dict[str, Any]
    machine: dict[str, Any]
    output_folder: Path
    report_name: str
    survey: dict[str, Any] = field(default_factory=dict)
    unroll: dict[str, Any] = field(default_factory=dict)
    export: dict[str, Any] = field(default_factory=dict)
    assembly: dict[str, Any] = field(default_factory=dict)
    analysis: dict[str, Any] = field(default_factory=dict)

    def output(self, relative: str | os.PathLike) -> Path:
        """An output path inside the job's output folder; a path that would leave it is a FablineError."""
        return inside(self.output_folder, relative, f"{self.path.name}: output")

    def to_dict(self) -> dict[str, Any]:
        """The job as plain data for the report and the runner's database."""
        return {"path": str(self.path), "name": self.name, "description": self.description, "stages": list(self.stages),
                "model": self.model, "lamella": self.lamella, "stock": self.stock, "unroll": self.unroll,
                "nest": self.nest, "export": self.export,
                "machine": self.machine, "output": {"folder": str(self.output_folder), "report": self.report_name},
                "survey": self.survey, "assembly": self.assembly, "analysis": self.analysis}


def inside(folder: Path, relative: str | os.PathLike, where: str) -> Path:
    """`folder / relative`, refused (FablineError naming `where`) if it resolves outside `folder`."""
    base = Path(os.path.realpath(folder))
    target = Path(os.path.realpath(base / relative))
    if target != base and base not in target.parents:
        raise FablineError(f"{where}: {str(relative)!r} would be written outside the output folder {base}")
    return target


def load_job_file(path: str | os.PathLike) -> JobSpec:
    """Read and check a job file; every problem is a one-line FablineError naming the file and key path."""
    path = Path(path)
    return job_from_text(read_text(path, kind="config"), path)


def job_from_text(text: str, path: Path, where: str | None = None) -> JobSpec:
    """Parse and check a job file's text as if it lay at `path` (a file read, or an upload before it is written);
    a TOML error names `where` (default: the path)."""
    return job_from_dict(parse_toml(text, str(where or path)), path)


def job_from_dict(raw: dict[str, Any], path: Path) -> JobSpec:
    """Check a parsed job table against SCHEMA and the stages' own vocabularies; `path` anchors relative paths."""
    where = path.name
    data = _check_table(raw, SCHEMA, where, "")
    base = path.resolve().parent
    if not _NAME.fullmatch(data["name"]):
        raise FablineError(f"{where}: name: {data['name']!r} must be letters, digits, '.', '_' or '-' "
                           "(it names output files)")
    if len(data["name"]) > NAME_MAX:
        raise FablineError(f"{where}: name: {len(data['name'])} characters, at most {NAME_MAX} (it names output files)")
    model = _check_model(data["model"], base, where)
    if "mesh" in model and data["lamella"]["materials_file"] is not None:
        raise FablineError(f"{where}: lamella.materials_file: not with model.mesh (the tracer's strip limits take a "
                           "built-in material); trace with `fabline design asymptotic` and give model.file")
    for section, key in (("lamella", "materials_file"), ("stock", "file"), ("survey", "result")):
        if data[section][key] is not None:
            data[section][key] = str(_existing(base, data[section][key], f"{where}: {section}.{key}"))
    if isinstance(data["survey"]["plan"], str):
        data["survey"]["plan"] = str(_existing(base, data["survey"]["plan"], f"{where}: survey.plan"))
    survey = _check_survey(data["survey"], where)
    stages = _check_stages(data["stages"] if "stages" in raw else _default_stages(survey), where)
    if ("survey" in stages) != survey["simulate"]:
        raise FablineError(f"{where}: stages: 'survey' needs survey.simulate = true" if "survey" in stages else
                           f"{where}: survey.simulate: true but 'survey' is not in stages")
    assembly = _check_assembly(data["assembly"], "assembly" in stages, where)
    analysis = _check_analysis(data["analysis"], where)
    data["machine"]["ports"] = _check_ports(data["machine"], where)
    if data["machine"]["profile"].endswith(".toml"):
        data["machine"]["profile"] = str(_existing(base, data["machine"]["profile"], f"{where}: machine.profile"))
    _check_values(data, where)
    folder = base / data["output"]["folder"]
    if folder.exists() and not folder.is_dir():
        raise FablineError(f"{where}: output.folder: {folder} exists and is not a folder")
    spec = JobSpec(path=path.resolve(), name=data["name"], description=data["description"], stages=stages, model=model,
                   lamella=data["lamella"], stock=data["stock"], nest=data["nest"], machine=data["machine"],
                   output_folder=folder.resolve(), report_name=data["output"]["report"], survey=survey,
                   unroll=data["unroll"], export=data["export"], assembly=assembly,
                   analysis=analysis)
    if spec.nest["stock_out"] is not None:
        spec.output(spec.nest["stock_out"])  # refused here if it would leave the output folder
    _check_port_files(spec, where)
    report = spec.output(spec.report_name)
    if report.suffix != ".html":
        raise FablineError(f"{where}: output.report: {spec.report_name!r} must end in .html")
    return spec


def _check_port_files(spec: JobSpec, where: str) -> None:
    """Each port URL checked as the link stage will open it: known options only, and a file it writes (a spy's
    file=, a simulator's log=) inside the output folder and none of the job's inputs."""
    from fabline.link import check_port

    inputs = (spec.path, spec.model.get("file"), spec.model.get("mesh"), spec.lamella["materials_file"], spec.stock["file"],
              spec.survey.get("result"))
    key = "machine.port" if spec.machine.get("port") is not None else "machine.ports"
    for port in spec.machine["ports"]:
        try:
            check_port(port, inputs=tuple(i for i in inputs if i), within=spec.output_folder)
        except FablineError as exc:
            raise FablineError(f"{where}: {key}: {exc}") from None


def _check_table(raw: Any, schema: dict[str, Any], where: str, prefix: str) -> dict[str, Any]:
    """Unknown keys, wrong types and missing required keys of one table, recursively; defaults filled in."""
    if not isinstance(raw, dict):
        raise FablineError(f"{where}: {prefix.rstrip('.')}: expected a table, got {_type_name(raw)}")
    raw = _renamed(raw, ALIASES.get(prefix.rstrip("."), {}), where, prefix)
    for key in raw:
        if key not in schema:
            raise FablineError(f"{where}: {prefix}{key}: unknown key (allowed: {', '.join(schema)})")
    checked: dict[str, Any] = {}
    for key, rule in schema.items():
        key_path = f"{prefix}{key}"
        if isinstance(rule, dict):
            checked[key] = _check_table(raw.get(key, {}), rule, where, f"{key_path}.")
            continue
        if key not in raw:
            if rule.required:
                raise FablineError(f"{where}: {key_path}: missing (required)")
            checked[key] = rule.default.copy() if isinstance(rule.default, (list, dict)) else rule.default
            continue
        checked[key] = _typed(raw[key], rule.kind, where, key_path, rule.unit)
    return checked


def _renamed(raw: dict[str, Any], aliases: dict[str, str], where: str, prefix: str) -> dict[str, Any]:
    """`raw` with its old key names replaced by the canonical ones; both names of one key is a FablineError."""
    renamed = dict(raw)
    for old, new in aliases.items():
        if old in renamed:
            if new in renamed:
                raise FablineError(f"{where}: {prefix}{old}: the old name of {prefix}{new}; give only {prefix}{new}")
            renamed[new] = renamed.pop(old)
    return renamed


def _typed(value: Any, kind: type, where: str, key_path: str, unit: str | None = None) -> Any:
    """`value` if it is of `kind` (an integer is accepted as a number; a length also as a string with a unit, in
    `unit` after), else a FablineError naming the key."""
    if unit is not None and isinstance(value, (str, int, float)) and not isinstance(value, bool):
        try:
            return job_length(value, unit)
        except FablineError as exc:
            raise FablineError(f"{where}: {key_path}: {exc}") from None
    if kind is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    kinds = kind if isinstance(kind, tuple) else (kind,)
    if isinstance(value, kinds) and not (bool not in kinds and isinstance(value, bool)):
        return value
    raise FablineError(f"{where}: {key_path}: expected {_TYPE_NAMES[kind]}, got {_type_name(value)} {value!r}")


def _type_name(value: Any) -> str:
    for kind in (bool, int, float, str, list, dict):
        if isinstance(value, kind):
            return {"bool": "boolean", "int": "integer", "float": "number", "str": "string",
                    "list": "list", "dict": "table"}[kind.__name__]
    return type(value).__name__


def _check_stages(stages: list, where: str) -> tuple[str, ...]:
    for k, stage in enumerate(stages):
        if stage not in STAGES:
            raise FablineError(f"{where}: stages[{k}]: unknown stage {stage!r} (use some of {', '.join(STAGES)})")
    if len(set(stages)) != len(stages):
        raise FablineError(f"{where}: stages: a stage is listed twice")
    for stage, needs in (("analyse", "unroll"), ("assembly", "unroll"), ("nest", "unroll"), ("export", "nest"), ("stream", "export")):
        if stage in stages and needs not in stages:
            raise FablineError(f"{where}: stages: '{stage}' needs '{needs}' in the same job")
    return tuple(s for s in STAGES if s in stages)


def _default_stages(survey: dict[str, Any]) -> list[str]:
    return list(DEFAULT_STAGES) + (["survey"] if survey["simulate"] else [])


def _check_survey(survey: dict[str, Any], where: str) -> dict[str, Any]:
    """`survey.result` (an existing survey to show) or `survey.simulate` with its settings, defaults filled in."""
    from fabline.jobs.survey_stage import load_survey_result
    from fabline.survey.camera import parse_resolution
    from fabline.survey.photos import check_simulation

    if survey["result"] is not None and survey["simulate"]:
        raise FablineError(f"{where}: survey: give survey.result (an existing survey) or survey.simulate = true, not both")
    if not survey["simulate"]:
        given = [key for key in SIMULATED_SURVEY_DEFAULTS if survey[key] is not None]
        if given:
            raise FablineError(f"{where}: survey.{given[0]}: only with survey.simulate = true")
        if survey["result"] is not None:
            try:
                load_survey_result(survey["result"])
            except FablineError as exc:
                raise FablineError(f"{where}: survey.result: {exc}") from None
        return {"result": survey["result"], "simulate": False}
    checked = {"result": None, "simulate": True,
               **{key: default if survey[key] is None else survey[key] for key, default in SIMULATED_SURVEY_DEFAULTS.items()}}
    _check_plan(survey, checked, where)
    try:
        width, height = parse_resolution(checked["resolution"])
    except FablineError as exc:
        raise FablineError(f"{where}: survey.resolution: {exc}") from None
    for key, ok, rule in (("photos", checked["photos"] >= 2, "must be at least 2"),
                          ("coverage", 0 < checked["coverage"] <= 2, "must be in (0, 2]"),
                          ("sag_mm", checked["sag_mm"] >= 0, "must not be negative"),
                          ("seed", checked["seed"] >= 0, "must not be negative"),
                          ("tolerance_mm", checked["tolerance_mm"] > 0, "must be positive"),
                          ("scale_bars", 0 <= checked["scale_bars"] <= 2, "must be 0, 1 or 2")):
        if not ok:
            raise FablineError(f"{where}: survey.{key}: {rule}, got {checked[key]}")
    check_simulation(width, height, checked["photos"], checked["seed"],
                     {key: f"{where}: survey.{key}" for key in ("resolution", "photos", "seed")})
    if checked["reference"] not in ("all", "supports"):
        raise FablineError(f"{where}: survey.reference: {checked['reference']!r} must be 'all' or 'supports'")
    return checked




def _check_analysis(analysis: dict[str, Any], where: str) -> dict[str, Any]:
    """The analyse stage's settings: loads with units (snow and wind in kN/m2, the person in N), partial factors at
    least 1, supports pinned or fixed, 1 to 16 beams per node interval."""
    checked = dict(analysis)
    for key, unit in (("snow", "kN/m2"), ("wind", "kN/m2"), ("person", "N")):
        checked[key] = _quantity(analysis[key], unit, f"{where}: analysis.{key}")
    for key, ok, rule in (("gamma_g", 1.0 <= analysis["gamma_g"] < 10, "must be 1 to 10"),
                          ("gamma_q", 1.0 <= analysis["gamma_q"] < 10, "must be 1 to 10"),
                          ("stations", 1 <= analysis["stations"] <= 16, "must be 1 to 16"),
                          ("supports", analysis["supports"] in ("pinned", "fixed"), "must be 'pinned' or 'fixed'")):
        if not ok:
            raise FablineError(f"{where}: analysis.{key}: {rule}, got {analysis[key]!r}")
    return checked


def _quantity(value: Any, unit: str, where: str) -> float:
    """A load key in `unit` (`fabline.units.parse_load`), its mistake named by `where`."""
    try:
        return parse_load(value, unit)
    except ValueError as exc:
        raise FablineError(f"{where}: {exc}") from None


def _check_plan(survey: dict[str, Any], checked: dict[str, Any], where: str) -> None:
    """`survey.plan`: true (plan the stations from the design, `fabline survey plan`, the photos one per station) or a
    plan file (its camera's resolution and its stations' count are the photos'), neither with `survey.photos`."""
    plan = checked["plan"]
    if plan is False:
        return
    for key in ("photos",) + (("resolution",) if isinstance(plan, str) else ()):
        if survey[key] is not None:
            raise FablineError(f"{where}: survey.{key}: the plan sets it (one photo per station"
                               + (", its camera's resolution" if key == "resolution" else "") + "); leave it out")
    if isinstance(plan, str):
        from fabline.survey.plan import load_plan_poses

        try:
            camera, poses = load_plan_poses(plan)
        except FablineError as exc:
            raise FablineError(f"{where}: survey.plan: {exc}") from None
        checked["photos"], checked["resolution"] = len(poses), f"{camera.width}x{camera.height}"


DEFAULT_MAX_SEGMENT_MM = 5000.0
"""The assembly stage's largest segment when the job names neither a count nor a size (`fabline assembly`'s)."""


def _check_assembly(assembly: dict[str, Any], staged: bool, where: str) -> dict[str, Any]:
    """`assembly.segments` (a count) or `assembly.max_segment` (a length), only with the assembly stage; neither
    takes the default size."""
    given = [key for key, value in assembly.items() if value is not None]
    if given and not staged:
        raise FablineError(f"{where}: assembly.{given[0]}: only with 'assembly' in stages")
    if len(given) > 1:
        raise FablineError(f"{where}: assembly: give assembly.segments (how many) or assembly.max_segment (how large), "
                           "not both")
    count, size = assembly["segments"], assembly["max_segment"]
    if count is not None and not 1 <= count <= 1000:
        raise FablineError(f"{where}: assembly.segments: must be 1 to 1000, got {count}")
    if size is not None and not 0 < size < math.inf:
        raise FablineError(f"{where}: assembly.max_segment: must be a positive length, got {size:g} mm")
    return {"segments": count, "max_segment": size if size is not None or count is not None else DEFAULT_MAX_SEGMENT_MM}


def _check_ports(machine: dict[str, Any], where: str) -> list[str]:
    """machine.port (one machine) or machine.ports (several, cutting sheets in parallel); default the simulator."""
    if machine["port"] is not None and machine["ports"] is not None:
        raise FablineError(f"{where}: machine: give machine.port or machine.ports, not both")
    if machine["ports"] is None:
        return [machine["port"] or DEFAULT_PORT]
    if not machine["ports"]:
        raise FablineError(f"{where}: machine.ports: give at least one port")
    ports = [_typed(port, str, where, f"machine.ports[{k}]") for k, port in enumerate(machine["ports"])]
    if len(set(ports)) != len(ports):
        raise FablineError(f"{where}: machine.ports: a port is listed twice")
    return ports


MESH_OPTIONS = {"spacing": Key(object, required=True), "step": Key(object), "seed": Key(list), "supports": Key(str),
                "units": Key(str)}
"""`[model.options]` of a job that starts from a mesh: `fabline design asymptotic`'s options under their own names;
spacing and step in the model's units (a number) or with a unit (`"70 mm"`)."""


def _check_model(model: dict[str, Any], base: Path, where: str) -> dict[str, Any]:
    """Exactly one of model.design (a built-in design, options checked against its signature), model.file (a
    network) or model.mesh (a surface traced by `design asymptotic` with its options)."""
    from fabline.model.designs import DESIGNS

    given = [key for key in ("design", "file", "mesh") if model[key] is not None]
    if len(given) != 1:
        raise FablineError(f"{where}: model: give exactly one of model.design ({', '.join(DESIGNS)}), model.file "
                           "(a network) or model.mesh (a surface to trace)")
    if model["mesh"] is not None:
        return {"mesh": str(_existing(base, model["mesh"], f"{where}: model.mesh")),
                "options": _check_mesh_options(model["options"], where)}
    if model["file"] is not None:
        if model["options"]:
            raise FablineError(f"{where}: model.options: only for a built-in design or a mesh, not with model.file")
        return {"file": str(_existing(base, model["file"], f"{where}: model.file")), "options": {}}
    if model["design"] not in DESIGNS:
        raise FablineError(f"{where}: model.design: unknown design {model['design']!r} (use one of {', '.join(DESIGNS)})")
    parameters = inspect.signature(DESIGNS[model["design"]]).parameters
    options = {}
    for key, value in model["options"].items():
        key_path = f"model.options.{key}"
        if key not in parameters:
            raise FablineError(f"{where}: {key_path}: unknown option of design {model['design']} "
                               f"(allowed: {', '.join(parameters)})")
        default = parameters[key].default
        if isinstance(default, tuple):
            value = _typed(value, list, where, key_path)
            if len(value) != len(default):
                raise FablineError(f"{where}: {key_path}: expected {len(default)} values, got {len(value)}")
            value = tuple(_typed(v, type(d), where, f"{key_path}[{k}]") for k, (v, d) in enumerate(zip(value, default)))
        else:
            value = _typed(value, type(default), where, key_path)
        options[key] = value
    return {"design": model["design"], "options": options}


def _check_mesh_options(options: dict[str, Any], where: str) -> dict[str, Any]:
    """The tracing options of model.mesh: lengths parse (`mesh_length`), the seed is three finite numbers, the
    units are a model unit; the ones left out are left out (the command's defaults)."""
    from fabline.model_units import UNIT_NAMES

    checked = _check_table(options, MESH_OPTIONS, where, "model.options.")
    for key in ("spacing", "step"):
        if checked[key] is not None:
            mesh_length(checked[key], f"{where}: model.options.{key}")
    if checked["seed"] is not None:
        seed = [_typed(v, float, where, f"model.options.seed[{k}]") for k, v in enumerate(checked["seed"])]
        if len(seed) != 3 or not all(math.isfinite(v) for v in seed):
            raise FablineError(f"{where}: model.options.seed: expected three finite numbers [x, y, z] in model units, "
                               f"got {checked['seed']!r}")
        checked["seed"] = seed
    if checked["units"] is not None and checked["units"] not in UNIT_NAMES:
        raise FablineError(f"{where}: model.options.units: {checked['units']!r} is not a unit (use one of "
                           f"{', '.join(UNIT_NAMES)})")
    return {key: value for key, value in checked.items() if value is not None}


def mesh_length(value: Any, where: str) -> Length:
    """A mesh job's spacing or step: a number in the model's units or a string with a unit, positive."""
    from fabline.model_units import Length, parse_model_length

    if isinstance(value, bool) or not isinstance(value, (int, float, str)):
        raise FablineError(f"{where}: expected a number (model units) or a string with a unit, got {_type_name(value)}")
    try:
        length = parse_model_length(value) if isinstance(value, str) else Length(float(value))
    except ValueError as exc:
        raise FablineError(f"{where}: {exc}") from None
    if not 0 < length.value < math.inf:
        raise FablineError(f"{where}: must be a positive length, got {value!r}")
    return length


def _existing(base: Path, relative: str, where: str) -> Path:
    """A file the job names, relative to its folder; a missing one, a NUL in its name and anything but a regular
    file (a folder, FIFO or device: `vet_input` says which) are refused naming the key."""
    path = base / relative
    if "\0" not in relative and not os.path.lexists(path):
        raise FablineError(f"{where}: file not found: {path}")
    try:
        vet_input(path, "model")  # the largest kind: a smaller kind's limit is its reader's to check
    except FablineError as exc:
        raise FablineError(f"{where}: {exc}") from None
    return path.resolve()


def nest_options(nest: dict[str, Any]) -> "NestOptions":
    """The nesting stage's options from a job's [nest] table (remnant_min checked: a FablineError names the key)."""
    from fabline.nest.nester import NestOptions
    from fabline.shop.stock import parse_sheet_size

    try:
        remnant_min = parse_sheet_size(nest["remnant_min"])
    except FablineError as exc:
        raise FablineError(f"nest.remnant_min: {exc}") from None
    return NestOptions(kerf=nest["kerf"], gap=nest["gap"], margin=nest["sheet_margin"], rotation_steps=nest["rotations"],
                       time_limit=nest["time_limit"], common_line=nest["common_line"], fill_holes=nest["fill_holes"],
                       remnants_first=nest["remnants_first"], remnant_min=remnant_min)


def unroll_options(lamella: dict[str, Any], unroll: dict[str, Any], stock: dict[str, Any],
                   nest: dict[str, Any]) -> "UnrollOptions":
    """The unroll stage's options from a job's tables, checked (a FablineError names the key): profile and material
    from [lamella], the strip length limit from the sheet's longer side and nest.sheet_margin unless [unroll] sets them."""
    from fabline.mechanics.materials import get_material, parse_profile
    from fabline.unroll.options import UnrollOptions

    from fabline.unroll.cables import parse_pretension

    given = {key: value for key, value in unroll.items() if value is not None and key != "previews"}
    if "cable_pretension" in given:
        given["cable_pretension"] = parse_pretension(given["cable_pretension"], "unroll.cable_pretension")
    given.setdefault("sheet_length", _sheet_length(stock))
    given.setdefault("sheet_margin", nest["sheet_margin"])
    options = UnrollOptions(profile=parse_profile(lamella["profile"]),
                            material=get_material(lamella["material"], lamella["materials_file"]), **given)
    return options.check(name=lambda key: f"unroll.{key}")


def _sheet_length(stock: dict[str, Any]) -> float:
    """The longer side of the job's sheet, mm: the stock file's first full sheet (0 if it has none) or stock.sheet."""
    from fabline.shop.stock import load_stock, parse_sheet_size

    if stock["file"]:
        sheets = [item for item in load_stock(stock["file"]) if not item.remnant]
        return max(sheets[0].width, sheets[0].height) if sheets else 0.0
    return max(parse_sheet_size(stock["sheet"]))


def toolpath_options(export: dict[str, Any], profile: "MachineProfile") -> "ToolpathOptions":
    """The export stage's options from a job's [export] table; a key left out takes the machine profile's (its kerf
    and [cutting] rule), as the command's options do."""
    from fabline.export import ToolpathOptions
    from fabline.machine.profile import TOOLPATH_MINIMA

    return ToolpathOptions.for_profile(profile, optimise=export["optimise"],
                                       **{key: export[key] for key in TOOLPATH_MINIMA})


def _check_values(data: dict[str, Any], where: str) -> None:
    """Ranges and vocabularies: sheet size, profile, material, machine profile, positive numbers."""
    from fabline.machine.profile import TOOLPATH_MINIMA, available_machines, load_machine
    from fabline.mechanics.materials import load_materials, parse_profile
    from fabline.shop.stock import parse_sheet_size

    def wrapped(key_path: str, check, *args):
        try:
            return check(*args)
        except FablineError as exc:
            raise FablineError(f"{where}: {key_path}: {exc}") from None

    wrapped("stock.sheet", parse_sheet_size, data["stock"]["sheet"])
    wrapped("stock.plate_sheet", parse_sheet_size, data["stock"]["plate_sheet"])
    wrapped("lamella.profile", parse_profile, data["lamella"]["profile"])
    materials = wrapped("lamella.materials_file", load_materials, data["lamella"]["materials_file"])
    if data["lamella"]["material"] not in materials:
        raise FablineError(f"{where}: lamella.material: unknown material {data['lamella']['material']!r} "
                           f"(use one of {', '.join(sorted(materials))})")
    machine = data["machine"]["profile"]
    if machine not in available_machines() and not machine.endswith(".toml"):
        raise FablineError(f"{where}: machine.profile: unknown machine {machine!r} "
                           f"(use one of {', '.join(available_machines())} or a .toml file)")
    wrapped("machine.profile", load_machine, machine)  # a bad profile is refused now, not after the stages before export
    count = data["stock"]["count"]
    if count is not None and not count > 0:
        raise FablineError(f"{where}: stock.count: must be positive, got {count}")
    from fabline.link.simulator import check_time_scale

    try:
        check_time_scale(data["machine"]["time_scale"])
    except ValueError as exc:
        raise FablineError(f"{where}: machine.time_scale: {exc}") from None
    if data["unroll"]["support_material"] is not None and data["unroll"]["support_material"] not in materials:
        raise FablineError(f"{where}: unroll.support_material: unknown material {data['unroll']['support_material']!r} "
                           f"(use one of {', '.join(sorted(materials))})")
    try:
        nest_options(data["nest"]).check(name=lambda key: f"nest.{key}")
        unroll_options(data["lamella"], data["unroll"], data["stock"], data["nest"])
    except FablineError as exc:
        raise FablineError(f"{where}: {exc}") from None
    for key, low in TOOLPATH_MINIMA.items():
        value = data["export"][key]
        if value is not None and not low <= value < math.inf:
            raise FablineError(f"{where}: export.{key}: must be a finite number, at least {low:g}, got {value}")
    sheet = _sheet_length(data["stock"])
    for key in ("kerf", "lead_in", "pierce_clearance", "tab_width"):  # a cut feature longer than the sheet cannot be on it
        value = data["export"][key]
        if value is not None and sheet and value > sheet:
            raise FablineError(f"{where}: export.{key}: {value:g} mm is longer than the sheet ({sheet:g} mm)")
