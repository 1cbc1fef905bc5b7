"""The unrolled strip in its own plane: a centreline of circular arcs and the notched outline around it.

The flat centreline keeps the arc length x of the (offset) lamella and bends in plane with the normal
curvature k_n (domain.md 2): constant over each sample interval, so the edges at y = +-h/2 are arcs too
and go out with DXF bulges. A strip whose centreline stays within `straight_tolerance` of its chord is
cut as an exact rectangle. Points are placed by (anchor, dx, y): the local frame at station `anchor`
(origin on the centreline, x along the tangent, y across) shifted by (dx, y), so slots stay rectangular.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

QUARTER_ARC_BULGE = float(np.tan(np.pi / 8.0))


@dataclass
class FlatCentreline:
    """Arcs of curvature `kappa` between stations `x`; tangent angle `theta` and `points` at the stations."""

    x: np.ndarray
    kappa: np.ndarray
    theta: np.ndarray
    points: np.ndarray
    straight: bool = field(init=False)

    def __post_init__(self) -> None:
        self.straight = not np.any(self.kappa)

    @classmethod
    def build(cls, x: np.ndarray, kappa_at_x: np.ndarray, straight_tolerance: float) -> "FlatCentreline":
        """Integrate the in-plane curvature from station x[0] (mapped to the origin) and lay the chord along +x."""
        x = np.asarray(x, dtype=float)
        kappa_at_x = np.asarray(kappa_at_x, dtype=float)
        if stays_straight(x[None], kappa_at_x[None], straight_tolerance)[0]:
            return cls(x[[0, -1]], np.zeros(1), np.zeros(2), np.array([[0.0, 0.0], [x[-1] - x[0], 0.0]]))
        kappa, mean, constant = _arc_curvatures(x[None], kappa_at_x[None], straight_tolerance)
        if constant[0]:
            x, kappa = x[[0, -1]], mean[0]
        else:
            kappa = kappa[0]
        theta, points = _integrate(x, kappa)
        return cls(x, kappa, theta, points)

    def at(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Centreline points (N, 2) and tangent angles (N,) at stations x (arcs continued past the ends)."""
        x = np.asarray(x, dtype=float)
        k = np.clip(np.searchsorted(self.x, x, side="right") - 1, 0, len(self.kappa) - 1)
        dx = x - self.x[k]
        kappa = self.kappa[k]
        chord = dx * np.sinc(kappa * dx / (2.0 * np.pi))
        middle = self.theta[k] + kappa * dx / 2.0
        return self.points[k] + np.column_stack([chord * np.cos(middle), chord * np.sin(middle)]), self.theta[k] + kappa * dx

    def place(self, anchor: np.ndarray, dx: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Points at (dx, y) in the local frame at each station `anchor`."""
        if self.straight:
            x = np.asarray(anchor, dtype=float) - self.x[0] + dx
            out = np.empty(np.broadcast(x, y).shape + (2,))
            out[..., 0], out[..., 1] = x, y
            return out
        anchor, dx, y = np.broadcast_arrays(np.asarray(anchor, float), np.asarray(dx, float), np.asarray(y, float))
        origin, theta = self.at(anchor)
        c, s = np.cos(theta), np.sin(theta)
        return origin + np.column_stack([c * dx - s * y, s * dx + c * y])

    def bulge(self, x_from: np.ndarray, x_to: np.ndarray) -> np.ndarray:
        """DXF bulge of the edge arc from station x_from to x_to (both within one arc of the centreline)."""
        if self.straight:
            return np.zeros(np.shape(x_from))
        return np.tan((self.at(x_to)[1] - self.at(x_from)[1]) / 4.0)


def stays_straight(x: np.ndarray, kappa_at_x: np.ndarray, tolerance: float) -> np.ndarray:
    """Per row of stations x (one strip segment each, padded by repeating its last station and curvature), True
    when its flat centreline stays within `tolerance` of its chord, so it is cut as an exact rectangle.

    Certainly so when the largest |k| keeps it within k L^2 / 8; otherwise the integrated centreline decides: its
    stations and the sagitta of every arc between them must stay within the tolerance. The second test matters
    for a model read from a file, whose rounded coordinates leave curvature noise that never adds up to a bend.
    """
    kappa, mean, constant = _arc_curvatures(x, kappa_at_x, tolerance)
    length = x[:, -1] - x[:, 0]
    straight = np.abs(kappa).max(axis=1) * length ** 2 / 8.0 < tolerance
    test = np.flatnonzero(~straight & ~constant)
    if len(test):
        _, points = _integrate(x[test], kappa[test])
        sagitta = np.max(np.abs(kappa[test]) * np.diff(x[test], axis=1) ** 2 / 8.0, axis=1)
        straight[test] = (np.abs(points[..., 1]).max(axis=1) < tolerance) & (sagitta < tolerance)
    one_arc = ~straight & constant
    straight[one_arc] = np.abs(mean[one_arc, 0]) * length[one_arc] ** 2 / 8.0 < tolerance
    return straight


def _arc_curvatures(x: np.ndarray, kappa_at_x: np.ndarray, tolerance: float) -> tuple[np.ndarray, ...]:
    """Per row: the curvature of each arc between stations (the mean of its ends), the mean curvature over the
    row (shape (rows, 1)), and whether the row is within `tolerance` of one arc of that mean curvature."""
    kappa = (kappa_at_x[:, 1:] + kappa_at_x[:, :-1]) / 2.0
    steps = np.diff(x, axis=1)
    length = x[:, -1] - x[:, 0]
    mean = np.sum(kappa * steps, axis=1, keepdims=True) / length[:, None]
    spread = np.max(np.where(steps > 0, np.abs(kappa - mean), 0.0), axis=1)
    return kappa, mean, spread * length ** 2 / 2.0 < tolerance


def _integrate(x: np.ndarray, kappa: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tangent angles and points at stations x of arcs of curvature `kappa` between them (last axis along the
    strip, leading axes separate centrelines), from the origin with the chord laid along +x."""
    steps = np.diff(x, axis=-1)
    theta = np.zeros(x.shape)
    np.cumsum(kappa * steps, axis=-1, out=theta[..., 1:])
    chords = steps * np.sinc(kappa * steps / (2.0 * np.pi))
    middle = theta[..., :-1] + kappa * steps / 2.0
    along, across = np.zeros(x.shape), np.zeros(x.shape)
    np.cumsum(chords * np.cos(middle), axis=-1, out=along[..., 1:])
    np.cumsum(chords * np.sin(middle), axis=-1, out=across[..., 1:])
    turn = np.arctan2(across[..., -1:], along[..., -1:])
    cos, sin = np.cos(turn), np.sin(turn)
    return theta - turn, np.stack([cos * along + sin * across, cos * across - sin * along], axis=-1)


@dataclass
class Notches:
    """Edge notches (joint slots) of one edge: centre stations, width, depth (round end included)."""

    centres: np.ndarray
    width: float
    depth: float


def notch_vertices(centres: np.ndarray, width: float, depth: float, y_edge: float, top: bool) -> tuple[np.ndarray, ...]:
    """Per notch, its four vertices in traversal order: anchor, dx, y, fixed bulge of the segment that follows.

    The bottom edge runs towards +x, the top edge towards -x; the round end (a half circle, bulge -1)
    is the concave turn of a counter-clockwise outline.
    """
    half, inward = width / 2.0, -1.0 if top else 1.0
    bottom_of_notch = y_edge + inward * (depth - half)
    dx = np.array([half, half, -half, -half]) if top else np.array([-half, -half, half, half])
    ys = np.array([y_edge, bottom_of_notch, bottom_of_notch, y_edge])
    bulges = np.array([0.0, -1.0, 0.0, np.nan])
    n = len(centres)
    return (np.repeat(centres, 4), np.tile(dx, n), np.tile(ys, n), np.tile(bulges, n))


def strip_outline(centre: FlatCentreline, start: float, end: float, height: float,
                  top: Notches, bottom: Notches) -> np.ndarray:
    """Closed counter-clockwise outline of the strip from station `start` to `end` with its edge notches.

    Edge vertices sit at the notch corners and wherever the centreline's curvature changes; edge segments
    carry the bulge of their arc, notch sides are straight and notch ends half circles.
    """
    if centre.straight:
        return _straight_outline(end - start, height, top.centres - start, bottom.centres - start, top.width, top.depth)
    rows = []
    for edge_y, notches, forward in ((-height / 2.0, bottom, True), (height / 2.0, top, False)):
        breaks = centre.x[1:-1]
        breaks = breaks[(breaks > start) & (breaks < end)]
        if notches.centres.size:
            breaks = breaks[~(np.abs(breaks[:, None] - notches.centres[None, :]) <= notches.width / 2.0).any(axis=1)]
        n_anchor, n_dx, n_y, n_bulge = notch_vertices(notches.centres, notches.width, notches.depth, edge_y, not forward)
        first, last = (start, end) if forward else (end, start)
        plain = 1 + len(breaks)
        anchor = np.concatenate([[first], breaks, n_anchor, [last]])
        dx = np.concatenate([np.zeros(plain), n_dx, [0.0]])
        y = np.concatenate([np.full(plain, edge_y), n_y, [edge_y]])
        fixed = np.concatenate([np.full(plain, np.nan), n_bulge, [0.0]])
        within = np.concatenate([np.zeros(plain), np.tile(np.arange(4), len(notches.centres)), [4]])
        order = np.lexsort((within, anchor if forward else -anchor))
        rows.append((anchor[order], dx[order], y[order], fixed[order]))
    anchor, dx, y, fixed = (np.concatenate(parts) for parts in zip(*rows))
    station = anchor + dx
    bulge = np.where(np.isnan(fixed), centre.bulge(station, np.roll(station, -1)), fixed)
    points = centre.place(anchor, dx, y)
    contour = np.column_stack([points, bulge])
    contour = np.vstack([contour, contour[:1]])
    contour[-1, 2] = 0.0
    return contour if np.any(contour[:, 2]) else contour[:, :2]


def _straight_outline(length: float, height: float, top: np.ndarray, bottom: np.ndarray, width: float,
                      depth: float) -> np.ndarray:
    """`strip_outline` of a straight strip from x = 0 to `length`, built directly (the common, fast case)."""
    half, y = width / 2.0, height / 2.0

    def notches(centres: np.ndarray, sign: float) -> np.ndarray:
        # sign -1: bottom edge, run towards +x; sign +1: top edge, run towards -x
        rows = np.empty((len(centres), 4, 3))
        rows[:, :, 0] = np.sort(centres)[::int(-sign)][:, None] + sign * half * np.array([1.0, 1.0, -1.0, -1.0])
        rows[:, :, 1] = sign * np.array([y, y - depth + half, y - depth + half, y])
        rows[:, :, 2] = [0.0, -1.0, 0.0, 0.0]
        return rows.reshape(-1, 3)

    return np.vstack([[[0.0, -y, 0.0]], notches(bottom, -1.0), [[length, -y, 0.0], [length, y, 0.0]],
                      notches(top, 1.0), [[0.0, y, 0.0], [0.0, -y, 0.0]]])


_QUARTERS = np.column_stack([np.cos(np.arange(5) * np.pi / 2.0), np.sin(np.arange(5) * np.pi / 2.0)])


def circle(centre: np.ndarray, radius: float) -> np.ndarray:
    """A closed circular contour of four quarter arcs (bulges), counter-clockwise."""
    return circles(np.asarray(centre, dtype=float).reshape(1, 2), radius)[0]


def circles(centres: np.ndarray, radius: float) -> list[np.ndarray]:
    """Closed circular contours of four quarter arcs each, one per centre (M, 2), counter-clockwise."""
    rings = np.empty((len(centres), 5, 3))
    rings[:, :, :2] = centres[:, None, :] + radius * _QUARTERS[None, :, :]
    rings[:, :, 2] = [QUARTER_ARC_BULGE] * 4 + [0.0]
    return list(rings)
