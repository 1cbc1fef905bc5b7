"""Structural check of a lamella (domain.md section 6): bending from k_g, shear and helix stress from twist.

All inputs in mm, 1/mm and N/mm2. Bending (6.1): sigma = E t k_g / 2. Twist (6.4): tau = G t tau_g.
Helix torsion (6.8-6.10): eps(r) = (r kappa)^2 / 2 - i_p^2 kappa^2 / 2, so the edges (r = h/2) stretch and
the centre contracts. The thesis checks each against yield separately; fabline also reports their
combination (worst of edge fibre and face centre, von Mises) for every node interval.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fabline.geometry.darboux import LamellaGeometry
from fabline.unroll.materials import Material, Profile

MM_PER_M = 1000.0


def min_bending_radius(material: Material, profile: Profile) -> float:
    """Smallest weak-axis bending radius before yield, r_min = E t / (2 f_y) (6.3), mm."""
    return material.E * profile.t / (2.0 * material.f_y)


def max_twist(material: Material, profile: Profile) -> float:
    """Largest twist before shear yield, kappa_x,max = tau_y / (G t) (6.6), rad/mm."""
    return material.tau_y / (material.G * profile.t)


def bending_stress(material: Material, profile: Profile, k_g: np.ndarray | float) -> np.ndarray:
    """Weak-axis bending stress E t |k_g| / 2 (6.1, 6.2), N/mm2."""
    return material.E * profile.t * np.abs(k_g) / 2.0


def twist_shear_stress(material: Material, profile: Profile, twist: np.ndarray | float) -> np.ndarray:
    """St Venant shear stress of the thin strip, G t |twist| (6.4), N/mm2."""
    return material.G * profile.t * np.abs(twist)


def helix_strains(profile: Profile, twist: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """Helix strains at the centre (minimum) and at the edges r = h/2 (maximum) for a given twist (6.8, 6.9)."""
    kappa_sq = np.asarray(twist, dtype=float) ** 2
    centre = -0.5 * profile.polar_radius_sq * kappa_sq
    return centre, 0.5 * (profile.h / 2.0) ** 2 * kappa_sq + centre


def helix_stresses(material: Material, profile: Profile, twist: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """Helix normal stresses sigma_H,min (centre) and sigma_H,max (edges) (6.10), N/mm2."""
    centre, edge = helix_strains(profile, twist)
    return material.E * centre, material.E * edge


def utilisations(material: Material, profile: Profile, k_g: np.ndarray, twist: np.ndarray) -> dict[str, np.ndarray]:
    """Utilisation against yield of each effect and of their combination, pointwise.

    bending = sigma_b / f_y, shear = tau / tau_y, helix = sigma_H,max / f_y; combined is the worse of the
    edge fibre (sigma_b + sigma_H,max, no torsional shear there) and the face centre (von Mises of
    sigma_b + |sigma_H,min| with tau).
    """
    sigma_b = bending_stress(material, profile, k_g)
    tau = twist_shear_stress(material, profile, twist)
    sigma_min, sigma_max = helix_stresses(material, profile, twist)
    edge = sigma_b + sigma_max
    centre = np.sqrt((sigma_b - sigma_min) ** 2 + 3.0 * tau ** 2)
    return {"bending": sigma_b / material.f_y, "shear": tau / material.tau_y, "helix": sigma_max / material.f_y,
            "combined": np.maximum(edge, centre) / material.f_y}


def limits(material: Material, profile: Profile, radius: float | None = None, twist: float | None = None) -> dict:
    """A designer's quick check: minimum radius, maximum twist, and the stresses at a given radius (mm) or twist (rad/m)."""
    kappa_max = max_twist(material, profile)
    result = {
        "profile": str(profile), "material": material.name,
        "E": material.E, "G": material.G, "f_y": material.f_y, "tau_y": material.tau_y,
        "min_bending_radius_mm": min_bending_radius(material, profile),
        "max_twist_rad_per_m": kappa_max * MM_PER_M, "max_twist_deg_per_m": float(np.degrees(kappa_max * MM_PER_M)),
    }
    if radius is not None:
        sigma = float(bending_stress(material, profile, 1.0 / radius))
        result["at_radius"] = {"radius_mm": radius, "bending_stress": sigma, "utilisation": sigma / material.f_y}
    if twist is not None:
        kappa = twist / MM_PER_M
        tau = float(twist_shear_stress(material, profile, kappa))
        eps_min, eps_max = helix_strains(profile, kappa)
        sigma_min, sigma_max = helix_stresses(material, profile, kappa)
        result["at_twist"] = {
            "twist_rad_per_m": twist, "shear_stress": tau, "shear_utilisation": tau / material.tau_y,
            "helix_strain_min": float(eps_min), "helix_strain_max": float(eps_max),
            "helix_stress_min": float(sigma_min), "helix_stress_max": float(sigma_max),
            "helix_utilisation": float(sigma_max) / material.f_y,
            "centre_contraction_mm_per_m": float(-eps_min) * MM_PER_M,
        }
    return result


