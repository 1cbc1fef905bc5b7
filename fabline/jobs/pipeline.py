"""The main job: model -> unroll -> analyse -> nest -> export -> stream -> survey -> report, every output inside the job's folder.

`prepare_job` runs the stages up to export (what the runner does before any sheet is cut) and writes a
report; `run_job` also streams every sheet to the job's machine (the built-in simulator by default), runs
the (simulated) as-built survey and rewrites the report with the streaming log and the survey. Each
stage's files are written atomically by that stage.
"""

from __future__ import annotations

import os
import signal
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

from fabline.errors import FablineError
from fabline.fileio import OutputSet, atomic_output, check_outputs, read_json, write_json
from fabline.jobs.jobfile import JobSpec, load_job_file, nest_options, toolpath_options, unroll_options
from fabline.jobs.report_analysis import ANALYSIS_NAME
from fabline.jobs.report_shop import machine_seconds
from fabline.progress import Eta, StreamBar, above_bars, estimate, simulated_speedup
from fabline.units import duration, mm
from fabline.verdicts import verdict_text

if TYPE_CHECKING:  # the model stage pulls in scipy; the runner imports this package and must start fast
    from fabline.model import Network

Say = Callable[[str], None]


@dataclass
class JobResult:
    """Everything a job made: the stage results, the files, the timings and the per-sheet streaming log."""

    spec: JobSpec
    network: "Network"
    partset: Any = None
    structure: list[dict] = field(default_factory=list)
    nesting: Any = None
    plate_nesting: Any = None  # the plate parts' (supports') own sheets
    export: Any = None
    sheet_files: list[dict] = field(default_factory=list)
    stream: list[dict] = field(default_factory=list)
    stream_wall_s: float | None = None  # the stream stage's wall time: the machines cut in parallel, never summed
    analysis: dict | None = None  # the analyse stage's record (analysis.json, fabline.analysis/1)
    assembly: dict | None = None  # the assembly plan's summary and its pages (`fabline.assembly`)
    survey: dict | None = None  # the report's survey entry (fabline.jobs.survey_stage.survey_entry)
    timings: dict[str, float] = field(default_factory=dict)
    report_path: Path | None = None

    def sheet_programs(self) -> list[tuple[str, str, str, dict]]:
        """(sheet id, G-code path, labelled sheet SVG path, what the operator loads: `load_facts`) per sheet, in
        cutting order, for the runner."""
        return [(s["sheet"], s["gcode"], s["svg"], load_facts(s)) for s in self.sheet_files]


def load_facts(sheet: dict) -> dict[str, Any]:
    """What the operator needs to load a sheet: its size, material, thickness, part count and picture."""
    return {**{key: sheet[key] for key in ("width_mm", "height_mm", "material", "thickness_mm", "parts")},
            "picture": sheet["svg"]}


def build_network(spec: JobSpec) -> "Network":
    """The job's network: the built-in design with its options, the model file, or the mesh traced as
    `fabline design asymptotic` does (its strip limits from the job's [lamella])."""
    from fabline.model import load_network
    from fabline.model.designs import DESIGNS

    if "file" in spec.model:
        return load_network(spec.model["file"])
    try:
        if "mesh" in spec.model:
            return _traced(spec)
        return DESIGNS[spec.model["design"]](**spec.model["options"])
    except FablineError as exc:
        raise FablineError(f"{spec.path.name}: model: {exc}") from None


def _traced(spec: JobSpec) -> "Network":
    """model.mesh traced with its options, as `fabline design asymptotic` would with the job's strip and the unroll
    stage's pair spacing, slot width and web (so that every crossing it hands over can be slotted)."""
    from fabline.design import design_asymptotic
    from fabline.jobs.jobfile import mesh_length, unroll_options

    options, where = spec.model["options"], f"{spec.path.name}: model.options"
    step = mesh_length(options["step"], f"{where}.step") if "step" in options else None
    unrolled = unroll_options(spec.lamella, spec.unroll, spec.stock, spec.nest)
    return design_asymptotic(spec.model["mesh"], mesh_length(options["spacing"], f"{where}.spacing"), options.get("seed"),
                             options.get("supports"), options.get("units"), step, spec.lamella["material"],
                             spec.lamella["profile"], pair_spacing=unrolled.pair_spacing,
                             slot_pair=unrolled.slot + unrolled.web).network


