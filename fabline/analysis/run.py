"""The analysis of one gridshell: its frame, whether it stands under the erection's residual stress alone (refused
below a buckling factor of 1, with what to change), every default combination on top, and each one's buckling factor;
the figures per case as the JSON record (analysis.json) holds them."""

from __future__ import annotations

import time

import numpy as np

from fabline.analysis.frame import Section
from fabline.analysis.loads import LoadSettings, basic_cases, combinations, person
from fabline.analysis.model import GridshellFrame, ModelOptions, build
from fabline.analysis.results import summary, utilisation
from fabline.analysis.solve import Model
from fabline.analysis.stability import case_buckling, erection_stability, rounded
from fabline.geometry.darboux import NetworkGeometry
from fabline.mechanics.materials import Material, Profile


def analyse(geometry: NetworkGeometry, material: Material, profile: Profile, options: ModelOptions,
            settings: LoadSettings = LoadSettings(), buckling: bool = True) -> dict:
    """Build, check and solve: the erection's stability (refused below 1), the residual case (no load), each
    combination, the person at the joint that moved most under the one-sided snow (the search's candidate), and each
    combination's linear buckling factor about the residual state, with seconds per step."""
    timings = {}
    start = time.perf_counter()
    section = Section.of(material, profile)
    grid = build(geometry, section, options)
    frame = grid.frame
    timings["build"] = time.perf_counter() - start
    t0 = time.perf_counter()
    erection = erection_stability(frame)
    timings["erection stability"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    model = Model(frame)
    timings["build"] += time.perf_counter() - t0
    beam_names = [f"{strip} beam {k}" for strip, k in frame.beam_tags]
    joints = np.array(list(grid.joints.values()))
    base = basic_cases(frame, joints, settings)
    cases = {"residual": np.zeros((len(frame.xyz), 6)), **combinations(base, settings)}
    results, solutions = {}, {}
    last = None
    for name, loads in cases.items():
        t0 = time.perf_counter()  # from the last case's equilibrium; after one Newton failed, from the start
        solutions[name] = last = model.next_case(loads) if last and last.converged else model.solve(loads)
        timings[name] = time.perf_counter() - t0
        results[name] = summary(solutions[name], section, material.f_y, frame.names, grid.joints, beam_names)
    snow_side = next(n for n in cases if n.endswith("S one-sided"))
    spot = grid.joints[results[snow_side]["max_deflection_node"]]
    name = f"{settings.gamma_g:g} G + {settings.gamma_q:g} P at {results[snow_side]['max_deflection_node']}"
    cases[name] = cases[f"{settings.gamma_g:g} G"] + settings.gamma_q * person(frame, spot, settings)
    t0 = time.perf_counter()
    solutions[name] = model.next_case(cases[name]) if last.converged else model.solve(cases[name])
    timings[name] = time.perf_counter() - t0
    results[name] = summary(solutions[name], section, material.f_y, frame.names, grid.joints, beam_names)
    record = {"model": {"nodes": len(frame.xyz), "beams": len(frame.beams), "links": len(frame.links),
                        "hinges": len(frame.hinges), "cables": len(frame.cables), "supports": len(frame.supports),
                        "dofs": 6 * len(frame.xyz), "stations": options.stations,
                        "pair_spacing_mm": options.pair_spacing, "support_kind": options.supports,
                        "couplers": len(options.couplers) if options.stations > 1 else 0},
              "loads": settings.__dict__, "cases": results,
              "erection": {"factor": rounded(erection.factor), "mode_peak_node": frame.names[erection.peak()]},
              "residual_check": residual_check(grid, solutions["residual"], material)}
    if buckling:
        t0 = time.perf_counter()
        record["buckling"] = case_buckling(grid, cases)
        timings["buckling"] = time.perf_counter() - t0
    record["seconds"] = {k: round(v, 3) for k, v in timings.items()}
    return record


def residual_check(grid: GridshellFrame, solution, material: Material) -> dict:
    """The unloaded frame's weak-axis bending and twist stresses against the geometric check's E t k_g / 2 and G t tau_g
    at the same beams: the largest deviation in % of the largest geometric stress, overall and at the 99th percentile."""
    section = grid.frame.section
    forces = solution.beam_forces
    bending = np.abs(forces[:, 1:3]).max(axis=1) / (section.h * section.t ** 2 / 6.0)
    shear = np.abs(forces[:, 5]) * section.t / section.J
    geometric = material.E * section.t * np.abs(grid.design[:, 0]) / 2.0, material.G * section.t * np.abs(grid.design[:, 1])
    out = {}
    for key, fe, geo in (("bending", bending, geometric[0]), ("shear", shear, geometric[1])):
        deviation = np.abs(fe - geo) / geo.max()
        out[key] = {"frame_max": round(float(fe.max()), 2), "geometric_max": round(float(geo.max()), 2),
                    "deviation_max_pct": round(100 * float(deviation.max()), 2),
                    "deviation_p99_pct": round(100 * float(np.percentile(deviation, 99)), 2),
                    "deviation_median_pct": round(100 * float(np.median(deviation)), 2)}
    out["max_utilisation"] = round(float(utilisation(forces, section, material.f_y).max()), 4)
    return out
