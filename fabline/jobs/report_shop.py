"""The shop floor's parts of the job report: the summary at the top, the bill of materials, the cut-order
previews, sheet pictures that zoom, and the streaming table in machine time with short port names.

Kept apart from `report.py` (which lays out the page) so each section is one function of the report data.
"""

from __future__ import annotations

import base64
import html
import os
from pathlib import Path
from urllib.parse import quote
from typing import Any

from fabline.units import duration
from fabline.verdicts import verdict_text

ZOOM_STYLE = """
.zoom{overflow:auto;max-height:85vh}.zoom>label{cursor:zoom-in;display:block}.zoom input{display:none}
.zoom input:checked+label{cursor:zoom-out}.zoom input:checked+label>svg,.zoom input:checked+label>img{width:400%;max-width:none}
figure.zoom img{width:100%;height:auto}
.summary td:first-child{font-weight:600}.summary{margin:8px 0 4px;font-size:14px}.summary td{text-align:left}
"""
def zoomable(svg: str, key: str) -> str:
    """The picture inside a checkbox label (`key` unique on the page), so a click shows it at four times the width
    (scrolling) and another click back: zoom without a script (the report has none)."""
    box = html.escape(f"zoom-{key}", quote=True)
    return f'<input type=checkbox id="{box}"><label for="{box}">{svg}</label>'


def mass(kg: float) -> str:
    """A mass as the report shows it: tonnes to 0.01 from a tonne up, kilograms to 0.1 below."""
    return f"{kg / 1000:.2f} t" if kg >= 1000 else f"{kg:.1f} kg"



def bill_of_materials(result: Any) -> dict | None:
    """The job's bill of materials (`fabline.jobs.bom`), when it was unrolled and nested."""
    if not (result.nesting and result.partset):
        return None
    from fabline.jobs.bom import bill_of_materials as bom
    from fabline.mechanics.materials import get_material

    lamella = result.spec.lamella
    plates = result.partset.plates
    return bom(result.nesting, result.partset, get_material(lamella["material"], lamella.get("materials_file")),
               getattr(result, "plate_nesting", None),
               get_material(plates.material, lamella.get("materials_file")) if plates else None)


def summary_block(data: dict[str, Any]) -> str:
    """What the job is, how many parts and sheets, machine time, mass, and the structural and survey verdicts."""
    e = html.escape
    model, nesting, bom = data["model"], data["nesting"], data.get("bill_of_materials")
    rows = [("what", f"{model['name']}: {model['lamellas']} lamellas, {model['nodes']} nodes")]
    if model.get("extent"):
        rows.append(("size in plan", model["extent"]["text"]))
    if data["parts"]:
        kinds = ", ".join(f"{n} {k}" for k, n in data["parts"]["by_kind"].items())
        rows.append(("parts", f"{data['parts']['count']} ({kinds})"))
    if nesting:
        sizes = sorted({f"{s['width_mm']:g} x {s['height_mm']:g} mm" for s in nesting["sheets"]})
        material = f", {bom['thickness_mm']:g} mm {bom['material']}" if bom else ""
        rows.append(("sheets", f"{len(nesting['sheets'])} of {' / '.join(sizes)}{material}"))
    if data.get("machine_time_s") is not None:
        rows.append(("machine time", f"{duration(data['machine_time_s'])} (export's estimate, all sheets on one machine)"))
    if bom:
        totals = bom["totals"]
        cost = f", cost {totals['cost']:,.2f} {totals['currency']}" if totals["cost"] is not None else ""
        rows.append(("mass", f"{mass(totals['mass_kg'])} of sheet, {mass(totals['parts_mass_kg'])} in parts "
                             f"({100 * totals['scrap_share']:.1f} % scrap){cost}"))
    structure = data["structure"]
    if structure["lamellas"]:
        from fabline.mechanics.structure import verdict_lines  # numpy: the runner imports this module and starts fast

        rows.append(("structure", verdict_lines(structure["verdict"])[0].removeprefix("structure: ")))
    else:
        rows.append(("structure", "not checked (no unroll stage)"))
    survey = data["survey"]
    if survey:
        s = survey["summary"]
        rows.append(("survey", f"{verdict_text(s)} (at {survey['tolerance_mm']:g} mm)"
                     + (": out of tolerance" if s["failed"] else "")))
    else:
        rows.append(("survey", "no survey yet"))
    stream = data["stream"]
    if stream["sheets"]:
        done = sum(s["outcome"] == "finished" for s in stream["sheets"])
        earlier = sum(bool(s.get("earlier")) for s in stream["sheets"])
        rows.append(("cut", f"{done} of {len(nesting['sheets']) if nesting else len(stream['sheets'])} sheets finished"
                     + (f" ({earlier} in an earlier run)" if earlier else "")))
    verdict = [r for r in rows if r[0] in ("structure", "survey")]
    css = {k: "fail" if ("exceed" in v or "out of tolerance" in v) else "ok" for k, v in verdict}
    body = "".join(f"<tr class={css.get(k, '')}><td>{e(k)}</td><td>{e(v)}</td></tr>" for k, v in rows)
    return f"<table id=summary class=summary>{body}</table>"


