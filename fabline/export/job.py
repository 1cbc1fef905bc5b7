"""Export a whole nesting: per sheet a DXF and a G-code program, an all-sheets DXF, and a summary.

Everything is computed and checked first and written only at the end, each file atomically, so a bad
input leaves nothing behind. Sheets are independent: each one's toolpaths, G-code and DXF drawing are made
in a worker process, the all-sheets drawing in another, so a many-sheet job uses every core. The parts
go to each worker once, when it starts (where processes fork, without pickling), not with every task.
"""

from __future__ import annotations

import gc
import os
import signal
import textwrap
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from fabline.errors import FablineError
from fabline.export import dxf
from fabline.export.contours import arc_centres
from fabline.export.cutlist import CUTLIST_NAME, cutlist_csv
from fabline.export.gcode import header_block, sheet_program
from fabline.export.preview import PREVIEW_SUFFIX, cut_order_svg
from fabline.export.toolpath import MIN_TABS, Toolpath, ToolpathOptions, check_placements, sheet_toolpaths
from fabline.fileio import atomic_output
from fabline.machine.motion import IDLE_LOCK, MotionSummary, summarise
from fabline.machine.profile import MachineProfile
from fabline.naming import file_stem
from fabline.nest.layout import Nesting, Sheet, load_nesting, parts_path
from fabline.nest.validate import check_fit, validate_nesting
from fabline.progress import progress
from fabline.unroll.parts import Part, load_parts

WORKERS = len(os.sched_getaffinity(0))   # processes making sheets and drawings at once
_WORKER_PARTS: dict[str, Part] = {}       # in a worker process: the parts of the job it works for


@dataclass
class SheetExport:
    """What was made for one sheet."""

    sheet: str
    parts: int
    summary: MotionSummary
    gcode: str = ""
    files: list[str] = field(default_factory=list)
    no_lead_in: list[str] = field(default_factory=list)   # the part of every closed cut with no room for a lead-in


@dataclass
class ExportResult:
    """The per-sheet results and the files written."""

    sheets: list[SheetExport]
    files: list[str]
    machine: str
    kerf: float

    def totals(self) -> MotionSummary:
        """All sheets together."""
        return MotionSummary(*(sum(getattr(s.summary, f) for s in self.sheets)
                               for f in ("cut_length", "mark_length", "travel", "time", "moves")))


def load_job(nesting_path: str | os.PathLike) -> tuple[Nesting, dict[str, Part]]:
    """A nesting and the parts it refers to, by id, checked by the nesting validator (`nest --check`): overlaps,
    a part placed twice or off its sheet, an outline that crosses itself become one error, before anything is made."""
    nesting = load_nesting(nesting_path)
    partset = load_parts(parts_path(nesting_path, nesting))
    parts = {p.id: p for p in partset.parts}
    for sheet in nesting.sheets:
        check_placements(sheet, parts, str(nesting_path))
    check_fit(nesting, partset, str(nesting_path))
    problems = validate_nesting(nesting, partset)
    if problems:
        more = f" (and {len(problems) - 1} more problems)" if len(problems) > 1 else ""
        raise FablineError(f"{nesting_path}: {problems[0]}{more}; see fabline nest --check {nesting_path}")
    return nesting, parts


def export_outputs(nesting: Nesting, profile: MachineProfile, dxf_dir: str | os.PathLike | None,
                   gcode_dir: str | os.PathLike | None, name: str, previews: bool = False,
                   cutlist: str | os.PathLike | None = None) -> list[Path]:
    """The files `export_job` writes for these arguments, known before anything is made (so that a command can
    check them against its inputs, e.g. the parts file its nesting names, up front)."""
    files: list[Path] = []
    for sheet in nesting.sheets:
        stem = f"{name}_{file_stem(sheet.id)}"
        if gcode_dir is not None:
            files.append(Path(gcode_dir) / f"{stem}.gcode")
            if previews and profile.grbl:
                files.append(Path(gcode_dir) / f"{stem}{PREVIEW_SUFFIX}")
        if dxf_dir is not None:
            files.append(Path(dxf_dir) / f"{stem}.dxf")
    if dxf_dir is not None:
        files.append(Path(dxf_dir) / f"{name}_all-sheets.dxf")
    folder = gcode_dir if gcode_dir is not None else dxf_dir
    if cutlist is not None or folder is not None:
        files.append(Path(cutlist if cutlist is not None else Path(folder) / CUTLIST_NAME))
    return files