def prepare_job(job: str | os.PathLike | JobSpec, say: Say = lambda text: None) -> JobResult:
    """Run the job's stages up to export and write the report; returns the result with the sheet programs. The
    stages are one `OutputSet`: a stage that refuses its input leaves the output folder as it was."""
    from fabline.jobs.bom import BOM_NAME
    from fabline.model import save_network
    from fabline.model.extent import extent_text

    spec = job if isinstance(job, JobSpec) else load_job_file(job)
    timings: dict[str, float] = {}
    report = spec.report_name
    names = ("network.json", "parts.json", ANALYSIS_NAME, "nesting.json", report, Path(report).with_suffix(".json"), BOM_NAME,
             PLATES_NESTING, PLATES_CUTLIST)
    with OutputSet():  # a stage refused (or Ctrl-C) removes what every stage before it wrote: the folder is as it was
        check_outputs(files=[spec.output(name) for name in names],
                      folders=[spec.output(name) for name in ("dxf", "gcode", "sheets", ASSEMBLY_FOLDER)],
                      inputs=(spec.path, spec.model.get("file"), spec.model.get("mesh")))
        result = JobResult(spec, network=_timed(timings, "model", lambda: build_network(spec)), timings=timings)
        save_network(result.network, spec.output("network.json"))
        say(f"model: {result.network.name}, {len(result.network.lamellas)} lamellas, {len(result.network.nodes)} nodes, "
            f"{extent_text(result.network)}")
        from fabline.jobs.design_stage import design_lines

        for line in design_lines(result.network):
            say(line)
        if "unroll" in spec.stages:
            _timed(result.timings, "unroll", lambda: _unroll(result))
            say(f"unroll: {len(result.partset.parts)} parts -> {spec.output('parts.json')}")
            for line in structure_lines(result):
                say(line)
        if "analyse" in spec.stages:
            _timed(result.timings, "analyse", lambda: _analyse(result))
            for line in analysis_lines(result.analysis):
                say(f"analyse: {line}")
        if "assembly" in spec.stages:
            _timed(result.timings, "assembly", lambda: _assembly(result))
            plan = result.assembly
            say(f"assembly: {len(plan['segments'])} segments, {len(plan['pages']) - 1} lamella pages -> "
                f"{spec.output(ASSEMBLY_FOLDER)}")
        if "nest" in spec.stages:
            _timed(result.timings, "nest", lambda: _nest(result))
            say(f"nest: {len(result.nesting.sheets)} sheet(s) -> {spec.output('nesting.json')}")
            if result.plate_nesting:
                plates = result.partset.plates
                say(f"nest: {len(plates.parts)} support plates on {len(result.plate_nesting.sheets)} sheet(s) of "
                    f"{plates.profile['t']:g} mm {plates.material} -> {spec.output(PLATES_NESTING)}")
        if "export" in spec.stages:
            _timed(result.timings, "export", lambda: _export(result))
            say(f"export: {len(result.sheet_files)} G-code program(s) -> {spec.output('gcode')}")
        if spec.survey.get("result"):
            from fabline.jobs.survey_stage import load_survey_result

            result.survey = load_survey_result(spec.survey["result"])
        if "report" in spec.stages:
            write_report(result)
    return result


def run_job(job: str | os.PathLike | JobSpec, say: Say = lambda text: None,
            confirm_sheet: Callable[[int, int, dict], None] | None = None, resume: bool = False,
            restart: bool = False, from_line: int | None = None) -> JobResult:
    """The whole job: prepare, then stream every sheet (asking `confirm_sheet(k, n, sheet)` before each one
    when given, `sheet` its entry of `sheet_files`: id, files and `load_facts`), then the survey, then the report with the streaming log and the survey. `resume` continues
    an interrupted run from the sheets' journals (finished sheets are not cut again); otherwise every sheet
    is cut afresh, which an interrupted earlier run refuses unless `restart` says so; `from_line` (with `resume`)
    continues the one interrupted sheet from that file line, the operator's choice. The caller holds the
    output folder's lock (`fabline.locks`), so no other run touches these journals meanwhile."""
    spec = job if isinstance(job, JobSpec) else load_job_file(job)
    if from_line is not None and not resume:
        raise FablineError("--from-line needs --resume (it names where the interrupted sheet continues)")
    if "stream" in spec.stages and not resume and not restart:
        _refuse_over_an_interrupted_run(spec)
    interrupted = _interrupted_sheet(spec) if from_line is not None else None
    result = prepare_job(spec, say)
    if "stream" not in spec.stages and "survey" not in spec.stages:
        return result
    try:
        if "stream" in spec.stages:
            identity = _run_identity(spec, resume)  # kept whatever the stage does, as the journals are
            _timed(result.timings, "stream", lambda: _stream_all(result, say, confirm_sheet, resume, identity,
                                                                    (interrupted, from_line)))
        if "survey" in spec.stages:
            _timed(result.timings, "survey", lambda: _survey(result, say))
    finally:  # the report shows the streaming log, also of a run that stopped
        if "report" in spec.stages:
            write_report(result)
    return result


