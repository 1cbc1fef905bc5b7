"""Tracing asymptotic curves: classical Runge-Kutta on the direction field, every step projected onto the surface.

All curves of one call advance together (one batch of closest-point queries per stage). Each stage's
direction is the family's asymptotic direction at the stage point, signed to agree with the step before,
so the curve never flips. A curve stops where it leaves the surface (trimmed to the boundary by
bisection), where K >= 0 (no asymptotic direction: the stop is reported), or when it closes on itself.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from fabline.design.field import asymptotic_directions

TRIM_BISECTIONS = 30


class Surface(Protocol):
    """What the tracer needs of a surface: projection onto it (with normal and second fundamental form), and its edge."""

    def at(self, points: np.ndarray): ...

    def project(self, points: np.ndarray): ...

    def outside(self, points: np.ndarray) -> np.ndarray: ...


@dataclass
class TracedCurve:
    """A traced curve as a polyline on the surface, and why each end stopped ("edge", "K>=0", "closed", "length")."""

    points: np.ndarray
    stops: tuple[str, str]
    seed_index: int


def trace_family(surface: Surface, seeds: np.ndarray, family: str, step: float, max_length: float) -> list[TracedCurve]:
    """The curves of `family` ("A" or "B") through each seed point, both ways until they stop."""
    seeds = surface.project(np.asarray(seeds, dtype=float).reshape(-1, 3)).xyz
    start = _direction(surface, seeds, family, None)
    count = len(seeds)
    points = np.vstack([seeds, seeds])
    heading = np.vstack([start, -start])
    paths: list[list[np.ndarray]] = [[p.copy()] for p in points]
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
        landed = surface.project(target[finite]).xyz if finite.any() else np.empty((0, 3))
        out = np.zeros(len(alive), dtype=bool)
        out[finite] = surface.outside(landed)
        keep = finite & ~out
        new = landed[~out[finite]]
        for row, index in enumerate(alive[keep]):
            paths[index].append(new[row])
        points[alive[keep]] = new
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
        closed = [i for i in alive[keep] if len(paths[i]) > 8 and np.linalg.norm(points[i] - paths[i][0]) < step]
        for index in closed:
            stops[index] = "closed"
        alive = np.array([i for i in alive[keep] if stops[i] == "length"], dtype=np.int64)
    curves = []
    for i in range(count):
        backward = np.array(paths[count + i][1:])[::-1].reshape(-1, 3)
        joined = np.vstack([backward, np.array(paths[i])])
        curves.append(TracedCurve(joined, (stops[count + i], stops[i]), len(backward)))
    return curves


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