def export_job(nesting: Nesting, parts: dict[str, Part], profile: MachineProfile, options: ToolpathOptions,
               dxf_dir: str | os.PathLike | None = None, gcode_dir: str | os.PathLike | None = None,
               name: str = "job", source: str = "nesting", cutlist: str | os.PathLike | None = None,
               previews: bool = False) -> ExportResult:
    """Make (and, given folders, write) the DXF and G-code of every sheet, and the cut list (`cutlist`, by default
    cutlist.csv in the G-code folder, else the DXF folder); `source` names the nesting in errors. `previews`
    also writes each sheet's cut-order preview `<program>.order.svg` beside its G-code (Grbl profiles: it is
    read back with Grbl's parser; about a second of CPU per 20 000-line sheet).

    Sheets are independent, so each is made in a worker process (toolpaths, G-code and its drawing), and the
    all-sheets drawing in another; the first sheet (in nesting order) that fails raises its error.
    """
    for sheet in nesting.sheets:
        if sheet.width > profile.bed_width or sheet.height > profile.bed_height:
            raise FablineError(f"{source}: sheet {sheet.id}: {sheet.width:g} x {sheet.height:g} mm is larger than the "
                               f"bed of machine {profile.name} ({profile.bed_width:g} x {profile.bed_height:g} mm, "
                               f"{profile.source}: bed)")
        check_placements(sheet, parts, source)
    count = len(nesting.sheets)
    pool = ProcessPoolExecutor(max_workers=max(1, min(WORKERS, count + (dxf_dir is not None))),
                               initializer=_start_worker, initargs=(parts,))
    try:
        overview = (pool.submit(_drawing_text, nesting.sheets) if dxf_dir is not None else None)
        preview = previews and gcode_dir is not None and profile.grbl
        futures = [pool.submit(_export_sheet, sheet, number, count, profile, options, name, source, dxf_dir is not None,
                               preview) for number, sheet in enumerate(nesting.sheets, start=1)]
        results, outputs = [], {}
        for future in progress(futures, "export", count):
            done, drawing, order = future.result()
            stem = f"{name}_{file_stem(done.sheet)}"
            if gcode_dir is not None:
                outputs[Path(gcode_dir) / f"{stem}.gcode"] = done.gcode
            if order is not None:
                outputs[Path(gcode_dir) / f"{stem}{PREVIEW_SUFFIX}"] = order
            if drawing is not None:
                outputs[Path(dxf_dir) / f"{stem}.dxf"] = drawing
            done.files = [str(p) for p in outputs if p.name in (f"{stem}.gcode", f"{stem}{PREVIEW_SUFFIX}", f"{stem}.dxf")]
            results.append(done)
        if overview is not None:
            outputs[Path(dxf_dir) / f"{name}_all-sheets.dxf"] = overview.result()
        folder = gcode_dir if gcode_dir is not None else dxf_dir
        if cutlist is not None or folder is not None:
            outputs[Path(cutlist if cutlist is not None else Path(folder) / CUTLIST_NAME)] = cutlist_csv(nesting, parts)
        # every sheet is in: wait for the idle workers to exit, so that no pool thread is still tearing down (and
        # printing a feeder thread's EBADF traceback) when a signal ends the process while the outputs are renamed
        pool.shutdown(wait=True)
    finally:
        pool.shutdown(wait=False, cancel_futures=True)  # a failure or an interrupt: do not wait for running sheets
    for path, text in outputs.items():
        with atomic_output(path) as handle:
            handle.write(text)
    return ExportResult(results, [str(p) for p in outputs], profile.name, options.kerf)