def structure_lines(result: JobResult) -> list[str]:
    """The unroll stage's structural verdict in the words `fabline unroll` and the report use (none without it)."""
    from fabline.mechanics.structure import verdict_lines

    verdict = result.partset.report.get("verdict") if result.partset else None
    return verdict_lines(verdict) if verdict else []


def write_report(result: JobResult) -> Path:
    """Write the HTML report and its JSON twin into the output folder (the pictures it links, cut-order previews and
    the deviation map, are their stages' files there); returns the HTML's path."""
    from fabline.jobs.report import render_report, report_data

    spec = result.spec
    data = report_data(result)
    result.report_path = spec.output(spec.report_name)
    with OutputSet():  # the page, its twin and the bill's CSV as one: a failure leaves the last complete set
        write_json(spec.output(Path(spec.report_name).with_suffix(".json")), data)
        if data["bill_of_materials"]:
            from fabline.jobs.bom import BOM_NAME, write_bom_csv

            write_bom_csv(data["bill_of_materials"]["items"], spec.output(BOM_NAME))
        with atomic_output(result.report_path) as handle:
            handle.write(render_report(result, data))
    return result.report_path


def _timed(timings: dict[str, float], name: str, work: Callable[[], Any]) -> Any:
    """Run one stage, timed; a stage that fails removes the files it wrote (an `OutputSet` of its own)."""
    started = time.perf_counter()
    with OutputSet():
        value = work()
    timings[name] = round(time.perf_counter() - started, 3)
    return value


def _unroll(result: JobResult) -> None:
    from fabline.unroll import save_parts, unroll_network
    from fabline.unroll.preview import write_previews

    spec = result.spec
    options = unroll_options(spec.lamella, spec.unroll, spec.stock, spec.nest)
    result.partset = unroll_network(result.network, options)
    save_parts(result.partset, spec.output("parts.json"))
    if spec.unroll["previews"]:
        write_previews(result.partset, spec.output("previews"))
    result.structure = [{k: v for k, v in row.items() if k != "intervals"}
                        for row in result.partset.report.get("lamellas", [])]


def _analyse(result: JobResult) -> None:
    """The erected shell's load analysis on OpenSees (`fabline analyse`) with the job's [analysis] settings, from the
    unrolled parts; its record into the output folder's analysis.json."""
    from fabline.analysis.loads import LoadSettings
    from fabline.analysis.parts import analyse_parts

    spec = result.spec
    settings = spec.analysis
    loads = LoadSettings(**{key: settings[key] for key in ("snow", "wind", "person", "gamma_g", "gamma_q")})
    try:
        record = analyse_parts(result.network.in_mm(), result.partset, loads, supports=settings["supports"],
                               stations=settings["stations"], buckling=settings["buckling"],
                               materials_file=spec.lamella["materials_file"], where=("model", "parts.json"))
    except FablineError as exc:
        raise FablineError(f"{spec.path.name}: analyse: {exc}") from None
    result.analysis = {"schema": "fabline.analysis/1", "units": "mm, N, N/mm2 (reactions kN)",
                       "model_file": str(spec.output("network.json")), "parts_file": str(spec.output("parts.json")),
                       **record}
    write_json(spec.output(ANALYSIS_NAME), result.analysis)


def analysis_lines(record: dict | None) -> list[str]:
    """The analyse stage's lines as `fabline analyse` prints them, and the file's size line (none without it)."""
    from fabline.analysis.parts import case_lines

    if not record:
        return []
    return case_lines(record) + [f"{record['model']['nodes']} nodes, {record['model']['beams']} beams, "
                                 f"{sum(record['seconds'].values()):.1f} s"]


ASSEMBLY_FOLDER = "assembly"


