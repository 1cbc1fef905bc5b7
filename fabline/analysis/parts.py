"""The analysis from what the unroll stage left: the network and its parts' profile, material, pair spacing, cables and
couplers,
checked, built into the frame's options and solved; shared by `fabline analyse` and the job's `analyse` stage."""

from __future__ import annotations

from fabline.analysis.loads import LoadSettings
from fabline.errors import FablineError


def analyse_parts(network, partset, settings: LoadSettings, supports: str = "pinned", stations: int = 2,
                  buckling: bool = True, materials_file: str | None = None, where: tuple[str, str] = ("model", "parts")) -> dict:
    """The analysis record (fabline.analysis/1 without its file names) of `network` (mm) with `partset`'s settings;
    a mismatch is a FablineError naming `where` (the model's and the parts' names)."""
    from fabline.analysis.model import ModelOptions
    from fabline.analysis.run import analyse
    from fabline.geometry.darboux import analyse as geometry_of
    from fabline.mechanics.hardware import load_catalogue
    from fabline.mechanics.materials import Profile, get_material

    model_name, parts_name = where
    try:
        profile = Profile(float(partset.profile["h"]), float(partset.profile["t"]))
    except (KeyError, TypeError, ValueError):
        raise FablineError(f"{parts_name}: profile: expected h and t in mm") from None
    material = get_material(partset.material, materials_file)
    unrolled = partset.report.get("options", {})
    runs = tuple(tuple(run["nodes"]) for run in partset.cables)
    unknown = sorted({n for run in runs for n in run} - set(network.nodes))
    if unknown:
        raise FablineError(f"{parts_name}: cables: node {unknown[0]} is not in {model_name} (unrolled from another model?)")
    if not any(node.kind == "support" for node in network.nodes.values()):
        raise FablineError(f"{model_name}: no node is a support (node kind 'support'): the frame would float")
    options = ModelOptions(stations=stations, pair_spacing=float(unrolled.get("pair_spacing_mm", 25.0)),
                           supports=supports, cables=runs, cable=load_catalogue().cable,
                           cable_prestrain=float(unrolled.get("cable_pretension_mm_per_m", 0.0)) / 1000.0,
                           couplers=tuple((c["lamella"], *c["nodes"]) for c in partset.couplers))
    return analyse(geometry_of(network), material, profile, options, settings, buckling=buckling)


def case_lines(record: dict) -> list[str]:
    """One line per load case (max deflection, largest reaction, utilisation, buckling factor), the erection's and the
    lowest buckling factor's lines."""
    factors = record.get("buckling", {}).get("factors", {})
    lines = [f"{name:<32} max deflection {case['max_deflection_mm']:8.2f} mm at {case['max_deflection_node']:<10} "
             f"largest reaction {case['max_reaction_kN']:7.3f} kN  utilisation {100 * case['max_utilisation']:6.1f} %"
             + (f"  buckling {_factor(factors[name])}" if name in factors else "")
             + ("" if case["converged"] else "  (NOT CONVERGED)") for name, case in record["cases"].items()]
    lines.append(f"erection: {factor_text(record['erection'])} on its own residual stress")
    if "buckling" in record:
        lines.append(f"buckling: lowest {factor_text(record['buckling'])} on {record['buckling']['case']}")
    return lines


def _factor(value: float | None) -> str:
    return "none" if value is None else f"{value:.3f}"


def factor_text(entry: dict) -> str:
    """A buckling record entry in words: the factor and where its mode is largest, or that there is none."""
    if entry["factor"] is None:
        return "no buckling factor (the load only stiffens the frame)"
    return f"factor {entry['factor']:.3f} (mode largest at {entry['mode_peak_node']})"