@dataclass
class LamellaCheck:
    """Per node interval extremes of one lamella's curvatures and utilisations, and its warnings."""

    lamella: str
    length: float
    node_ids: list[str]
    max_k_g: np.ndarray
    max_tau_g: np.ndarray
    max_k_n: np.ndarray
    use: dict[str, np.ndarray]
    centre_contraction: float
    top_extension: float
    bottom_extension: float
    warnings: list[str] = field(default_factory=list)

    @property
    def utilisation(self) -> float:
        """The governing utilisation of the thesis's separate checks (bending, shear, helix)."""
        return float(max(self.use[k].max() for k in ("bending", "shear", "helix")))

    def summary(self, material: Material, profile: Profile) -> dict:
        """The lamella's row in the report: extremes, utilisations and the helix length changes."""
        k_g, tau_g = float(self.max_k_g.max()), float(self.max_tau_g.max())
        governing = max(("bending", "shear", "helix"), key=lambda k: self.use[k].max())
        return {
            "lamella": self.lamella, "length_mm": round(self.length, 3),
            "min_radius_mm": round(1.0 / k_g, 1) if k_g > 0 else None,
            "min_allowed_radius_mm": round(min_bending_radius(material, profile), 1),
            "max_twist_rad_per_m": round(tau_g * MM_PER_M, 4),
            "max_allowed_twist_rad_per_m": round(max_twist(material, profile) * MM_PER_M, 4),
            "max_in_plane_curvature_per_m": round(float(self.max_k_n.max()) * MM_PER_M, 6),
            "max_bending_stress": round(float(bending_stress(material, profile, k_g)), 2),
            "max_shear_stress": round(float(twist_shear_stress(material, profile, tau_g)), 2),
            "max_helix_stress": round(float(helix_stresses(material, profile, tau_g)[1]), 2),
            **{f"utilisation_{k}": round(float(v.max()), 4) for k, v in self.use.items()},
            "utilisation": round(self.utilisation, 4), "governing": governing,
            "helix_centre_contraction_mm": round(self.centre_contraction, 3),
            "helix_top_edge_extension_mm": round(self.top_extension, 3),
            "helix_bottom_edge_extension_mm": round(self.bottom_extension, 3),
            "intervals": self._intervals(),
        }

    def _intervals(self) -> list[dict]:
        """Per node interval: the largest k_g and tau_g (1/m) and the utilisations, rounded for the report."""
        columns = {"k_g_per_m": np.round(self.max_k_g * MM_PER_M, 6), "tau_g_per_m": np.round(self.max_tau_g * MM_PER_M, 6),
                   **{k: np.round(v, 4) for k, v in self.use.items()}}
        names, values = list(columns), zip(*(c.tolist() for c in columns.values()))
        return [{"from": a, "to": b, **dict(zip(names, row))}
                for a, b, row in zip(self.node_ids[:-1], self.node_ids[1:], values)]