def _assembly(result: JobResult) -> None:
    """The assembly plan of the unrolled parts: its pages into the output folder's assembly/, its figures kept for
    the report."""
    from fabline.assembly import plan_assembly
    from fabline.assembly.sheets import write_pages

    spec = result.spec
    try:
        plan = plan_assembly(result.network, result.partset, spec.assembly["segments"], spec.assembly["max_segment"])
    except FablineError as exc:
        raise FablineError(f"{spec.path.name}: {exc}") from None
    pages = write_pages(plan, spec.output(ASSEMBLY_FOLDER))
    result.assembly = {**plan.summary(), "pages": [str(p) for p in pages]}


def _nest(result: JobResult) -> None:
    from fabline.nest import save_nesting, write_sheet_svgs
    from fabline.nest.nester import nest
    from fabline.shop.stock import StockItem, load_stock, parse_sheet_size, save_stock, stock_after

    spec = result.spec
    if spec.stock["file"]:
        stock = load_stock(spec.stock["file"])
    else:
        width, height = parse_sheet_size(spec.stock["sheet"])
        stock = [StockItem(spec.stock["sheet"], width, height, spec.stock["count"])]
    result.nesting = nest(result.partset, stock, nest_options(spec.nest), parts_file="parts.json").nesting
    save_nesting(result.nesting, spec.output("nesting.json"))
    if result.partset.plates:  # another thickness: sheets of their own (stock.plate_sheet)
        width, height = parse_sheet_size(spec.stock["plate_sheet"])
        result.plate_nesting = nest(result.partset.plates, [StockItem(spec.stock["plate_sheet"], width, height)],
                                    nest_options(spec.nest), parts_file="parts.json").nesting
        save_nesting(result.plate_nesting, spec.output(PLATES_NESTING))
    if spec.nest["svg"]:
        write_sheet_svgs(result.nesting, result.partset, spec.output("nesting-svg"))
    if spec.nest["stock_out"]:
        save_stock(stock_after(stock, [s.stock for s in result.nesting.sheets], result.nesting.remnants, "nesting"),
                   spec.output(spec.nest["stock_out"]))


def _export(result: JobResult) -> None:
    from fabline.export import export_job
    from fabline.export.preview import PREVIEW_SUFFIX
    from fabline.jobs.pictures import sheet_svg
    from fabline.machine import load_machine

    spec = result.spec
    profile = load_machine(spec.machine["profile"])
    parts = {p.id: p for p in result.partset.parts}
    material, thickness = spec.lamella["material"], float(result.partset.profile.get("t", 0.0))
    result.export = export_job(result.nesting, parts, profile, toolpath_options(spec.export, profile),
                               dxf_dir=spec.output("dxf"), gcode_dir=spec.output("gcode"), name=spec.name,
                               source=str(spec.output("nesting.json")), cutlist=spec.output("cutlist.csv"),
                               previews=spec.export["previews"])
    if result.plate_nesting:
        _export_plates(result)
    result.sheet_files = []
    for sheet, made in zip(result.nesting.sheets, result.export.sheets):
        gcode = next(f for f in made.files if f.endswith(".gcode") or f.endswith(".nc"))
        svg_path = spec.output(Path("sheets") / f"{Path(gcode).stem}.svg")
        with atomic_output(svg_path) as handle:
            handle.write(sheet_svg(sheet, parts))
        preview = next((f for f in made.files if f.endswith(PREVIEW_SUFFIX)), None)
        result.sheet_files.append({"sheet": sheet.id, "gcode": gcode, "svg": str(svg_path), "parts": made.parts,
                                   "width_mm": sheet.width, "height_mm": sheet.height, "material": material,
                                   "thickness_mm": thickness,
                                   **({"preview": preview} if preview else {}),
                                   "cut_length_mm": made.summary.cut_length, "time_s": made.summary.time})


PLATES_NESTING = "plates-nesting.json"
PLATES_DXF = "plates.dxf"
PLATES_CUTLIST = "plates-cutlist.csv"


def _export_plates(result: JobResult) -> None:
    """The plate parts' sheets (supports) as one DXF and a cut list of their own, no G-code: the job's machine is set
    up for the strips' thickness, a plate of another thickness goes to a plate cutter with its own settings."""
    from fabline.export.cutlist import cutlist_csv
    from fabline.export.dxf import drawing_text

    spec = result.spec
    parts = {p.id: p for p in result.partset.plates.parts}
    with atomic_output(spec.output(Path("dxf") / PLATES_DXF)) as handle:
        handle.write(drawing_text(result.plate_nesting.sheets, parts))
    with atomic_output(spec.output(PLATES_CUTLIST)) as handle:
        handle.write(cutlist_csv(result.plate_nesting, parts))


