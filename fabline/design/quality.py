"""Quality of a traced network: how asymptotic its curves are, how they cross, how even the spacing is, and the strain.

Curvatures come from the geometry stage (splines through the written curves and normals), so the
report measures the network file as the later stages will see it. Twist (tau_g) and weak-axis bending
(k_g) are checked by the unroll stage's combined check (`structural_verdict`), so the design says what unroll says.
"""

from __future__ import annotations

import numpy as np

from fabline.geometry import analyse
from fabline.mechanics.materials import get_material, parse_profile
from fabline.model.network import Network
from fabline.mechanics.structure import (check_lamellas, combined_radius_limit, combined_twist_limit, percent,
                                         structural_verdict, verdict_lines)

MM_PER_M = 1000.0


def quality_report(network: Network, surface=None, spacing: float | None = None, material: str = "steel-s235",
                   profile: str = "100x1.5") -> dict:
    """k_n along every curve, crossing angles, node spacing, distance to the surface, twist and bending against the limits.

    Lengths in the model's units, curvatures in 1/m, distances in mm, angles in degrees.
    """
    geometry = analyse(network)
    per_metre = MM_PER_M  # geometry works in mm and 1/mm
    unit_mm = network.mm_per_unit
    curves = {}
    for lam_id, geo in geometry.lamellas.items():
        curves[lam_id] = {"max_k_n": float(np.abs(geo.k_n_curve).max() * per_metre),  # the traced curve's own bending
                          "max_k_g": float(np.abs(geo.k_g).max() * per_metre),
                          "max_tau_g": float(np.abs(geo.tau_g).max() * per_metre)}
    angles = np.array(list(geometry.crossing_angles.values()))
    crossing = {nid for nid, lams in network.lamellas_at().items() if len(lams) >= 2}
    gaps = np.array([b - a for geo in geometry.lamellas.values()
                     for (na, a), (nb, b) in zip(zip(geo.node_ids, geo.node_s), zip(geo.node_ids[1:], geo.node_s[1:]))
                     if na in crossing and nb in crossing]) / unit_mm
    material_data, profile_data = get_material(material), parse_profile(profile)
    checks = {check.lamella: check for check in check_lamellas(list(geometry.lamellas.values()), material_data, profile_data)}
    worst_twist = max(curves, key=lambda k: curves[k]["max_tau_g"])
    worst_bend = max(curves, key=lambda k: curves[k]["max_k_g"])
    twist = curves[worst_twist]["max_tau_g"]
    bend = curves[worst_bend]["max_k_g"]
    report = {
        "lamellas": len(network.lamellas), "nodes": len(network.nodes),
        "k_n": {"max": max(c["max_k_n"] for c in curves.values()),
                "mean_of_max": float(np.mean([c["max_k_n"] for c in curves.values()])), "worst": max(curves, key=lambda k: curves[k]["max_k_n"])},
        "crossing_angles": _stats(angles),
        "spacing": {"requested": spacing, **_stats(gaps)},
        "twist": {"max_tau_g": twist, "lamella": worst_twist, **_at_most(checks[worst_twist], "twist", material_data, profile_data)},
        "bending": {"max_k_g": bend, "lamella": worst_bend, "min_radius_mm": (MM_PER_M / bend) if bend else None,
                    **_at_most(checks[worst_bend], "bending", material_data, profile_data)},
        "structure": structural_verdict(list(checks.values()), material_data, profile_data, network.meta.get("k_max")),
        "material": material, "profile": profile, "curves": curves,
    }
    if surface is not None:
        points = np.vstack([lam.curve for lam in network.lamellas])
        distance = np.linalg.norm(surface.project(points).xyz - points, axis=1) * unit_mm
        report["distance_to_surface_mm"] = {"mean": float(distance.mean()), "max": float(distance.max())}
        cells, area = covered_area(network)
        report["coverage"] = {"cells": cells, "area": area, "surface_area": float(surface.mesh.area),
                              "fraction": area / float(surface.mesh.area)}
    return report


