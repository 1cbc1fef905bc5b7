"""Structural check of a lamella (domain.md section 6): bending from k_g, shear and helix stress from twist.

All inputs in mm, 1/mm and N/mm2. Bending (6.1): sigma = E t k_g / 2. Twist (6.4): tau = G t tau_g.
Helix torsion (6.8-6.10): eps(r) = (r kappa)^2 / 2 - i_p^2 kappa^2 / 2, so the edges (r = h/2) stretch and
the centre contracts. The thesis checks each against yield separately (high k_g and high tau_g do not meet
on an asymptotic network); but the twist's shear and its helix contraction meet at the face centre, so
fabline's verdict is the combined check (VERDICT_RULE): per node interval the worse of the edge fibre
(sigma_b + sigma_H,max) and the face centre (von Mises), which is never below a separate check.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Protocol

import numpy as np

from fabline.mechanics.materials import Material, Profile



class LamellaGeometry(Protocol):
    """What the check reads of a lamella's Darboux frame (`fabline.geometry.LamellaGeometry` has it): the lamella
    (its `id`), its length, the arc length stations s (mm), the curvatures k_n, k_g and the geodesic torsion tau_g
    (1/mm) there, and its nodes."""

    lamella: object
    s: np.ndarray
    k_n: np.ndarray
    k_g: np.ndarray
    tau_g: np.ndarray
    node_ids: list
    node_s: np.ndarray

    @property
    def length(self) -> float: ...

MM_PER_M = 1000.0
SEPARATE_CHECKS = ("bending", "shear", "helix")
CHECKS = SEPARATE_CHECKS + ("combined",)
VERDICT_RULE = ("a lamella passes when the combined utilisation of every node interval is at most 100 % of yield: "
                "the worse of the edge fibre (bending plus helix stress) and the face centre (von Mises of bending, "
                "helix contraction and twist shear). The thesis checks the effects separately because high bending "
                "and high twist do not meet on an asymptotic network, but shear and helix contraction come from the "
                "same twist and meet at the face centre.")


def percent(utilisation: float) -> str:
    """A utilisation as a percentage for people, never rounded onto or across 100 %: 1.003 is '100.3 %',
    0.997 '99.7 %', 0.5 '50 %'."""
    value = 100.0 * float(utilisation)
    text = f"{value:.0f}"
    decimals = 0
    while text.lstrip("-") in ("100", "100." + "0" * decimals) and value != 100.0 and decimals < 6:
        decimals += 1
        text = f"{value:.{decimals}f}"
    return f"{text} %"


def rounded_utilisation(value: float) -> float:
    """A utilisation rounded to 4 decimals for the report, but never onto 1 from above (1.00003 stays over 1)."""
    rounded = round(float(value), 4)
    return 1.0001 if value > 1.0 and rounded <= 1.0 else rounded


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
    sigma_min, sigma_max = helix_stresses(material, profile, twist)
    return combined_utilisations(material, bending_stress(material, profile, k_g),
                                 twist_shear_stress(material, profile, twist), sigma_max, -sigma_min)


def combined_utilisations(material: Material, sigma_b, tau, edge_helix, contraction) -> dict[str, np.ndarray]:
    """The combined rule on given stresses (N/mm2): the worse of the edge fibre (sigma_b + the helix stretch there)
    and the fibre nearest the twist axis (von Mises of sigma_b + the helix contraction there, with the shear tau);
    for the full section (`utilisations`) and the net section at a slot (`slots`)."""
    return {"bending": sigma_b / material.f_y, "shear": tau / material.tau_y, "helix": edge_helix / material.f_y,
            "combined": combined_stress(sigma_b, tau, edge_helix, contraction) / material.f_y}


def combined_stress(sigma_b, tau, edge_only, contraction):
    """The combined rule's governing stress (N/mm2): the worse of the edge fibre, sigma_b + `edge_only` (what acts
    at the edge alone: the helix stretch, and in a loaded frame its strong-axis bending), and the fibre nearest the
    twist axis, von Mises of sigma_b + the helix `contraction` there with the shear tau."""
    edge = sigma_b + edge_only
    centre = np.sqrt((sigma_b + contraction) ** 2 + 3.0 * tau ** 2)
    return np.maximum(edge, centre)


def _helix_coefficients(material: Material, profile: Profile) -> tuple[float, float]:
    """sigma_H,max = c_edge kappa^2 and |sigma_H,min| = c_centre kappa^2 (6.10), N/mm2 per (1/mm)^2."""
    i_p_sq = profile.polar_radius_sq
    return 0.5 * material.E * ((profile.h / 2.0) ** 2 - i_p_sq), 0.5 * material.E * i_p_sq


def combined_twist_limit(material: Material, profile: Profile, k_g: float = 0.0) -> float:
    """The largest twist (rad/mm) with combined utilisation 100 % at weak-axis curvature k_g (1/mm); 0 when the
    bending alone reaches yield. Closed form of `utilisations`' combined rule solved for the twist: at the edge
    sigma_b + c_e kappa^2 = f_y, at the face centre (sigma_b + c_c kappa^2)^2 + 3 (G t kappa)^2 = f_y^2."""
    sigma_b = float(bending_stress(material, profile, k_g))
    f_y = material.f_y
    if sigma_b >= f_y:
        return 0.0
    c_edge, c_centre = _helix_coefficients(material, profile)
    shear_sq = (material.G * profile.t) ** 2
    edge = (f_y - sigma_b) / c_edge
    b = 2.0 * sigma_b * c_centre + 3.0 * shear_sq  # c_c^2 x^2 + b x - (f_y^2 - sigma_b^2) = 0 in x = kappa^2
    rest = f_y ** 2 - sigma_b ** 2
    centre = 2.0 * rest / (b + math.sqrt(b * b + 4.0 * c_centre ** 2 * rest))
    return math.sqrt(min(edge, centre))


def combined_radius_limit(material: Material, profile: Profile, twist: float = 0.0) -> float | None:
    """The smallest weak-axis bending radius (mm) with combined utilisation 100 % at the given twist (rad/mm);
    None when the twist alone reaches yield (no radius is allowed, not even straight). Closed form as above,
    solved for sigma_b."""
    kappa_sq = float(twist) ** 2
    c_edge, c_centre = _helix_coefficients(material, profile)
    f_y = material.f_y
    shear_sq = 3.0 * (material.G * profile.t) ** 2 * kappa_sq
    if shear_sq >= f_y ** 2:
        return None
    sigma_b = min(f_y - c_edge * kappa_sq, math.sqrt(f_y ** 2 - shear_sq) - c_centre * kappa_sq)
    if sigma_b <= 0.0:
        return None
    return material.E * profile.t / (2.0 * sigma_b)


def limits(material: Material, profile: Profile, radius: float | None = None, twist: float | None = None) -> dict:
    """A designer's quick check: minimum radius, maximum twist, and the stresses at a given radius (mm) or twist (rad/m)."""
    kappa_max = max_twist(material, profile)
    result = {
        "profile": str(profile), "material": material.name,
        "E": material.E, "G": material.G, "f_y": material.f_y, "tau_y": material.tau_y,
        "min_bending_radius_mm": min_bending_radius(material, profile),
        "max_twist_rad_per_m": kappa_max * MM_PER_M, "max_twist_deg_per_m": float(np.degrees(kappa_max * MM_PER_M)),
        "combined_max_twist_rad_per_m": combined_twist_limit(material, profile) * MM_PER_M,
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
            # the verdict's check, with the bending of `radius` when given (both at one place)
            "combined_utilisation": float(utilisations(material, profile, np.array([1.0 / radius if radius else 0.0]),
                                                       np.array([kappa]))["combined"][0]),
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
        """The governing utilisation: the largest of every check, the combined one included (VERDICT_RULE)."""
        return float(max(self.use[k].max() for k in CHECKS))

    def summary(self, material: Material, profile: Profile) -> dict:
        """The lamella's row in the report: extremes, utilisations and the helix length changes."""
        k_g, tau_g = float(self.max_k_g.max()), float(self.max_tau_g.max())
        governing = max(CHECKS, key=lambda k: self.use[k].max())
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
            **{f"utilisation_{k}": rounded_utilisation(v.max()) for k, v in self.use.items()},
            "utilisation": rounded_utilisation(self.utilisation), "governing": governing,
            "passes": self.utilisation <= 1.0,
            **self.combined_limits(material, profile),
            "helix_centre_contraction_mm": round(self.centre_contraction, 3),
            "helix_top_edge_extension_mm": round(self.top_extension, 3),
            "helix_bottom_edge_extension_mm": round(self.bottom_extension, 3),
            "intervals": self._intervals(),
        }

    @property
    def worst_interval(self) -> int:
        """The node interval of the largest combined utilisation (the verdict's)."""
        return int(np.argmax(self.use["combined"]))

    def combined_limits(self, material: Material, profile: Profile) -> dict:
        """At the worst interval: its nodes, the allowed twist at its bending radius and the allowed radius at its
        twist (rad/m, mm; None where the twist alone reaches yield)."""
        worst = self.worst_interval
        radius = combined_radius_limit(material, profile, float(self.max_tau_g[worst]))
        return {"worst_nodes": self.node_ids[worst:worst + 2],
                "allowed_twist_at_radius_rad_per_m": round(combined_twist_limit(material, profile, float(self.max_k_g[worst]))
                                                           * MM_PER_M, 4),
                "allowed_radius_at_twist_mm": None if radius is None else round(radius, 1)}

    def _intervals(self) -> list[dict]:
        """Per node interval: the largest k_g and tau_g (1/m) and the utilisations, rounded for the report."""
        columns = {"k_g_per_m": np.round(self.max_k_g * MM_PER_M, 6), "tau_g_per_m": np.round(self.max_tau_g * MM_PER_M, 6),
                   **{k: np.where((v > 1.0) & (np.round(v, 4) <= 1.0), 1.0001, np.round(v, 4)) for k, v in self.use.items()}}
        keys = ("from", "to", *columns)  # one dict(zip) per interval: tens of thousands of rows in a large network
        rows = zip(self.node_ids[:-1], self.node_ids[1:], *(c.tolist() for c in columns.values()))
        return [dict(zip(keys, row)) for row in rows]


