"""Tracing asymptotic curves: classical Runge-Kutta on the direction field, every step projected onto the surface.

All curves of one call advance together (one batch of closest-point queries per stage). Each stage's
direction is the family's asymptotic direction at the stage point, signed to agree with the step before,
so the curve never flips. A curve stops where asymptotic lines end or a strip cannot follow them (`StopRule`):
where it leaves the surface (trimmed to the boundary by bisection), where K >= 0, where the two directions
merge (they cross at under MIN_CROSSING_DEG), where the surface is flat (both curvatures under the flat
threshold: the directions are noise), where it turns tighter or twists more than the strip can (the
combined rule's limits with the other effect zero), where the normal field is too rough to trust (a step's
chord leaves the tangent plane), or when it closes on itself. The reason of each end is kept.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from fabline.design.field import asymptotic_directions
from fabline.design.mesh import principal

TRIM_BISECTIONS = 30
MIN_CROSSING_DEG = 30.0
"""The two families cross at less than this: they merge. The slot (twice the strip's thickness t wide) holds a
lamella crossing at angle a over t / sin a of its width: 2 t at 30 degrees, the whole slot."""
ROUGH_TILT_DEG = 5.0
"""A step whose chord leaves the tangent plane by more than this: the normal field is too rough to trust there
(an asymptotic curve's chord lies in it to second order; the network check allows 10 degrees)."""
BEND_WINDOW = 1.0
"""The curve's turning (geodesic curvature) is averaged over this many radians at the stop limit (an arc of the
smallest radius the tracer allows), so the noise of a step's direction (8 degrees at a noisy edge) does not stop
it, while a tight loop does within a few steps (a 7 mm loop pushes the average over after about 7 mm of it)."""
STOP_REASONS = {
    "edge": "reaches the edge", "closed": "closes on itself", "length": "reaches the tracing length",
    "K>=0": "reaches a region where K >= 0 (synclastic or parabolic: no asymptotic lines)",
    "merging": f"reaches where the two asymptotic directions merge (they cross at under {MIN_CROSSING_DEG:g} degrees)",
    "flat": "reaches a flat region (both curvatures near zero: the directions are noise)",
    "bend": "turns tighter than the strip can bend (under half its smallest radius)",
    "twist": "twists more than the strip can (over twice its largest twist)",
    "rough": "meets a normal field too rough to trust (the curve would leave the surface)",
}
"""Why a traced curve ends, as a designer reads it."""


@dataclass(frozen=True)
class StopRule:
    """Where a strip cannot follow an asymptotic curve, in the surface's units: `flat` the curvature (1/unit)
    both principal curvatures stay under at a flat point, `max_k_g` the sharpest turn (1/unit: the strip's
    smallest radius at zero twist), `max_twist` the largest twist (rad/unit, at zero bending)."""

    flat: float = 0.0
    max_k_g: float = np.inf
    max_twist: float = np.inf


class Surface(Protocol):
    """What the tracer needs of a surface: projection onto it (with normal and second fundamental form), and its edge."""

    def at(self, points: np.ndarray): ...

    def project(self, points: np.ndarray): ...

    def outside(self, points: np.ndarray) -> np.ndarray: ...


@dataclass
class TracedCurve:
    """A traced curve as a polyline on the surface, and why each end stopped (a key of STOP_REASONS)."""

    points: np.ndarray
    stops: tuple[str, str]
    seed_index: int


def trace_family(surface: Surface, seeds: np.ndarray, family: str, step: float, max_length: float,
                 rule: StopRule = StopRule()) -> list[TracedCurve]:
    """The curves of `family` ("A" or "B") through each seed point, both ways until they stop (`rule`)."""
    seeds = surface.project(np.asarray(seeds, dtype=float).reshape(-1, 3)).xyz
    start = _direction(surface, seeds, family, None)
    count = len(seeds)
    points = np.vstack([seeds, seeds])
    heading = np.vstack([start, -start])
    paths: list[list[np.ndarray]] = [[p.copy()] for p in points]
    turns: list[list[float]] = [[] for _ in points]  # signed geodesic turning of each step, radians
    window = max(1, int(np.ceil(BEND_WINDOW / (rule.max_k_g * step)))) if rule.max_k_g < np.inf else 0
    stops = ["length"] * (2 * count)
    alive = np.flatnonzero(np.isfinite(heading).all(axis=1))
    for i in np.flatnonzero(~np.isfinite(heading).all(axis=1)):
        stops[i] = "K>=0"
    for _ in range(int(np.ceil(max_length / step))):
        if alive.size == 0:
            break
        p, d = points[alive], heading[alive]
        k1 = _direction(surface, p, family, d)
        k2 = _direction(surface, p + 0.5 * step * k1, family, k1)
        k3 = _direction(surface, p + 0.5 * step * k2, family, k2)
        k4 = _direction(surface, p + step * k3, family, k3)
        move = (k1 + 2 * k2 + 2 * k3 + k4) / 6.0
        target = p + step * move
        finite = np.isfinite(target).all(axis=1)
        lifted = surface.project(target[finite]) if finite.any() else None
        landed = lifted.xyz if lifted is not None else np.empty((0, 3))
        out = np.zeros(len(alive), dtype=bool)
        out[finite] = surface.outside(landed)
        keep = finite & ~out
        inner = ~out[finite]
        new = landed[inner]
        ended = _ended(rule, p[keep], d[keep], new, lifted.normal[inner] if lifted is not None else new,
                       lifted.shape[inner] if lifted is not None else np.empty((0, 3, 3)), step)
        for row, index in enumerate(alive[keep]):
            reason, turn = ended[0][row], ended[1][row]
            if reason:
                stops[index] = reason
                continue
            paths[index].append(new[row])
            turns[index].append(turn)
            if window and len(turns[index]) >= window and abs(sum(turns[index][-window:])) > rule.max_k_g * step * window:
                while len(paths[index]) > 1 and abs(turns[index][-1]) > rule.max_k_g * step:  # back to where the turn began
                    turns[index].pop()
                    paths[index].pop()
                stops[index] = "bend"
        moved = [i for row, i in enumerate(alive[keep]) if not ended[0][row]]
        points[moved] = np.array([paths[i][-1] for i in moved]).reshape(-1, 3)
        heading[alive[keep]] = move[keep] / np.linalg.norm(move[keep], axis=1, keepdims=True)
        edge = alive[out]
        if edge.size:
            beyond = landed[out[finite]]
            ends = _trim(surface, p[out], k1[out], beyond, _direction(surface, beyond, family, move[out]), step)
            for row, index in enumerate(edge):
                if len(paths[index]) > 1 and np.linalg.norm(ends[row] - points[index]) < 0.5 * step:
                    paths[index].pop()  # a short last interval would magnify the end point's tiny error
                paths[index].append(ends[row])
                stops[index] = "edge"
        for index in alive[~finite]:
            stops[index] = "K>=0"
        closed = [i for i in moved if stops[i] == "length" and len(paths[i]) > 8 and np.linalg.norm(points[i] - paths[i][0]) < step]
        for index in closed:
            stops[index] = "closed"
        alive = np.array([i for i in alive[keep] if stops[i] == "length"], dtype=np.int64)
    curves = []
    for i in range(count):
        backward = np.array(paths[count + i][1:])[::-1].reshape(-1, 3)
        joined = np.vstack([backward, np.array(paths[i])])
        curves.append(TracedCurve(joined, (stops[count + i], stops[i]), len(backward)))
    return curves


def _ended(rule: StopRule, start: np.ndarray, heading: np.ndarray, end: np.ndarray, normal: np.ndarray,
           shape: np.ndarray, step: float) -> tuple[list[str], np.ndarray]:
    """For steps from `start` (heading `heading`) to `end` (normal, second fundamental form there): the reason the
    curve cannot go there ("" where it can) and the step's signed geodesic turning (radians)."""
    chord = end - start
    length = np.maximum(np.linalg.norm(chord, axis=1), 1e-300)
    tilt = np.degrees(np.arcsin(np.clip(np.abs(np.einsum("ij,ij->i", chord, normal)) / length, 0.0, 1.0)))
    turn = np.arcsin(np.clip(np.einsum("ij,ij->i", np.cross(heading, chord / length[:, None]), normal), -1.0, 1.0))
    k1, k2, _, _ = principal(normal, shape) if len(end) else (np.empty(0),) * 4
    with np.errstate(invalid="ignore", divide="ignore"):
        crossing = 2.0 * np.degrees(np.arctan(np.sqrt(k1 / -k2)))
    crossing = np.minimum(crossing, 180.0 - crossing)
    twist = np.sqrt(np.maximum(-k1 * k2, 0.0))
    reasons = []
    for row in range(len(end)):
        if max(abs(k1[row]), abs(k2[row])) < rule.flat:
            reasons.append("flat")
        elif not (k1[row] > 0 > k2[row]):
            reasons.append("K>=0")
        elif crossing[row] < MIN_CROSSING_DEG:
            reasons.append("merging")
        elif twist[row] > rule.max_twist:
            reasons.append("twist")
        elif tilt[row] > ROUGH_TILT_DEG:
            reasons.append("rough")
        else:
            reasons.append("")
    return reasons, turn


def _direction(surface: Surface, points: np.ndarray, family: str, previous: np.ndarray | None) -> np.ndarray:
    """The family's unit asymptotic direction at the points' projections, signed to agree with `previous`."""
    direction = np.full_like(points, np.nan)
    finite = np.isfinite(points).all(axis=1)
    if finite.any():
        lifted = surface.at(points[finite])
        a, b, _ = asymptotic_directions(lifted.normal, lifted.shape)
        direction[finite] = a if family == "A" else b
    if previous is not None:
        flip = np.einsum("ij,ij->i", direction, previous) < 0
        direction[flip] *= -1
    return direction


def _trim(surface: Surface, start: np.ndarray, start_dir: np.ndarray, end: np.ndarray, end_dir: np.ndarray,
          step: float) -> np.ndarray:
    """Where each step from `start` (inside) to `end` (beyond the edge, on the surface's continuation) crosses the edge.

    Bisection along the cubic Hermite curve of the step (both ends and their directions), so the curve's
    end joins it smoothly and lies on the surface to the accuracy of the step.
    """
    span = np.linalg.norm(end - start, axis=1, keepdims=True)

    def at(t: np.ndarray) -> np.ndarray:
        t = t[:, None]
        return ((2 * t**3 - 3 * t**2 + 1) * start + (t**3 - 2 * t**2 + t) * span * start_dir
                + (-2 * t**3 + 3 * t**2) * end + (t**3 - t**2) * span * end_dir)

    lo, hi = np.zeros(len(start)), np.ones(len(start))
    for _ in range(TRIM_BISECTIONS):
        mid = 0.5 * (lo + hi)
        out = surface.outside(at(mid))
        hi = np.where(out, mid, hi)
        lo = np.where(out, lo, mid)
    return at(lo)
