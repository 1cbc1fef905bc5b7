"""The lamella's net section at a slot (issue 28): at a joint only h_net = h - slot depth of the height is left.

Worked out by hand (docs/unrolling.md, "The slotted section"). The bending moment M = E I k_g and the torque
T = G J tau_g are continuous along the lamella, so over the short slot the net section carries the full section's:
- weak-axis bending: W = h t^2 / 6 becomes h_net t^2 / 6, so sigma_b,net = sigma_b h / h_net (the net section
  curves more there: "higher curvature at joints", domain.md 5);
- twist shear (thin-section torsion, W_t = h t^2 / 3): tau_net = tau h / h_net;
- the helix stress is no stress resultant but the stretch of a fibre wound about the twist axis, sigma_H(r) =
  E (r^2 - i_p^2) tau_g^2 / 2. The slot is 2 t long against a net height of about h/2, so the full section either
  side holds the fibres on their helices about the lamella's own centre line: the net section's free edge is the
  lamella's edge, still at h/2 (the full sigma_H,max), and its fibre nearest the axis is the slot root, at
  slot depth - h/2 (the clearance) off it, where the helix contraction is the centre's (nearly sigma_H,min).
The combined rule is the lamella's (`structure.utilisations`): the free edge (bending plus helix, no torsional
shear at a free edge) and the fibre nearest the axis (von Mises of bending plus helix contraction, with the shear).
Nominal net-section stresses: no notch factor at the slot's round end, and the star washers, which clamp the joint
and would share the moment, are ignored: conservative. Each slot node takes its own k_g and tau_g, interpolated at
the node's arc length (not the larger of its two intervals' maxima), as the joint sits at the node.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fabline.mechanics.materials import Material, Profile
from fabline.mechanics.structure import (bending_stress, combined_utilisations, percent, rounded_utilisation,
                                        twist_shear_stress)

SLOT_CHECKS = ("bending", "shear", "helix", "combined")


def net_height(profile: Profile, slot_depth: float) -> float:
    """The height left at a slot (mm)."""
    return profile.h - slot_depth


def slot_utilisations(material: Material, profile: Profile, slot_depth: float, k_g: np.ndarray | float,
                      twist: np.ndarray | float) -> dict[str, np.ndarray]:
    """Utilisation against yield of the net section at a slot of this depth (mm), pointwise (see the module)."""
    h_net = net_height(profile, slot_depth)
    scale = profile.h / h_net
    sigma_b = scale * bending_stress(material, profile, k_g)
    tau = scale * twist_shear_stress(material, profile, twist)
    kappa_sq = np.asarray(twist, dtype=float) ** 2
    i_p_sq = profile.polar_radius_sq
    edge_helix = 0.5 * material.E * ((profile.h / 2.0) ** 2 - i_p_sq) * kappa_sq
    nearest = max(0.0, slot_depth - profile.h / 2.0)  # the net section's fibre nearest the twist axis
    near_helix = 0.5 * material.E * (nearest ** 2 - i_p_sq) * kappa_sq
    return combined_utilisations(material, sigma_b, tau, edge_helix, np.abs(near_helix))


@dataclass
class SlotCheck:
    """One lamella's slot nodes, the curvatures there (1/mm) and the net section's utilisations."""

    net_height: float
    node_ids: list[str]
    k_g: np.ndarray
    tau_g: np.ndarray
    use: dict[str, np.ndarray]

    @property
    def utilisation(self) -> float:
        """The largest combined utilisation of the lamella's slots (0 without slots)."""
        return float(self.use["combined"].max()) if self.node_ids else 0.0

    @property
    def worst_node(self) -> str | None:
        """The slot node of the largest utilisation."""
        return self.node_ids[int(np.argmax(self.use["combined"]))] if self.node_ids else None

    def summary(self) -> dict:
        """The lamella's slot figures for parts.json's lamella row."""
        at = int(np.argmax(self.use["combined"])) if self.node_ids else None
        return {"slot_net_height_mm": round(self.net_height, 3), "slot_nodes": len(self.node_ids),
                "slot_utilisation": rounded_utilisation(self.utilisation), "slot_node": self.worst_node,
                "slot_governing": (max(SLOT_CHECKS[:3], key=lambda k: self.use[k][at]) if at is not None else None),
                "slot_k_g_per_m": round(float(self.k_g[at]) * 1000.0, 6) if at is not None else None,
                "slot_tau_g_per_m": round(float(self.tau_g[at]) * 1000.0, 6) if at is not None else None,
                "slot_passes": self.utilisation <= 1.0}