def _survey(result: JobResult, say: Say) -> None:
    from fabline.jobs.survey_stage import SURVEY_FOLDER, simulate_and_measure

    spec = result.spec
    folder = spec.output(SURVEY_FOLDER)
    result.survey = simulate_and_measure(result.network, folder, spec.survey, say)
    summary, truth = result.survey["summary"], result.survey["truth"]
    say(f"survey: {summary['measured']} of {summary['nodes']} nodes measured in {result.survey['simulated']['measure_s']:.1f} s: "
        f"RMS deviation {mm(summary['rms_deviation_mm'])} mm, max {mm(summary['max_deviation_mm'])} mm; at "
        f"{result.survey['tolerance_mm']:g} mm {verdict_text(summary)}; against the injected truth RMS error "
        f"{mm(truth['rms_error_mm'])} mm "
        f"-> {folder / 'survey.json'}")


def machine_ports(spec: JobSpec) -> list[str]:
    """The job's ports; a simulator URL gets the job's time scale and is set up as the job's machine (the
    profile's controller settings: laser mode, max rates, acceleration, bed) unless it says otherwise."""
    from urllib.parse import quote

    ports = []
    for port in spec.machine["ports"]:
        if port.startswith("sim://"):
            for option, value in (("time_scale", f"{spec.machine['time_scale']:g}"),
                                  ("machine", quote(str(spec.machine["profile"]), safe=""))):
                if f"{option}=" not in port:
                    port += ("&" if "?" in port else "?") + f"{option}={value}"
        ports.append(port)
    return ports


def _unfinished(spec: JobSpec) -> list[str]:
    """The programs (file names) whose journal in the job's G-code folder says their run did not finish."""
    from fabline.link import read_journal

    unfinished = []
    for journal in sorted(spec.output("gcode").glob("*.journal")):
        try:
            if not read_journal(journal).finished:
                unfinished.append(journal.name.removesuffix(".journal"))
        except FablineError:
            unfinished.append(journal.name.removesuffix(".journal"))
    return unfinished


def _interrupted_sheet(spec: JobSpec) -> str:
    """The one program an earlier run left unfinished, which --from-line names a line of."""
    unfinished = _unfinished(spec)
    if len(unfinished) != 1:
        raise FablineError(f"{spec.path.name}: --from-line names a line of the one interrupted sheet, but "
                           + (f"{len(unfinished)} sheets were interrupted ({', '.join(unfinished[:3])}): resume "
                              "without it, each sheet from its journal" if unfinished else "no sheet was interrupted"))
    return unfinished[0]


def _refuse_over_an_interrupted_run(spec: JobSpec) -> None:
    """An earlier run of this job stopped before it finished a sheet: a new run would cut that sheet from its
    first line again, so it must be asked for (--restart) or the old run continued (--resume)."""
    unfinished = _unfinished(spec)
    if unfinished:
        raise FablineError(f"{spec.path.name}: an earlier run stopped before finishing {', '.join(unfinished[:3])}"
                           f"{' and more' if len(unfinished) > 3 else ''}; continue it with --resume, "
                           "or cut every sheet afresh with --restart")


class _JobClock:
    """The job's time while its sheets stream on several machines: planned seconds per sheet (the export's planner
    estimate on this machine, a simulator's time scale applied), what each running sheet reports, and the job's
    elapsed and remaining time by `fabline.progress.estimate` (the work left shared by the machines)."""

    def __init__(self, planned: list[float], machines: int):
        self.planned, self.machines = planned, max(machines, 1)
        self.started = time.perf_counter()
        self.finished: dict[int, float] = {}       # sheet -> wall seconds it took
        self.running: dict[int, Eta | None] = {}

    def eta(self) -> Eta:
        """The whole job: elapsed wall time, remaining by the pace of the work done so far (time a machine stood
        held for the operator is not work: the finished sheets count their wall time less it)."""
        done = sum(self.planned[k] for k in self.finished)
        worked = sum(self.finished.values())
        for k, eta in self.running.items():
            if eta is not None:
                done, worked = done + min(eta.planned_done, self.planned[k]), worked + eta.elapsed
        work = estimate(sum(self.planned), done, worked)
        return Eta(time.perf_counter() - self.started, work.remaining / self.machines, work.planned / self.machines,
                   work.pace, work.planned_done / self.machines)