def check_lamella(geometry: LamellaGeometry, material: Material, profile: Profile) -> LamellaCheck:
    """Check one lamella along its centreline, interval by interval between consecutive nodes.

    Warns (naming the lamella, the two nodes and the numbers) where a separate check exceeds 100 %:
    a radius below r_min, a twist above kappa_max, or a helix edge stress above f_y.
    """
    return check_lamellas([geometry], material, profile)[0]


def check_lamellas(geometries: list[LamellaGeometry], material: Material, profile: Profile) -> list[LamellaCheck]:
    """`check_lamella` of every lamella: the per-sample and per-interval arithmetic of all of them in whole-array
    operations on their samples one lamella after another; only each lamella's sums (over its own slice, in its
    own order) and its warnings one by one. A network has hundreds of lamellas of thousands of samples."""
    if not geometries:
        return []
    sizes = [len(geo.s) for geo in geometries]
    first = np.cumsum([0] + sizes[:-1]).tolist()
    s = np.concatenate([geo.s for geo in geometries])
    raw_k_n = np.concatenate([geo.k_n for geo in geometries])
    raw_tau_g = np.concatenate([geo.tau_g for geo in geometries])
    k_g, tau_g, k_n = np.abs(np.concatenate([geo.k_g for geo in geometries])), np.abs(raw_tau_g), np.abs(raw_k_n)
    starts, ends, reduce_at = [], [], []
    for geo, base, size in zip(geometries, first, sizes):
        lo = np.searchsorted(geo.s, geo.node_s[:-1], side="left")
        lo[0] = 0
        lo = np.minimum(lo, size - 1)
        hi = np.minimum(np.searchsorted(geo.s, geo.node_s[1:], side="right"), size)
        hi[-1] = size
        starts.append(lo + base)
        ends.append(hi + base)
        reduce_at += [lo + base, [base + size]]  # the lamella's end closes its last interval (dropped below)
    interval_rows = np.cumsum([0] + [len(lo) for lo in starts]).tolist()
    is_start = np.ones(interval_rows[-1] + len(starts) - 1, dtype=bool)
    is_start[np.cumsum([len(lo) + 1 for lo in starts[:-1]], dtype=int) - 1] = False
    reduce_at, ends = np.concatenate(reduce_at[:-1]), np.concatenate(ends)  # the last lamella's runs to the end anyway
    max_k_g, max_tau_g, max_k_n = (_interval_max(a, reduce_at, is_start, ends) for a in (k_g, tau_g, k_n))
    use = utilisations(material, profile, max_k_g, max_tau_g)
    ds = np.diff(s)  # the pairs across two lamellas are computed too, and left out of every sum
    contraction_terms = helix_strains(profile, (tau_g[1:] + tau_g[:-1]) / 2.0)[0] * ds
    top_terms, bottom_terms = (_edge_extension_terms(ds, raw_k_n, raw_tau_g, r)
                               for r in (profile.h / 2.0, -profile.h / 2.0))
    checks = []
    for k, (geo, base, size) in enumerate(zip(geometries, first, sizes)):
        pairs, rows = slice(base, base + size - 1), slice(interval_rows[k], interval_rows[k + 1])
        check = LamellaCheck(geo.lamella.id, geo.length, list(geo.node_ids), max_k_g[rows], max_tau_g[rows],
                             max_k_n[rows], {key: value[rows] for key, value in use.items()},
                             float(-np.sum(contraction_terms[pairs])), float(np.sum(top_terms[pairs])),
                             float(np.sum(bottom_terms[pairs])))
        check.warnings = _warnings(check, material, profile)
        checks.append(check)
    return checks