def _start_worker(parts: dict[str, Part]) -> None:
    """Set up a worker process with the job's parts, and move everything it inherited out of the garbage
    collector's sight (gc.freeze): the G-code writer allocates hundreds of thousands of small objects, and every
    full collection would otherwise walk the whole inherited job again (a sixth of the export's CPU time).
    A Ctrl-C (sent to the whole process group) is the parent's to handle: a worker ignores it, and writes nothing."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _WORKER_PARTS.clear()
    _WORKER_PARTS.update(parts)
    gc.freeze()


def _drawing_text(sheets: list[Sheet]) -> str:
    """In a worker: the DXF text of `sheets`."""
    return dxf.drawing_text(sheets, _WORKER_PARTS)


def _export_sheet(sheet: Sheet, number: int, count: int, profile: MachineProfile, options: ToolpathOptions,
                  name: str, source: str, drawing: bool, preview: bool) -> tuple[SheetExport, str | None, str | None]:
    """In a worker: one sheet's toolpaths (checked against the bed), G-code with its header and summary, and DXF
    text and the cut-order preview read back from the G-code if asked."""
    parts = _WORKER_PARTS
    paths = sheet_toolpaths(sheet, parts, options, source)
    _check_bed(paths, profile, f"{source}: sheet {sheet.id}")
    body, moves = sheet_program(paths, profile)
    summary = summarise(moves, profile.acceleration, profile.junction_deviation, profile.rapid_rate,
                        idle_lock=IDLE_LOCK if profile.grbl else 0.0)
    no_lead_in = [path.part for path in paths if path.no_room]
    header = _header(name, sheet, number, count, profile, options, summary, len(no_lead_in))
    program = header_block(header, profile) + body
    order = (cut_order_svg(program.encode("ascii"), f"{name}_{file_stem(sheet.id)}.gcode", sheet.width, sheet.height,
                           f"{name} sheet {sheet.id}") if preview else None)
    return (SheetExport(sheet.id, len(sheet.placements), summary, program, no_lead_in=no_lead_in),
            dxf.drawing_text([sheet], parts) if drawing else None, order)


def export_nesting(nesting_path: str | os.PathLike, profile: MachineProfile, options: ToolpathOptions,
                   dxf_dir: str | os.PathLike | None = None, gcode_dir: str | os.PathLike | None = None,
                   previews: bool = False) -> ExportResult:
    """Export a nesting file (and the parts file it names), files named after the nesting."""
    nesting, parts = load_job(nesting_path)
    return export_job(nesting, parts, profile, options, dxf_dir, gcode_dir, Path(nesting_path).stem, str(nesting_path),
                      previews=previews)


def _check_bed(paths: list[Toolpath], profile: MachineProfile, where: str) -> None:
    """Every toolpath (arcs through their extreme points, lead-ins too) must stay on the machine's bed."""
    if not paths:
        return
    rows = np.vstack([p.contour for p in paths])
    sizes = [len(p.contour) for p in paths]
    rows[np.cumsum(sizes) - 1, 2] = 0.0               # no arc joins one path to the next
    centre, radius, sweep = arc_centres(rows)
    low, high = rows[:, :2].copy(), rows[:, :2].copy()
    arcs = np.flatnonzero(sweep != 0)
    if len(arcs):
        start = np.arctan2(rows[arcs, 1] - centre[arcs, 1], rows[arcs, 0] - centre[arcs, 0])
        for axis, angle, sign in ((0, 0.0, 1), (1, np.pi / 2, 1), (0, np.pi, -1), (1, -np.pi / 2, -1)):
            passed = np.where(sweep[arcs] > 0, (angle - start) % (2 * np.pi), (start - angle) % (2 * np.pi)) <= np.abs(sweep[arcs])
            extreme = centre[arcs, axis] + sign * radius[arcs]
            hit = arcs[passed]
            if sign > 0:
                high[hit, axis] = np.maximum(high[hit, axis], extreme[passed])
            else:
                low[hit, axis] = np.minimum(low[hit, axis], extreme[passed])
    outside = ((low < 0) | (high > [profile.bed_width, profile.bed_height])).any(axis=1)
    lead_ins = [k for k, p in enumerate(paths) if p.lead_in is not None
                and not (0 <= p.lead_in[0] <= profile.bed_width and 0 <= p.lead_in[1] <= profile.bed_height)]
    if not outside.any() and not lead_ins:
        return
    first = int(np.searchsorted(np.cumsum(sizes), np.argmax(outside), side="right")) if outside.any() else lead_ins[0]
    path = paths[first]
    span = slice(sum(sizes[:first]), sum(sizes[:first + 1]))
    lo, hi = low[span].min(axis=0), high[span].max(axis=0)
    raise FablineError(f"{where}: part {path.part}: {path.operation} toolpath spans x {lo[0]:.3f}..{hi[0]:.3f}, "
                       f"y {lo[1]:.3f}..{hi[1]:.3f} mm, outside the bed of machine {profile.name} "
                       f"(0..{profile.bed_width:g} x 0..{profile.bed_height:g} mm)")


def cutting_summary(options: ToolpathOptions) -> list[str]:
    """Lead-ins, then tabs, a line each, as the program header and the command's summary say them."""
    lead = (f"lead-in {options.lead_in:g} mm, pierce clearance {options.pierce_clearance:g} mm" if options.lead_in > 0
            else "no lead-ins")
    if options.tabs is None:
        tabs = (f"tabs {options.tab_width:g} mm on parts under {options.tabs_below:g} mm, one per "
                f"{options.tab_every:g} mm of perimeter, at least {MIN_TABS}" if options.tabs_below > 0 else "no tabs")
    else:
        tabs = f"{options.tabs} tabs of {options.tab_width:g} mm per outer contour" if options.tabs else "no tabs"
    return [lead, tabs]


def _header(name, sheet, number, count, profile, options, summary, no_lead_in) -> list[str]:
    minutes, seconds = divmod(round(summary.time), 60)
    lines = [
        f"fabline export: job {name}, sheet {sheet.id} ({number} of {count}), {sheet.width:g} x {sheet.height:g} mm"
        + (f", stock {sheet.stock}" if sheet.stock else ""),
        f"machine {profile.name} ({profile.controller}), mode {profile.mode}, kerf {options.kerf:.3f} mm",
    ]
    if profile.main_output == "dxf":
        lines.append(f"for reference: machine {profile.name} cuts from the DXF, in its own CAM")
    lead, tabs = cutting_summary(options)
    lines += [lead + (f"; {no_lead_in} cut{'s' * (no_lead_in != 1)} without (no room)" if no_lead_in else ""), tabs]
    if profile.requires:
        lines.append(f"requires {profile.requires}")
    lines.append(f"cut {summary.cut_length:.1f} mm, mark {summary.mark_length:.1f} mm, "
                 f"travel {summary.travel:.1f} mm, estimated {minutes // 60}:{minutes % 60:02d}:{seconds:02d}")
    ids = " ".join(p.part for p in sheet.placements)
    lines.extend(textwrap.wrap(f"parts ({len(sheet.placements)}): {ids}", profile.max_line_length - 2,
                               subsequent_indent="  ", break_long_words=True))
    return lines