RUN_RECORD = "stream-run.json"
"""In the job's G-code folder: the number of the job's current run, which every sheet's journal names (a resume
continues that run; a new run is the next number), so a sheet an earlier run finished is not taken as this run's."""


def _run_identity(spec: JobSpec, resume: bool) -> dict[str, str]:
    """The run identity the sheets' journals carry: {job, run}; a new run takes the next number and records it
    before any sheet starts, a resume reads it (none recorded: journals of a fabline before runs were numbered,
    which named the job alone)."""
    record = spec.output("gcode") / RUN_RECORD
    try:
        number = read_json(record).get("run") if record.exists() else None
    except (FablineError, AttributeError):
        number = None
    if resume:
        return {"job": spec.name, "run": number} if isinstance(number, str) else {"job": spec.name}
    number = str(int(number) + 1) if isinstance(number, str) and number.isdigit() else "1"
    write_json(record, {"format": "fabline.stream-run/1", "job": spec.name, "run": number})
    return {"job": spec.name, "run": number}


def _stream_all(result: JobResult, say: Say, confirm_sheet: Callable[[int, int, dict], None] | None,
                resume: bool, identity: dict[str, str], start: tuple[str | None, int | None] = (None, None)) -> None:
    """Cut every sheet: each machine takes the next sheet when it is free (one sheet at a time per machine);
    after a failure no new sheet starts, the ones running finish, and the first error is raised. Each sheet
    streams from a process of its own, so that machines stream on all CPU cores; Ctrl-C stops them safely.
    `identity` is the run the journals name (`_run_identity`); with `resume` a sheet this run finished is
    skipped, one it began continues, any other is cut afresh. `start` is (program file name, file line): that
    sheet continues from that line (--from-line)."""
    import multiprocessing

    from fabline.jobs.streaming import STOP_SIGNALS, journal_summary, run_progress, stream_in_process

    sheets = list(enumerate(result.sheet_files))
    count = len(sheets)
    entries: dict[int, dict] = {}
    ports = machine_ports(result.spec)
    resumed: set[int] = set()  # the sheets this run had begun: continued from their journals
    if resume:  # a sheet this run finished is not cut again: no link process, no time of this run
        for k, sheet in list(sheets):
            progress = run_progress(sheet["gcode"], identity)
            if progress is None:  # not begun in this run (an earlier run's journal, or none): cut afresh
                continue
            finished, lines = progress
            if finished:
                sheets.remove((k, sheet))
                entries[k] = {"sheet": sheet["sheet"], "program": sheet["gcode"], "outcome": "finished", "earlier": True,
                              "port": "", "lines": lines, "executed": lines, "seconds": None, "resumed_from": lines}
            else:
                resumed.add(k)
        if not sheets:
            result.stream = [entries[k] for k in sorted(entries)]
            say(f"stream: nothing left to cut: all {count} sheets finished in an earlier run")
            return
    errors: list[FablineError] = []
    running: set = set()
    lock = threading.Lock()
    context = multiprocessing.get_context("spawn")  # no fork of a process that runs threads
    clock = _JobClock([0.0 if k in entries else sheet.get("time_s", 0.0) / simulated_speedup(ports[0])
                       for k, sheet in enumerate(result.sheet_files)], len(ports))
    job_bar = StreamBar("job", position=0, unit="sheet")
    say = above_bars(say)
    bars = {port: StreamBar(port.split("?", 1)[0], position=slot + 1, leave=False) for slot, port in enumerate(ports)}

    def job_eta_text() -> str:
        return f"job: {clock.eta().describe()}"

    def machine(port: str) -> None:
        shown = port.split("?", 1)[0]  # sim:// options (time scale, controller settings) are in the report
        bar = bars[port]
        while True:
            with lock:
                if not sheets or errors:
                    return
                k, sheet = sheets.pop(0)
                try:
                    if confirm_sheet is not None:
                        confirm_sheet(k, count, sheet)
                except FablineError as exc:  # nobody confirmed the sheet: it is not cut, nor any after it
                    errors.append(exc)
                    return
            started = time.perf_counter()
            receiver, sender = context.Pipe(duplex=False)
            link = context.Process(target=stream_in_process, daemon=True,
                                   args=(port, sheet["gcode"], k in resumed, identity, sender,
                                         start[1] if Path(sheet["gcode"]).name == start[0] else None))
            with lock:
                signal.pthread_sigmask(signal.SIG_BLOCK, set(STOP_SIGNALS))  # inherited: a signal waits for the handlers
                link.start()
                signal.pthread_sigmask(signal.SIG_UNBLOCK, set(STOP_SIGNALS))
                running.add(link)
            final = None
            with lock:
                clock.running[k] = None
            while final is None and (link.is_alive() or receiver.poll()):
                if not receiver.poll(0.1):
                    continue
                try:
                    message = receiver.recv()
                except EOFError:
                    break
                if message[0] == "result":
                    final = message[1:]
                else:
                    _, done, lines, eta = message
                    with lock:
                        clock.running[k] = eta
                        job_bar.show(len(clock.finished), count, clock.eta())
                    bar.show(done, lines, eta, desc=f"{shown} {sheet['sheet']}")
            link.join()
            with lock:
                running.discard(link)
                clock.running.pop(k, None)
            if final is not None:
                outcome, summary = final
            else:
                outcome = f"stopped: the link process ended with exit code {link.exitcode}"
                summary = journal_summary(port, sheet["gcode"])
            entry = {"sheet": sheet["sheet"], "program": sheet["gcode"], "outcome": outcome,
                     "seconds": round(time.perf_counter() - started, 3), **summary}
            with lock:
                entries[k] = entry
                clock.finished[k] = max(entry["seconds"] - entry.get("held_s", 0.0), 0.0)
                if outcome != "finished":
                    errors.append(FablineError(f"stream: sheet {sheet['sheet']} on {shown}: {outcome}"))
                job_bar.show(len(clock.finished), count, clock.eta())
            say(f"stream: sheet {k + 1} of {count} ({sheet['sheet']}) on {shown}: {entry['executed']} of {entry['lines']} lines "
                f"{outcome}{_sheet_times(entry)}; {job_eta_text()}")

    threads = [threading.Thread(target=machine, args=(port,), daemon=True) for port in ports]
    for thread in threads:
        thread.start()
    try:
        for thread in threads:
            thread.join()
    except KeyboardInterrupt:  # stop every machine safely (its journal resumes the sheet), start no new sheet
        with lock:
            sheets.clear()
            for link in running:
                os.kill(link.pid, signal.SIGINT)
        for thread in threads:
            thread.join()
        result.stream = [entries[k] for k in sorted(entries)]
        raise
    finally:
        for bar in (*bars.values(), job_bar):
            bar.close()
    result.stream = [entries[k] for k in sorted(entries)]
    result.stream_wall_s = round(clock.eta().elapsed, 3)
    say(stream_summary(result.stream, len(ports), result.stream_wall_s))
    if errors:
        raise errors[0]