def covered_area(network: Network) -> tuple[int, float]:
    """The network's cells (four crossings joined by consecutive stretches of two A and two B lamellas) and their
    area in the model's units squared (each cell as two triangles over its corners: its chords' area)."""
    at = network.lamellas_at()
    crossing = {nid for nid, lams in at.items() if len(lams) >= 2}
    along: dict[str, list[str]] = {lam.id: [nid for nid in lam.nodes if nid in crossing] for lam in network.lamellas}
    family = {lam.id: lam.family for lam in network.lamellas}
    position = {(lam_id, nid): k for lam_id, chain in along.items() for k, nid in enumerate(chain)}

    def beside(nid: str, lam_id: str) -> list[str]:
        k, chain = position[(lam_id, nid)], along[lam_id]
        return [chain[j] for j in (k - 1, k + 1) if 0 <= j < len(chain)]

    def joined(a: str, b: str, fam: str) -> bool:
        return any(family[lam] == fam and b in beside(a, lam) for lam in at[a])

    cells: dict[frozenset, tuple[str, ...]] = {}
    for lam_id, chain in along.items():
        if family[lam_id] != "A":
            continue
        for n1, n2 in zip(chain, chain[1:]):
            for b1 in (lam for lam in at[n1] if family[lam] == "B"):
                for b2 in (lam for lam in at[n2] if family[lam] == "B" and lam != b1):
                    for n4 in beside(n1, b1):
                        for n3 in beside(n2, b2):
                            if n3 != n4 and joined(n3, n4, "A"):
                                cells[frozenset((n1, n2, n3, n4))] = (n1, n2, n3, n4)
    xyz = {nid: network.nodes[nid].xyz for nid in crossing}
    area = 0.0
    for n1, n2, n3, n4 in cells.values():
        area += 0.5 * (np.linalg.norm(np.cross(xyz[n2] - xyz[n1], xyz[n3] - xyz[n1]))
                       + np.linalg.norm(np.cross(xyz[n3] - xyz[n1], xyz[n4] - xyz[n1])))
    return len(cells), float(area)


def _at_most(check, what: str, material, profile) -> dict:
    """At the lamella's interval of largest twist (or bending): the combined limit of that effect given the other
    effect there (twist rad/m at its radius, radius mm at its twist; None if its twist alone exceeds yield) and
    the combined utilisation."""
    at = int(np.argmax(check.max_tau_g if what == "twist" else check.max_k_g))
    k_g, tau_g = float(check.max_k_g[at]), float(check.max_tau_g[at])
    limit = (combined_twist_limit(material, profile, k_g) * MM_PER_M if what == "twist"
             else combined_radius_limit(material, profile, tau_g))
    return {"limit" if what == "twist" else "limit_radius_mm": limit, "utilisation": float(check.use["combined"][at])}


def percent_area(fraction: float) -> str:
    """A covered fraction as a percentage, never shown as 100 % unless it is whole."""
    shown = f"{fraction * 100:.1f} %"
    return "99.9 %" if shown == "100.0 %" and fraction < 1.0 else shown


def _stats(values: np.ndarray) -> dict:
    if len(values) == 0:
        return {"count": 0}
    return {"count": int(len(values)), "mean": float(values.mean()), "min": float(values.min()), "max": float(values.max()),
            "std": float(values.std())}


def summary_lines(report: dict, units: str) -> list[str]:
    """The report in a few printed lines."""
    angles, gaps = report["crossing_angles"], report["spacing"]
    lines = [f"k_n along the curves: max {report['k_n']['max']:.2g} 1/m (lamella {report['k_n']['worst']}), "
             f"mean of the maxima {report['k_n']['mean_of_max']:.2g} 1/m"]
    if angles["count"]:
        lines.append(f"crossing angles: {angles['min']:.2f}..{angles['max']:.2f} deg (mean {angles['mean']:.2f}) at {angles['count']} nodes")
    if gaps["count"]:
        asked = f", asked {gaps['requested']:g}" if gaps.get("requested") else ""
        lines.append(f"node spacing along the curves: {gaps['mean']:.4g} {units} mean, {gaps['min']:.4g}..{gaps['max']:.4g} "
                     f"(std {gaps['std']:.3g}{asked})")
    if "distance_to_surface_mm" in report:
        d = report["distance_to_surface_mm"]
        lines.append(f"curves off the surface: {d['mean']:.3f} mm mean, {d['max']:.3f} mm max")
    if "coverage" in report:
        c = report["coverage"]
        lines.append(f"covers {percent_area(c['fraction'])} of the surface's area ({c['area']:.4g} of {c['surface_area']:.4g} "
                     f"{units}2 in {c['cells']} cells)" + (f"; {c['left_out']:.4g} {units}2 has no asymptotic lines (K >= 0 "
                                                           "or flat), left out" if c.get("left_out") else ""))
    if "structure" not in report:  # a network file from before the combined check: its figures meant otherwise
        lines.append("structural check: not in this file (an older fabline wrote it); `fabline unroll` gives the verdict")
        return lines
    t, b = report["twist"], report["bending"]
    limit = f"{t['limit']:.3f} rad/m" if t["limit"] else "none"
    lines.append(f"largest twist {t['max_tau_g']:.3f} rad/m on {t['lamella']} ({percent(t['utilisation'])} combined; "
                 f"combined limit there {limit} for {report['profile']} {report['material']})")
    radius = f"radius {b['min_radius_mm']:.0f} mm" if b["min_radius_mm"] else "no bending"
    limit = f"{b['limit_radius_mm']:.0f} mm" if b["limit_radius_mm"] else "none (its twist alone exceeds yield)"
    lines.append(f"largest weak-axis bending k_g {b['max_k_g']:.3f} 1/m on {b['lamella']} ({radius}, "
                 f"{percent(b['utilisation'])} combined; smallest radius allowed at its twist {limit})")
    lines.extend(verdict_lines(report["structure"]))
    return lines
