"""From a solved case to what a designer reads: each beam's stresses and utilisation (the geometric check's combined
rule, fabline.mechanics.structure, with the frame's forces in place of the design curvatures, plus the axial force and
strong-axis bending the loads add), the largest deflection, the support reactions."""

from __future__ import annotations

import numpy as np

from fabline.analysis.frame import Section
from fabline.analysis.solve import Solution
from fabline.mechanics.structure import combined_stress, helix_stresses
from fabline.mechanics.materials import Material, Profile


def stresses(forces: np.ndarray, section: Section) -> dict[str, np.ndarray]:
    """Per beam (N/mm2): axial N/A, weak-axis bending |M_z|/W_z and strong-axis |M_y|/W_y at the worse end, the twist's
    shear T t / J (thin strip: G t times the twist), and the helix stresses of that twist (6.10)."""
    profile = Profile(section.h, section.t)
    twist = forces[:, 5] / (section.G * section.J)
    helix_min, helix_max = helix_stresses(Material("", section.E, section.G, 1.0, 1.0), profile, twist)
    return {"axial": forces[:, 0] / section.A,
            "weak": np.abs(forces[:, 1:3]).max(axis=1) / (section.h * section.t ** 2 / 6.0),
            "strong": np.abs(forces[:, 3:5]).max(axis=1) / (section.t * section.h ** 2 / 6.0),
            "shear": np.abs(forces[:, 5]) * section.t / section.J, "helix_min": helix_min, "helix_max": helix_max}


def utilisation(forces: np.ndarray, section: Section, f_y: float) -> np.ndarray:
    """The combined rule per beam: the worse of the edge fibre (axial, both bendings and the helix stretch) and the
    face centre at mid-height (von Mises of axial, weak bending and helix contraction with the twist's shear), over f_y."""
    s = stresses(forces, section)
    return combined_stress(np.abs(s["axial"]) + s["weak"], s["shear"], s["strong"] + s["helix_max"],
                           -s["helix_min"]) / f_y


def summary(solution: Solution, section: Section, f_y: float, names: list[str], joints: dict[str, int],
            beam_names: list[str]) -> dict:
    """A case's figures: the largest deflection (mm, where), every joint's deflection, the support reactions (kN,
    largest first), the largest utilisation (where)."""
    node_of = {index: nid for nid, index in joints.items()}
    joint_ids = list(joints)
    moved = np.linalg.norm(solution.displacements[[joints[n] for n in joint_ids], :3], axis=1)
    worst = int(np.argmax(moved))
    use = utilisation(solution.beam_forces, section, f_y)
    at = int(np.argmax(use))
    reactions = sorted(({"node": node_of.get(k, names[k]), "force_kN": (r[:3] / 1000.0).round(4).tolist(),
                         "resultant_kN": round(float(np.linalg.norm(r[:3])) / 1000.0, 4)}
                        for k, r in solution.reactions.items()), key=lambda row: -row["resultant_kN"])
    return {"converged": solution.converged,
            "max_deflection_mm": round(float(moved[worst]), 3), "max_deflection_node": joint_ids[worst],
            "deflections_mm": dict(zip(joint_ids, np.round(moved, 3).tolist())),
            "reactions": reactions, "max_reaction_kN": reactions[0]["resultant_kN"] if reactions else 0.0,
            "reaction_sum_kN": (sum(solution.reactions.values())[:3] / 1000.0).round(6).tolist() if reactions else [],
            "max_utilisation": round(float(use[at]), 4), "max_utilisation_at": beam_names[at],
            "utilisation_by_strip": by_strip(use, beam_names),
            "cable_max_kN": round(float(solution.cable_forces.max()) / 1000.0, 4) if len(solution.cable_forces) else None}


def by_strip(values: np.ndarray, beam_names: list[str]) -> dict[str, float]:
    """The largest of a per-beam figure along each strip (`STRIP beam K` names): what a plan picture colours a strip by."""
    out: dict[str, float] = {}
    for name, value in zip(beam_names, values.tolist()):
        strip = name.rsplit(" beam ", 1)[0]
        out[strip] = max(out.get(strip, 0.0), round(value, 4))
    return out