def _sheet_times(entry: dict) -> str:
    """` in 0:10:12 machine time (planned 0:10:00 for these lines), 1.3 s wall`: the machine's own clock against the
    planner's time for the lines this run cut; what is not known is left out."""
    taken = machine_seconds(entry)
    planned = (entry["planned_done_s"] - entry.get("planned_before_s", 0.0)) if "planned_done_s" in entry else None
    parts = [f" in {duration(taken)} machine time" if taken is not None else ""]
    parts.append(f" (planned {duration(planned)})" if planned is not None and taken is not None else "")
    parts.append(f", {entry['seconds']:.1f} s wall" if entry.get("seconds") is not None else "")
    return "".join(parts)


def stream_summary(stream: list[dict], machines: int, wall: float) -> str:
    """The stream stage in one line: sheets cut in this run on how many machines in how much wall time (the
    machines run in parallel: one wall time for all), the machine time the planner planned for the lines cut and
    the machine time taken (summed over the machines, each by its own clock), and the sheets an earlier run
    finished."""
    cut = [s for s in stream if not s.get("earlier")]
    earlier = len(stream) - len(cut)
    timed = [s for s in cut if machine_seconds(s) is not None and "planned_done_s" in s]
    text = f"stream: {len(cut)} sheet(s) on {machines} machine(s) in {wall:.1f} s"
    if timed:
        planned = sum(s["planned_done_s"] - s.get("planned_before_s", 0.0) for s in timed)
        text += (f"; machine time (summed over the machines) planned {duration(planned)}, "
                 f"taken {duration(sum(machine_seconds(s) for s in timed))}")
    if earlier:
        text += f"; {earlier} sheet(s) finished in an earlier run"
    return text
