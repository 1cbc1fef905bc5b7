"""The report's design stage, for a job that starts from a mesh: what the tracer covered, what it left out and why
its curves stopped, from the network's meta (`fabline design asymptotic` writes the same figures)."""

from __future__ import annotations

import html
from collections import Counter
from typing import Any


def design_data(meta: dict[str, Any], units: str) -> dict[str, Any] | None:
    """The design stage's figures (None for a network not traced on a surface): coverage, the regions left out,
    the curve ends by stop reason with one place each, the curves dropped."""
    if meta.get("design") != "asymptotic":
        return None
    from fabline.design.trace import STOP_REASONS

    counts = Counter(stop["reason"] for stop in meta["stops"])
    stops = [{"reason": reason, "ends": count, "meaning": STOP_REASONS.get(reason, reason),
              "example": next(s for s in meta["stops"] if s["reason"] == reason)} for reason, count in counts.items()]
    return {"surface": meta["surface"], "units": units, "spacing": meta["spacing"], "seed": meta["seed"],
            "coverage": meta["quality"]["coverage"], "left_out": meta["regions"], "stops": stops,
            "dropped": meta["dropped"]}


def design_section(design: dict[str, Any] | None) -> str:
    """The design stage as HTML: a line of coverage, then the regions left out and the stops by reason as tables."""
    if not design:
        return ""
    from fabline.design.quality import percent_area

    e, u, c = html.escape, design["units"], design["coverage"]
    xyz = lambda point: ", ".join(f"{v:.3f}" for v in point)  # noqa: E731
    regions = "".join(f"<tr><td>{e(r['kind'])}</td><td>{xyz(r['centre'])}</td><td>{r['vertices']}</td>"
                      f"<td>{r['extent']:.3g}</td><td>{r['area']:.3g}</td></tr>" for r in design["left_out"])
    stops = "".join(f"<tr><td>{e(s['reason'])}</td><td>{s['ends']}</td><td style=\"text-align:left\">the curve "
                    f"{e(s['meaning'])}</td><td>{e(s['example']['curve'])} near ({xyz(s['example']['xyz'])})</td></tr>"
                    for s in design["stops"])
    dropped = design["dropped"]
    return (f"<h2 id=design>Design</h2><p>Asymptotic network traced on {e(design['surface'])} at a spacing of "
            f"{design['spacing']:.4g} {e(u)} from the seed ({xyz(design['seed'])}) {e(u)}: it covers "
            f"{percent_area(c['fraction'])} of the surface's area ({c['area']:.4g} of {c['surface_area']:.4g} {e(u)}2 in "
            f"{c['cells']} cells); {c.get('left_out', 0.0):.4g} {e(u)}2 has no asymptotic lines and is left out. "
            f"{dropped['curves']} traced curve(s) dropped (too short to carry two crossings"
            + (f"; {len(dropped['refused'])} refused by the network check" if dropped["refused"] else "") + ").</p>"
            + (f"<table id=design-left-out><tr><th>left out</th><th>centre {e(u)}</th><th>vertices</th>"
               f"<th>across {e(u)}</th><th>area {e(u)}2</th></tr>{regions}</table>" if regions else "")
            + (f"<table id=design-stops><tr><th>stop</th><th>curve ends</th><th>why</th><th>e.g. ({e(u)})</th></tr>"
               f"{stops}</table>" if stops else ""))


def design_lines(network: Any) -> list[str]:
    """The design stage in a line for the console (none for a network not traced on a surface)."""
    from fabline.design.quality import percent_area

    design = design_data(network.meta, network.units)
    if design is None:
        return []
    c, units = design["coverage"], network.units
    return [f"design: traced on {design['surface']}, covers {percent_area(c['fraction'])} of its area; "
            f"{len(design['left_out'])} region(s) without asymptotic lines left out ({c.get('left_out', 0.0):.4g} {units}2); "
            + ", ".join(f"{s['ends']} curve end(s) stop at {s['reason']}" for s in design["stops"])
            + f"; {design['dropped']['curves']} curve(s) dropped"]