def bom_section(bom: dict | None) -> str:
    """The sheets with size, thickness, material, mass and scrap share, their totals and cost, and the hardware."""
    if not bom:
        return ""
    e = html.escape
    head = ("<tr><th>sheet</th><th>size mm</th><th>thickness mm</th><th>material</th><th>mass kg</th>"
            "<th>in parts kg</th><th>scrap %</th></tr>")
    rows = "".join(f"<tr><td>{e(s['id'])}</td><td>{s['width_mm']:g} x {s['height_mm']:g}</td><td>{s['thickness_mm']:g}</td>"
                   f"<td>{e(s['material'])}</td><td>{s['mass_kg']:.1f}</td><td>{s['parts_mass_kg']:.1f}</td>"
                   f"<td>{100 * s['scrap_share']:.1f}</td></tr>" for s in bom["sheets"])
    totals = bom["totals"]
    rows += (f"<tr><th>{totals['sheets']} sheets</th><th></th><th></th><th></th><th>{totals['mass_kg']:.1f}</th>"
             f"<th>{totals['parts_mass_kg']:.1f}</th><th>{100 * totals['scrap_share']:.1f}</th></tr>")
    cost = (f" At {bom['price_per_kg']:g} {e(totals['currency'])}/kg the sheets cost {totals['cost']:,.2f} "
            f"{e(totals['currency'])}." if totals["cost"] is not None else
            " No price: add price_per_kg to the material (docs/unrolling.md, Structural check: materials) for the cost.")
    def cell(value: Any, form: str = "{:g}") -> str:
        return "" if value is None else form.format(value)

    items = "".join(f"<tr><td>{e(i['kind'])}</td><td>{e(i['item'])}</td><td>{e(i['size'])}</td>"
                    f"<td>{cell(i['length_mm'], '{:.1f}')}</td><td>{i['count']}</td>"
                    f"<td>{cell(i['total_mass_kg'], '{:.2f}')}</td><td>{e(i['per'])}</td></tr>"
                    for i in bom.get("items", []) if i["kind"] != "sheet")
    cables = bom.get("cables")
    cable_text = (f" {cables['runs']} bracing cables ({e(cables['cable'])}): {cables['geometric_length_m']:.1f} m "
                  f"geometric, {cables['cut_length_m']:.1f} m cut, {mass(cables['mass_kg'])}." if cables else "")
    plates = bom.get("plates")
    plate_text = (f" {plates['supports']} supports: {plates['parts']} plates on {len(plates['sheets'])} sheet(s) of "
                  f"{plates['thickness_mm']:g} mm {e(plates['material'])} ({mass(plates['mass_kg'])}), drawn in "
                  "dxf/plates.dxf with their cut list plates-cutlist.csv, no G-code: the job's machine is set up for "
                  "the strips." if plates else "")
    return (f"<h2>Bill of materials</h2><p>{bom['thickness_mm']:g} mm {e(bom['material'])} at "
            f"{bom['density_kg_m3']:g} kg/m3: {mass(totals['mass_kg'])} of sheet.{cost}{cable_text}{plate_text} The cut list with "
            f"every part's sheet and position is cutlist.csv, the whole bill bom.csv, beside this report.</p>"
            f"<table id=bom>{head}{rows}</table><p></p><table id=hardware><tr><th>kind</th><th>item</th><th>size</th>"
            f"<th>length mm</th><th>count</th><th>mass kg</th><th>per</th></tr>{items}</table>")


def picture_source(path: Path, folder: Path, media_type: str) -> str:
    """An image's address from a page in `folder`: relative (URL-quoted) when the file lies inside the folder, so the
    page loads it only when shown and still finds it when the folder is moved; otherwise inlined as a data URL."""
    relative = os.path.relpath(os.path.abspath(path), os.path.abspath(folder))
    if not relative.startswith(os.pardir):
        return html.escape(quote(Path(relative).as_posix()), quote=True)
    return f"data:{media_type};base64,{base64.b64encode(path.read_bytes()).decode('ascii')}"


def preview_figure(entry: dict[str, Any], folder: Path) -> str:
    """A sheet's cut-order preview (the SVG export drew from its G-code), an image beside the report (`folder`) that
    loads when its fold is opened, zoomable."""
    path = entry.get("preview")
    if not path or not Path(path).is_file():
        return ""
    source = picture_source(Path(path), folder, "image/svg+xml")
    image = f'<img src="{source}" loading=lazy alt="cut order of sheet {html.escape(entry["id"], quote=True)}">'
    return (f"<details class=preview data-sheet=\"{html.escape(entry['id'])}\"><summary>Sheet {html.escape(entry['id'])}: "
            "cut order (from the G-code: engraving green, then cuts from blue to red, numbered; dashed grey travel; "
            "click to zoom)"
            f"</summary><figure class=zoom>{zoomable(image, 'order-' + entry['id'])}</figure></details>")