def helix_edge_extension(geometry: LamellaGeometry, r: float) -> float:
    """How much longer the twisted strip's fibre at height r (along n) is than the flat strip's (mm), 6.7.

    The fibre c + r n has length element sqrt((1 - r k_n)^2 + (r tau_g)^2) ds; the flat strip, bent in
    plane by k_n, gives it (1 - r k_n) ds; the difference is the non-developable helix part.
    """
    return float(np.sum(_edge_extension_terms(np.diff(geometry.s), geometry.k_n, geometry.tau_g, r)))


def _edge_extension_terms(ds: np.ndarray, k_n: np.ndarray, tau_g: np.ndarray, r: float) -> np.ndarray:
    """`helix_edge_extension`'s length difference of every sample interval (curvatures at the samples, ds between)."""
    flat = 1.0 - r * ((k_n[1:] + k_n[:-1]) / 2.0)
    return (np.hypot(flat, r * ((tau_g[1:] + tau_g[:-1]) / 2.0)) - flat) * ds


def _interval_max(values: np.ndarray, reduce_at: np.ndarray, is_start: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Maximum of values[start_i:ends[i]] of every interval i (neighbours share a sample): one `maximum.reduceat` at
    the interval starts and the lamella ends (`is_start` tells which are which), then each interval's closing
    sample values[ends[i] - 1], which the next interval's start at that shared sample leaves out."""
    out = np.maximum.reduceat(values, reduce_at)[is_start]
    return np.maximum(out, values[ends - 1])


def _warnings(check: LamellaCheck, material: Material, profile: Profile) -> list[str]:
    """One line per lamella and check that exceeds yield, naming the worst interval's nodes and numbers; the
    combined check warns where it alone exceeds yield (a separate check over yield already said so)."""
    lines = []
    r_min, kappa_max = min_bending_radius(material, profile), max_twist(material, profile)
    separate_over = np.any([check.use[key] > 1.0 for key in SEPARATE_CHECKS], axis=0)
    for key in CHECKS:
        over = np.flatnonzero((check.use[key] > 1.0) & (~separate_over if key == "combined" else True))
        if not over.size:
            continue
        worst = int(over[np.argmax(check.use[key][over])])
        a, b = check.node_ids[worst], check.node_ids[worst + 1]
        where = f"lamella {check.lamella}, nodes {a}..{b}" + (f" (and {over.size - 1} more intervals)" if over.size > 1 else "")
        share = percent(check.use[key][worst])
        if key == "bending":
            detail = (f"bending radius {1.0 / check.max_k_g[worst]:.0f} mm is below the minimum {r_min:.0f} mm "
                      f"for a {profile.t:g} mm thick strip ({share} of f_y)")
        elif key == "shear":
            detail = (f"twist {check.max_tau_g[worst] * MM_PER_M:.3f} rad/m exceeds the maximum {kappa_max * MM_PER_M:.3f} rad/m "
                      f"for a {profile.t:g} mm thick strip ({share} of tau_y)")
        elif key == "helix":
            detail = (f"helix edge stress at twist {check.max_tau_g[worst] * MM_PER_M:.3f} rad/m is {share} of f_y "
                      f"for a {profile.h:g} mm high strip")
        else:
            radius = f"{1.0 / check.max_k_g[worst]:.0f} mm" if check.max_k_g[worst] > 0 else "straight"
            detail = (f"twist {check.max_tau_g[worst] * MM_PER_M:.3f} rad/m with bending radius {radius}: combined "
                      f"stress (von Mises at the face centre, or bending plus helix at the edge) is {share} of f_y "
                      f"for a {profile.h:g} x {profile.t:g} mm strip, though each effect alone is within yield")
        lines.append(f"{where}: {detail}")
    return lines


def structural_verdict(checks: list[LamellaCheck], material: Material, profile: Profile,
                       k_max: float | None = None) -> dict:
    """The verdict of a set of lamellas by the combined rule (VERDICT_RULE), as every stage says it: pass or the
    failing lamellas, the worst one's interval with its combined limits (the twist allowed at its radius, the
    radius allowed at its twist, and the limits in pure twist and pure bending), and when failing the remedies,
    each solved from the same check so that alone it brings the worst interval to 100 %: all curvatures scaled
    (the design's `k_max`, or its largest twist when none is given), a thinner strip, a lower strip, a higher f_y."""
    worst = max(checks, key=lambda check: check.utilisation)
    at = worst.worst_interval
    k_g, twist = float(worst.max_k_g[at]), float(worst.max_tau_g[at])
    radius_limit = combined_radius_limit(material, profile, twist)
    failing = [check.lamella for check in checks if check.utilisation > 1.0]
    verdict = {
        "passes": not failing, "lamellas": len(checks), "failing": failing,
        "max_utilisation": rounded_utilisation(worst.utilisation), "lamella": worst.lamella,
        "nodes": worst.node_ids[at:at + 2], "profile": str(profile), "h_mm": profile.h, "t_mm": profile.t,
        "material": material.name, "f_y": material.f_y,
        "radius_mm": 1.0 / k_g if k_g > 0 else None, "twist_rad_per_m": twist * MM_PER_M,
        "limits": {"twist_at_radius_rad_per_m": combined_twist_limit(material, profile, k_g) * MM_PER_M,
                   "radius_at_twist_mm": radius_limit,
                   "twist_straight_rad_per_m": combined_twist_limit(material, profile) * MM_PER_M,
                   "radius_untwisted_mm": min_bending_radius(material, profile),
                   "shear_alone_twist_rad_per_m": max_twist(material, profile) * MM_PER_M},
    }
    if failing:
        verdict["remedies"] = _remedies(checks, material, profile, k_max if k_max else max(
            float(check.max_tau_g.max()) for check in checks) * MM_PER_M, k_max is not None)
    return verdict


def combined_maximum(material: Material, profile: Profile, k_g: np.ndarray, twist: np.ndarray) -> float:
    """The largest combined utilisation of intervals with these curvatures (1/mm): what the remedies solve."""
    return float(utilisations(material, profile, k_g, twist)["combined"].max())


def _remedies(checks: list[LamellaCheck], material: Material, profile: Profile, k_max: float, of_design: bool) -> dict:
    """Each remedy's figure by root-finding `combined_maximum` = 1 over every interval (monotone in each)."""
    from scipy.optimize import brentq  # only a failing design pays for scipy.optimize's import

    k_g = np.concatenate([check.max_k_g for check in checks])
    twist = np.concatenate([check.max_tau_g for check in checks])

    def over(scale: float = 1.0, **dimension: float) -> float:
        return combined_maximum(material, replace(profile, **dimension), scale * k_g, scale * twist) - 1.0

    scale = brentq(lambda s: over(scale=s), 0.0, 1.0, xtol=1e-12)
    remedies = {"scale": scale, "k_max_per_m": scale * k_max, "k_max_of": "design" if of_design else "largest twist"}
    floor_t, floor_h = 1e-6 * profile.t, 1e-6 * profile.h
    remedies["t_mm"] = (brentq(lambda t: over(t=t), floor_t, profile.t, xtol=1e-12)
                        if over(t=floor_t) < 0.0 else None)  # the helix stress does not depend on t
    remedies["h_mm"] = (brentq(lambda h: over(h=h), floor_h, profile.h, xtol=1e-12)
                        if over(h=floor_h) < 0.0 else None)  # bending and shear do not depend on h
    stress = combined_maximum(material, profile, k_g, twist) * material.f_y  # utilisation is stress / f_y
    remedies["f_y"] = stress
    return remedies


def verdict_lines(verdict: dict) -> list[str]:
    """The verdict in the words every stage prints: a headline, and when failing the combined limit and the
    remedies; a remedy's printed figure is rounded to the safe side (k_max, t and h down, f_y up)."""
    worst, lim = verdict["lamella"], verdict["limits"]
    at = f"lamella {worst}, nodes {verdict['nodes'][0]}..{verdict['nodes'][1]}"
    radius = f"radius {verdict['radius_mm']:.0f} mm" if verdict["radius_mm"] else "straight"
    what = f"{verdict['profile']} mm {verdict['material']} (f_y {verdict['f_y']:g} N/mm2)"
    at_twist = (f"radius {lim['radius_at_twist_mm']:.0f} mm at its twist" if lim["radius_at_twist_mm"] is not None
                else "no radius passes at its twist (the twist alone exceeds yield)")
    limit = (f"combined limit for {what}: twist {lim['twist_at_radius_rad_per_m']:.3f} rad/m at {worst}'s bending "
             f"({radius}), {at_twist}; in pure twist {lim['twist_straight_rad_per_m']:.3f} rad/m (shear alone would allow "
             f"{lim['shear_alone_twist_rad_per_m']:.3f}), in pure bending radius {lim['radius_untwisted_mm']:.0f} mm")
    slots = None
    if verdict.get("slots"):
        from fabline.mechanics.slots import slot_lines

        slots = slot_lines(verdict["slots"])
    if verdict["passes"]:
        lines = [f"structure: all {verdict['lamellas']} lamellas pass the combined check (largest {percent(verdict['max_utilisation'])}, "
                 f"{at}: twist {verdict['twist_rad_per_m']:.3f} rad/m, {radius}); {limit}"]
        return [lines[0] + f"; {slots[0]}", slots[1]] if slots else lines
    failing = verdict["failing"]
    names = ", ".join(failing[:12]) + (f" and {len(failing) - 12} more" if len(failing) > 12 else "")
    lines = [f"structure: {len(failing)} of {verdict['lamellas']} lamellas exceed yield by the combined check: {names} "
             f"(largest {percent(verdict['max_utilisation'])}, {at}: twist {verdict['twist_rad_per_m']:.3f} rad/m, {radius})",
             f"  {limit}"]
    if slots:
        lines[0] += f"; {slots[0]}"
        lines.insert(1, slots[1])
    r = verdict["remedies"]
    k_max = math.floor(r["k_max_per_m"] * 1000.0) / 1000.0
    of = "k_max" if r["k_max_of"] == "design" else "largest twist"
    options = [f"curvatures x {math.floor(r['scale'] * 1000.0) / 1000.0:.3f} ({of} {k_max:.3f} 1/m, a flatter or larger design)"]
    h, t = verdict["h_mm"], verdict["t_mm"]
    if r["t_mm"] is not None:
        options.append(f"thickness {math.floor(r['t_mm'] * 100.0) / 100.0:.2f} mm ({h:g} x {math.floor(r['t_mm'] * 100.0) / 100.0:.2f})")
    else:
        options.append("no thinner strip (the helix stress alone exceeds yield)")
    if r["h_mm"] is None:
        options.append("no lower strip (bending and shear alone exceed yield)")
    elif r["h_mm"] <= t:
        options.append(f"no lower strip (it would be {r['h_mm']:.2g} mm high, not above its thickness)")
    else:
        options.append(f"height {math.floor(r['h_mm'] * 10.0) / 10.0:.1f} mm ({math.floor(r['h_mm'] * 10.0) / 10.0:.1f} x {t:g})")
    options.append(f"a material certified to f_y {math.ceil(r['f_y']):.0f} N/mm2")
    lines.append("  remedies, each alone bringing the largest utilisation to 100 %: " + "; ".join(options))
    return lines