def check_lamella(geometry: LamellaGeometry, material: Material, profile: Profile) -> LamellaCheck:
    """Check one lamella along its centreline, interval by interval between consecutive nodes.

    Warns (naming the lamella, the two nodes and the numbers) where a separate check exceeds 100 %:
    a radius below r_min, a twist above kappa_max, or a helix edge stress above f_y.
    """
    s = geometry.s
    k_g, tau_g, k_n = np.abs(geometry.k_g), np.abs(geometry.tau_g), np.abs(geometry.k_n)
    node_s = geometry.node_s
    starts = np.searchsorted(s, node_s[:-1], side="left")
    starts[0] = 0
    starts = np.minimum(starts, len(s) - 1)
    ends = np.minimum(np.searchsorted(s, node_s[1:], side="right"), len(s))
    ends[-1] = len(s)
    max_k_g, max_tau_g, max_k_n = (_interval_max(a, starts, ends) for a in (k_g, tau_g, k_n))
    use = utilisations(material, profile, max_k_g, max_tau_g)
    ds = np.diff(s)
    mid_tau = (tau_g[1:] + tau_g[:-1]) / 2.0
    contraction = float(-np.sum(helix_strains(profile, mid_tau)[0] * ds))
    top, bottom = (helix_edge_extension(geometry, r) for r in (profile.h / 2.0, -profile.h / 2.0))
    check = LamellaCheck(geometry.lamella.id, geometry.length, list(geometry.node_ids), max_k_g, max_tau_g, max_k_n,
                         use, contraction, top, bottom)
    check.warnings = _warnings(check, material, profile)
    return check


def helix_edge_extension(geometry: LamellaGeometry, r: float) -> float:
    """How much longer the twisted strip's fibre at height r (along n) is than the flat strip's (mm), 6.7.

    The fibre c + r n has length element sqrt((1 - r k_n)^2 + (r tau_g)^2) ds; the flat strip, bent in
    plane by k_n, gives it (1 - r k_n) ds; the difference is the non-developable helix part.
    """
    ds = np.diff(geometry.s)
    k_n = (geometry.k_n[1:] + geometry.k_n[:-1]) / 2.0
    tau_g = (geometry.tau_g[1:] + geometry.tau_g[:-1]) / 2.0
    flat = 1.0 - r * k_n
    return float(np.sum((np.hypot(flat, r * tau_g) - flat) * ds))


def _interval_max(values: np.ndarray, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Maximum of values[starts[i]:ends[i]] for each i (intervals may overlap by their shared sample)."""
    out = np.maximum.reduceat(values, starts)
    closing = values[np.minimum(ends, len(values)) - 1]
    return np.maximum(out, closing)


def _warnings(check: LamellaCheck, material: Material, profile: Profile) -> list[str]:
    """One line per lamella and check that exceeds yield, naming the worst interval's nodes and numbers."""
    lines = []
    r_min, kappa_max = min_bending_radius(material, profile), max_twist(material, profile)
    for key in ("bending", "shear", "helix"):
        over = np.flatnonzero(check.use[key] > 1.0)
        if not over.size:
            continue
        worst = int(over[np.argmax(check.use[key][over])])
        a, b = check.node_ids[worst], check.node_ids[worst + 1]
        where = f"lamella {check.lamella}, nodes {a}..{b}" + (f" (and {over.size - 1} more intervals)" if over.size > 1 else "")
        percent = 100.0 * check.use[key][worst]
        if key == "bending":
            detail = (f"bending radius {1.0 / check.max_k_g[worst]:.0f} mm is below the minimum {r_min:.0f} mm "
                      f"for a {profile.t:g} mm thick strip ({percent:.0f} % of f_y)")
        elif key == "shear":
            detail = (f"twist {check.max_tau_g[worst] * MM_PER_M:.3f} rad/m exceeds the maximum {kappa_max * MM_PER_M:.3f} rad/m "
                      f"for a {profile.t:g} mm thick strip ({percent:.0f} % of tau_y)")
        else:
            detail = (f"helix edge stress at twist {check.max_tau_g[worst] * MM_PER_M:.3f} rad/m is {percent:.0f} % of f_y "
                      f"for a {profile.h:g} mm high strip")
        lines.append(f"{where}: {detail}")
    return lines