def check_slots(geometry, slot_nodes: list[str], material: Material, profile: Profile,
                slot_depth: float) -> SlotCheck:
    """The net section at every slot node of one lamella (`structure.LamellaGeometry`), its k_g and tau_g
    interpolated at the node's arc length."""
    index = {nid: k for k, nid in enumerate(geometry.node_ids)}
    slotted = set(slot_nodes)
    nodes = [nid for nid in geometry.node_ids if nid in slotted]
    s = np.asarray(geometry.node_s, dtype=float)[[index[nid] for nid in nodes]]
    k_g = np.abs(np.interp(s, geometry.s, geometry.k_g))
    tau_g = np.abs(np.interp(s, geometry.s, geometry.tau_g))
    return SlotCheck(net_height(profile, slot_depth), nodes, k_g, tau_g,
                     slot_utilisations(material, profile, slot_depth, k_g, tau_g))


def slot_verdict(checks: dict[str, SlotCheck]) -> dict | None:
    """The slots' part of the structural verdict: how many lamellas yield locally at a joint, the worst one (None
    where no lamella has a slot)."""
    if not any(check.node_ids for check in checks.values()):
        return None
    over = [lamella for lamella, check in checks.items() if check.utilisation > 1.0]
    worst = max(checks, key=lambda lamella: checks[lamella].utilisation)
    check = checks[worst]
    return {"lamellas": len(checks), "over": over, "passes": not over, "net_height_mm": check.net_height,
            "max_utilisation": rounded_utilisation(check.utilisation), "lamella": worst, "node": check.worst_node,
            "slots": sum(len(c.node_ids) for c in checks.values())}


def slot_lines(slots: dict) -> tuple[str, str]:
    """The slot verdict (`slot_verdict`) in words: a short clause for the headline and a line of its own, saying
    that a slot over yield is local yielding at the joint, not a failure of the lamella between joints."""
    where = f"lamella {slots['lamella']} at node {slots['node']}"
    net = f"{slots['net_height_mm']:g} mm of the height left"
    largest = percent(slots["max_utilisation"])
    if slots["passes"]:
        return (f"at the slots within yield (largest {largest})",
                f"  at the joints: every lamella's net section at its slots ({net}) is within yield (largest "
                f"{largest}, {where}); nominal net-section stresses, the star washers' restraint ignored (conservative)")
    over = len(slots["over"])
    return (f"at the slots {over} of {slots['lamellas']} lamellas exceed yield locally (largest {largest})",
            f"  at the joints: {over} of {slots['lamellas']} lamellas exceed yield in the net section at a slot ({net}; "
            f"largest {largest}, {where}): local yielding of the lamella at the joints, where the slot leaves about "
            f"half its height, not of the lamella between the joints (the combined check above); nominal net-section "
            f"stresses, the star washers' restraint ignored (conservative)")


def slot_warning(lamella: str, check: SlotCheck, profile: Profile) -> str | None:
    """One line for a lamella whose net section yields at a slot, naming the worst node and how many slots."""
    over = int(np.count_nonzero(check.use["combined"] > 1.0))
    if not over:
        return None
    k = int(np.argmax(check.use["combined"]))
    radius = f"{1.0 / check.k_g[k]:.0f} mm" if check.k_g[k] > 0 else "straight"
    more = f" (and {over - 1} more slot nodes)" if over > 1 else ""
    return (f"lamella {lamella}, slot at node {check.worst_node}{more}: the net section "
            f"{check.net_height:g} of {profile.h:g} mm at twist {check.tau_g[k] * 1000.0:.3f} rad/m, bending radius "
            f"{radius} is {percent(check.utilisation)} of f_y: local yielding at the joint (washers' restraint ignored), "
            f"not of the lamella between joints")
