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

from fabline.model.surfaces.field import asymptotic_directions

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
        out = np.zeros(len(alive), dtype=bool)
        out[finite] = surface.outside(target[finite])
        keep = finite & ~out
        new = surface.project(target[keep]).xyz
        for row, index in enumerate(alive[keep]):
            paths[index].append(new[row])
        points[alive[keep]] = new
        heading[alive[keep]] = move[keep] / np.linalg.norm(move[keep], axis=1, keepdims=True)
        edge = alive[out]
        if edge.size:
            ends = _trim(surface, points[edge], step * move[out])
            for row, index in enumerate(edge):
                if np.linalg.norm(ends[row] - points[index]) > 1e-9 * step:
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
    lifted = surface.at(points)
    a, b, _ = asymptotic_directions(lifted.normal, lifted.shape)
    direction = a if family == "A" else b
    if previous is not None:
        flip = np.einsum("ij,ij->i", direction, previous) < 0
        direction[flip] *= -1
    return direction


def _trim(surface: Surface, starts: np.ndarray, moves: np.ndarray) -> np.ndarray:
    """Where each step from an inside point leaves the surface, by bisection on the step fraction."""
    lo, hi = np.zeros(len(starts)), np.ones(len(starts))
    for _ in range(TRIM_BISECTIONS):
        mid = 0.5 * (lo + hi)
        out = surface.outside(starts + mid[:, None] * moves)
        hi = np.where(out, mid, hi)
        lo = np.where(out, lo, mid)
    return surface.project(starts + lo[:, None] * moves).xyz
