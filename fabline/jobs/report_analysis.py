"""The report's analysis section (the job's `analyse` stage): per load case the largest deflection, support reaction
and utilisation, the buckling factor, a deflection and a utilisation picture in plan, and the support reactions."""

from __future__ import annotations

import html
from typing import Any

from fabline.analysis.parts import factor_text
from fabline.jobs.pictures import value_plan_svg

ANALYSIS_NAME = "analysis.json"
"""The analyse stage's record in the output folder."""

CASE_FIGURES = ("converged", "max_deflection_mm", "max_deflection_node", "max_reaction_kN", "max_utilisation",
                "max_utilisation_at", "reaction_sum_kN", "cable_max_kN")
"""What the report's JSON keeps of each case (analysis.json has every node's deflection and every reaction)."""


def analysis_data(record: dict[str, Any] | None, path: str) -> dict[str, Any] | None:
    """The analysis figures the report shows, per case, and where the full record is."""
    if not record:
        return None
    return {"file": path, "model": record["model"], "loads": record["loads"], "buckling": _buckling(record),
            "erection": record["erection"],
            "cases": {name: {key: case.get(key) for key in CASE_FIGURES} for name, case in record["cases"].items()},
            "residual_check": record["residual_check"], "seconds": record["seconds"]}


def _buckling(record: dict[str, Any]) -> dict[str, Any] | None:
    return {k: v for k, v in record["buckling"].items() if k != "mode"} if "buckling" in record else None


def governing(record: dict[str, Any], key: str) -> str:
    """The load case with the largest `key` (a converged one if any converged: an unconverged state is no result)."""
    cases = record["cases"]
    pool = [n for n, c in cases.items() if c["converged"]] or list(cases)
    return max(pool, key=lambda n: cases[n][key])


def analysis_section(network, record: dict[str, Any] | None, data: dict[str, Any] | None) -> str:
    """The section: the per-case table, the two pictures of the governing cases, the reactions table."""
    if not record:
        return ""
    e = html.escape
    buckling = data["buckling"]
    head = ("<tr><th>load case</th><th>max deflection mm</th><th>at</th><th>largest reaction kN</th>"
            "<th>max utilisation %</th><th>at</th><th>buckling factor</th><th>converged</th></tr>")
    rows = []
    for name, case in record["cases"].items():
        factor = buckling["factors"].get(name) if buckling else None
        factor = "" if factor is None else f"<span{' class=fail' if factor <= 1.0 else ''}>{factor:.3f}</span>"
        rows.append(f"<tr{'' if case['converged'] else ' class=fail'}><td>{e(name)}</td>"
                    f"<td>{case['max_deflection_mm']:.2f}</td><td>{e(case['max_deflection_node'])}</td>"
                    f"<td>{case['max_reaction_kN']:.3f}</td><td>{100 * case['max_utilisation']:.1f}</td>"
                    f"<td>{e(case['max_utilisation_at'])}</td><td>{factor}</td>"
                    f"<td>{'yes' if case['converged'] else 'no'}</td></tr>")
    moved, used = governing(record, "max_deflection_mm"), governing(record, "max_utilisation")
    deflection = value_plan_svg(network, record["cases"][moved]["deflections_mm"], "mm", f"deflection, {moved}")
    utilisation = value_plan_svg(network, {k: 100 * v for k, v in record["cases"][used]["utilisation_by_strip"].items()},
                                 "%", f"utilisation, {used}")
    loads = record["loads"]
    said = (f"Snow {loads['snow']:g} kN/m2 on the plan, wind {loads['wind']:g} kN/m2 normal to the shell, a person "
            f"{loads['person']:g} N at the joint the one-sided snow moved most; partial factors {loads['gamma_g']:g} "
            f"(self-weight) and {loads['gamma_q']:g} (the variable load); the erection's residual stress in every case. "
            + f"Erection: {e(factor_text(data['erection']))} on its own residual stress. "
            + (f"Buckling: lowest {e(factor_text(buckling))} on {e(buckling['case'])} (each case's in the table)."
               if buckling else "Buckling not computed (analysis.buckling = false).")
            + f" {record['model']['nodes']} frame nodes, {record['model']['beams']} beams; every node's deflection and "
            f"every reaction in {e(data['file'])}.")
    unconverged = [n for n, c in record["cases"].items() if not c["converged"]]
    warning = (f"<p class=fail>{len(unconverged)} load case(s) did not converge ({e(', '.join(unconverged))}): their "
               "figures are the last state reached, not an equilibrium.</p>" if unconverged else "")
    return (f"<h2 id=analysis>Load analysis</h2><p>{said}</p>{warning}<table id=analysis-cases>{head}{''.join(rows)}</table>"
            f"<div class=pictures><figure id=analysis-deflection>{deflection}<figcaption>Deflection of each joint under "
            f"{e(moved)} (plan view; hover a dot for its value).</figcaption></figure>"
            f"<figure id=analysis-utilisation>{utilisation}<figcaption>Largest utilisation along each lamella under "
            f"{e(used)}, residual stress included (plan view).</figcaption></figure></div>"
            + _reactions_table(record))


def _reactions_table(record: dict[str, Any]) -> str:
    """Every support's reaction resultant (kN) per load case, and each case's sum of vertical reactions."""
    cases = record["cases"]
    supports = sorted({row["node"] for case in cases.values() for row in case["reactions"]})
    head = "<tr><th>support</th>" + "".join(f"<th>{html.escape(n)}</th>" for n in cases) + "</tr>"
    resultant = {name: {row["node"]: row["resultant_kN"] for row in case["reactions"]} for name, case in cases.items()}
    body = ["<tr><td>" + html.escape(node) + "</td>" + "".join(
        f"<td>{resultant[n].get(node, 0.0):.3f}</td>" for n in cases) + "</tr>" for node in supports]
    body.append("<tr><td>sum Fz</td>" + "".join(
        f"<td>{case['reaction_sum_kN'][2]:.3f}</td>" if case["reaction_sum_kN"] else "<td></td>"
        for case in cases.values()) + "</tr>")
    return f"<p>Support reactions, kN (resultant per support):</p><table id=analysis-reactions>{head}{''.join(body)}</table>"