def short_port(port: str) -> str:
    """A port without its options (`sim://grbl-1?time_scale=...` -> `sim://grbl-1`)."""
    return port.split("?", 1)[0]


def machine_seconds(entry: dict[str, Any]) -> float | None:
    """The machine time a sheet took in this run by the controller's own clock (`machine_s`: a simulator's machine
    clock, a real machine's wall time less the time held); None when it is not known (cut in an earlier run, a
    link process that died before reporting)."""
    return None if entry.get("earlier") else entry.get("machine_s")


def _left(entry: dict[str, Any], planned: float | None) -> float | None:
    """The planner's machine time for the lines of a sheet not yet cut; None for a finished sheet or an unknown plan."""
    if entry["outcome"] == "finished" or planned is None:
        return None
    return max(planned - entry.get("planned_done_s", 0.0), 0.0)


def _wall(seconds: float | None) -> str:
    return f"{seconds:.1f}" if seconds is not None else ""


def stream_table(stream: dict[str, Any], estimates: dict[str, float]) -> str:
    """Per streamed sheet: its machine, lines, outcome, the machine time this run took by the controller's clock,
    the planner's time for the program (the streamer's, else the export's estimate), the planned time of what is
    left of an unfinished sheet, and the wall seconds. Then a row per machine, and the job: machine time summed over
    the machines (machine-hours), but one wall time, the stream stage's, as the machines cut in parallel."""
    e = html.escape
    if not stream["sheets"]:
        return "<h2>Streaming</h2><p>Not streamed in this run.</p>"

    def cell(seconds: float | None) -> str:
        return f"<td>{duration(seconds)}</td>" if seconds is not None else "<td></td>"

    head = ("<tr><th>sheet</th><th>machine</th><th>lines</th><th>executed</th><th>outcome</th><th>machine time</th>"
            "<th>planned</th><th>left (planned)</th><th>wall s</th></tr>")
    rows, machines, lefts = [], {}, []
    for s in stream["sheets"]:
        planned = s.get("planned_s", estimates.get(s["sheet"]))
        left, taken = _left(s, planned), machine_seconds(s)
        lefts.append(left or 0.0)
        outcome = "finished in an earlier run" if s.get("earlier") else s["outcome"]
        if not s.get("earlier"):
            machine = machines.setdefault(short_port(s["port"]), [0, 0.0, 0.0, True])
            machine[0] += 1
            machine[1] += taken or 0.0
            machine[2] += s["seconds"] or 0.0
            machine[3] = machine[3] and taken is not None
        rows.append(f"<tr class={'ok' if s['outcome'] == 'finished' else 'fail'}><td>{e(s['sheet'])}</td>"
                    f"<td>{e(short_port(s['port']))}</td><td>{s['lines']}</td><td>{s['executed']}</td><td>{e(outcome)}</td>"
                    f"{cell(taken)}{cell(planned)}{cell(left)}"
                    f"<td>{_wall(s.get('seconds'))}</td></tr>")
    for port, (count, taken, wall, known) in machines.items():
        rows.append(f"<tr class=machine><th>{e(port)}</th><td></td><td></td><td></td><td>{count} sheet(s)</td>"
                    f"{cell(taken if known else None)}<td></td><td></td><td>{wall:.1f}</td></tr>")
    listed = {s["sheet"] for s in stream["sheets"]}
    left_total = sum(lefts) + sum(t for sheet, t in estimates.items() if sheet not in listed)
    known = all(known for *_, known in machines.values())
    taken_total = sum(taken for _, taken, _, _ in machines.values()) if machines and known else None
    planned_total = sum(s.get("planned_s", estimates.get(s["sheet"])) or 0.0 for s in stream["sheets"])
    wall = stream.get("wall_s")
    counted = f"{len(machines)} machine(s)" if machines else ""
    rows.append(f"<tr class=total><th>job</th><td>{counted}</td><td>{stream['lines']}</td>"
                f"<td>{stream['executed']}</td><td></td>{cell(taken_total)}{cell(planned_total)}"
                f"{cell(left_total if left_total else None)}<td>{_wall(wall)}</td></tr>")
    earlier = sum(bool(s.get("earlier")) for s in stream["sheets"])
    note = (f" {earlier} sheet(s) were finished in an earlier run: no machine time of this run." if earlier else "")
    return (f"<h2>Streaming</h2><p>{stream['executed']} of {stream['lines']} lines executed"
            f"{' - every sheet finished' if stream['finished'] else ''}.{note} Machine time: the controller's own "
            f"clock (a simulator's machine clock, whatever wall time its process took; a real machine's wall time "
            f"less the time it stood held), summed over the machines in the job row. Planned: the planner's machine "
            f"time for the program; left: the planned time of what is not cut yet. Wall s: per sheet and machine; the "
            f"job row gives the stream stage's wall time, as the machines cut in parallel.</p>"
            f"<table id=stream>{head}{''.join(rows)}</table>")
