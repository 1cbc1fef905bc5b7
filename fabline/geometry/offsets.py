"""Curves offset sideways on the surface from a lamella's centreline, and where two such curves cross.

The two lamellas of a pair run o = +-d/2 beside the network curve: p(tau) = c(tau) + o u(tau), with u the
Darboux sideways vector. Since du/ds = -k_g t + tau_g n, their length element is
ds_o = sqrt((1 - o k_g)^2 + (o tau_g)^2) ds, so node distances differ from the centreline's by about
o times the integral of k_g. Splines extrapolate a little past the curve's ends, where end slots may lie.
A network's lamellas are evaluated together through `SplineTable`, so no step loops over lamellas.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fabline.geometry.darboux import GAUSS_W, GAUSS_X, CurveFit, LamellaGeometry  # the same quadrature

PAIR_SPACING_MM = 25.0  # d: centre distance of a lamella pair's two strips (unroll's default)


def strip_crossing_offsets(tangent_i: np.ndarray, tangent_j: np.ndarray, normal: np.ndarray, offset_i: np.ndarray,
                           offset_j: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where the strip `offset_i` beside curve i (along n x t_i) crosses the strip `offset_j` beside curve j, in the
    tangent plane of their node: the arc lengths (a along i, b along j) from the node; rows are crossings.

    From c + a t_i + o_i u_i = c + b t_j + o_j u_j: its u_i part gives b, its t_i part a (exact on a plane, within
    k d^2 on a surface: the start of `closest_approach`, and how far past the node a curve must run for it).
    """
    u_i, u_j = np.cross(normal, tangent_i), np.cross(normal, tangent_j)
    cos_ij, sin_ij = np.einsum("ij,ij->i", tangent_j, tangent_i), np.einsum("ij,ij->i", tangent_j, u_i)
    b = (offset_i - offset_j * np.einsum("ij,ij->i", u_j, u_i)) / sin_ij
    return b * cos_ij + offset_j * np.einsum("ij,ij->i", u_j, tangent_i), b


class SplineTable:
    """The cubic splines of many lamella fits in one coefficient table, to evaluate (fit, parameter) queries in bulk.

    The same piecewise polynomials as each `CurveFit.spline` (extrapolating from the end pieces), with
    `CurveFit.arc_length` and `parameter_at` in batched form: one set of array operations for all lamellas
    instead of a scipy call per lamella and step.
    """

    def __init__(self, fits: list[CurveFit]) -> None:
        pieces = np.array([len(fit.tau) - 1 for fit in fits])
        self.first_piece = np.cumsum(pieces) - pieces           # fit f's pieces: first_piece[f] + 0 .. pieces[f] - 1
        self.first_knot = self.first_piece + np.arange(len(fits))  # fit f's knots: first_knot[f] + 0 .. pieces[f]
        self.pieces = pieces
        self.knots = np.concatenate([fit.tau for fit in fits])
        self.s_at_knots = np.concatenate([fit.s_at_samples for fit in fits])
        self._coefficients = np.concatenate([fit.spline.c for fit in fits], axis=1)  # (4 powers, highest first; pieces; 6)
        # one increasing key for all pieces: fit f's parameters shifted by f times more than any fit spans
        self._span = float(max(fit.tau[-1] - fit.tau[0] for fit in fits)) + 1.0
        self._start = np.array([fit.tau[0] for fit in fits])
        left = np.concatenate([fit.tau[:-1] for fit in fits])
        self._piece_keys = left - np.repeat(self._start, pieces) + np.repeat(np.arange(len(fits)) * self._span, pieces)
        # the same for arc lengths (each fit's from 0), to find the piece holding a length
        self._s_span = float(self.s_at_knots.max()) + 1.0
        self._knot_s_keys = self.s_at_knots + np.repeat(np.arange(len(fits)) * self._s_span, pieces + 1)

    def local_piece(self, fit: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """Index within its fit of the polynomial piece each parameter falls in (end pieces continued outwards)."""
        key = tau - self._start[fit] + fit * self._span
        piece = np.searchsorted(self._piece_keys, key, side="right") - 1 - self.first_piece[fit]
        return np.clip(piece, 0, self.pieces[fit] - 1)

    def piece_coefficients(self, fit: np.ndarray, piece: np.ndarray) -> np.ndarray:
        """The coefficients (4 powers, highest first; N; 6) of the given local pieces: `np.take` along the pieces,
        three times faster than indexing the middle axis of the network's table, which spans hundreds of megabytes."""
        return np.take(self._coefficients, self.first_piece[fit] + piece, axis=1)

    def evaluate(self, fit: np.ndarray, piece: np.ndarray, tau: np.ndarray, derivative: int = 0) -> np.ndarray:
        """Spline values (N, 6: point and normal) or their first derivative at tau, on the given local pieces."""
        return _horner(self.piece_coefficients(fit, piece),
                       (tau - self.knots[self.first_knot[fit] + piece])[:, None], derivative)

    def arc_length(self, fit: np.ndarray, tau: np.ndarray,
                   location: "Location | None" = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """`CurveFit.arc_length` of many queries: the length from the fit's start, the local piece, and the part of
        the length within that piece (5-point Gauss-Legendre on the spline speed, as CurveFit integrates); pass the
        `location` of these parameters (from `locate`) to reuse its pieces and coefficients."""
        location = location if location is not None else self.locate(fit, tau)
        piece, lo = location.piece, location.knot
        half, mid = (tau - lo) / 2.0, (tau + lo) / 2.0
        gauss = mid[:, None] + half[:, None] * GAUSS_X[None, :]            # (N, 5), all on the query's piece
        speed = np.ascontiguousarray(_speed(location.coefficients, (gauss - lo[:, None]).T).T)  # (N, 5)
        within = half * (speed @ GAUSS_W)
        return self.s_at_knots[self.first_knot[fit] + piece] + within, piece, within

    def parameter_at(self, fit: np.ndarray, s: np.ndarray) -> np.ndarray:
        """`CurveFit.parameter_at` of many queries: the parameter at arc length s, by Newton steps from the chord."""
        key = s + fit * self._s_span
        knot = np.clip(np.searchsorted(self._knot_s_keys, key, side="right") - 1, self.first_knot[fit],
                       self.first_knot[fit] + self.pieces[fit] - 1)
        s0, s1 = self.s_at_knots[knot], self.s_at_knots[knot + 1]
        fraction = np.clip((s - s0) / (s1 - s0), 0.0, 1.0)
        tau = self.knots[knot] + fraction * (self.knots[knot + 1] - self.knots[knot])
        location = None
        for _ in range(3):
            location = self.locate(fit, tau, location)  # few parameters change piece from one step to the next
            length, _, _ = self.arc_length(fit, tau, location)
            tau = tau - (length - s) / _speed(location.coefficients, tau - location.knot)
        low, high = self.knots[self.first_knot[fit]], self.knots[self.first_knot[fit] + self.pieces[fit]]
        return np.clip(tau, low, high)

    def locate(self, fit: np.ndarray, tau: np.ndarray, previous: "Location | None" = None) -> "Location":
        """The local pieces of parameters `tau` (as `local_piece`) with their coefficients and knots.

        Given the `previous` location of the same queries (e.g. the last Gauss-Newton step's), only parameters
        that left their piece are searched and gathered again: the same result, at a fraction of the work.
        """
        if previous is None:
            piece = self.local_piece(fit, tau)
            return Location(piece, self._by_column(fit, piece), self.knots[self.first_knot[fit] + piece])
        moved = np.flatnonzero(~self._holds(fit, previous.piece, tau))
        if not moved.size:
            return previous
        piece, coefficients, knot = previous.piece.copy(), previous.coefficients.copy(), previous.knot.copy()
        piece[moved] = self.local_piece(fit[moved], tau[moved])
        coefficients[:, :, moved] = self._by_column(fit[moved], piece[moved])
        knot[moved] = self.knots[self.first_knot[fit[moved]] + piece[moved]]
        return Location(piece, coefficients, knot)

    def _by_column(self, fit: np.ndarray, piece: np.ndarray) -> np.ndarray:
        """`piece_coefficients` as (4 powers; 6; N): the table is read piece by piece (a few cache lines a query), then
        laid out so that the repeated evaluations of a `Location` run numpy's loops along all queries."""
        return np.ascontiguousarray(self.piece_coefficients(fit, piece).transpose(0, 2, 1))

    def _holds(self, fit: np.ndarray, piece: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """Whether `local_piece` would still give `piece`: the very comparisons its search makes, on the same keys."""
        key = tau - self._start[fit] + fit * self._span
        row = self.first_piece[fit] + piece
        last = piece == self.pieces[fit] - 1
        above_start = (piece == 0) | (key >= self._piece_keys[row])
        below_end = last | (key < self._piece_keys[np.where(last, row, row + 1)])
        return above_start & below_end

    def offset_points(self, fit: np.ndarray, tau: np.ndarray, offset: np.ndarray,
                      location: "Location | None" = None) -> tuple[np.ndarray, np.ndarray]:
        """Points c + o u at parameters `tau` of the given fits, and the centreline's derivative c' there; pass
        `location` (from `locate`) to reuse the pieces found for these parameters.

        c' is the offset curve's derivative up to the relative terms o k_g and o tau_g (about 1 % for a pair),
        which is all a Gauss-Newton step needs; two spline evaluations instead of the full Darboux frame.
        """
        location = location if location is not None else self.locate(fit, tau)
        coefficients, dx = location.coefficients, tau - location.knot
        value, d1 = _horner(coefficients, dx, 0), _horner(coefficients[:, :3], dx, 1)   # (6, N), (3, N)
        squares = d1 * d1
        t = np.ascontiguousarray((d1 / np.sqrt(squares[0] + squares[1] + squares[2])).T)  # np.linalg.norm's sum
        normal = np.ascontiguousarray(value[3:].T)  # rows again for einsum, whose summation order depends on layout
        n = normal - np.einsum("ij,ij->i", normal, t)[:, None] * t
        n /= np.linalg.norm(n, axis=1)[:, None]
        return value[:3].T + offset[:, None] * np.cross(n, t), np.ascontiguousarray(d1.T)


@dataclass(frozen=True)
class Location:
    """Where parameters fall in a `SplineTable`: each one's local piece, that piece's coefficients (4 powers, highest
    first; 6 columns; N) and its starting knot."""

    piece: np.ndarray
    coefficients: np.ndarray
    knot: np.ndarray

    def take(self, rows: np.ndarray) -> "Location":
        """The location of queries `rows` (e.g. each node once per strip through it), from these compact arrays rather
        than from the network's table."""
        return Location(self.piece[rows], np.take(self.coefficients, rows, axis=2), self.knot[rows])


def _speed(coefficients: np.ndarray, dx: np.ndarray) -> np.ndarray:
    """|c'|, the centreline's speed, from pieces' coefficients laid out by column (4 powers; 3 or 6 columns; N, as
    `Location` holds them) at offsets dx (..., N) into the N queries' pieces, as np.linalg.norm of the derivative
    gives it (x^2 + y^2, then + z^2). Queries come last so that numpy's inner loops run over all of them rather than
    over 3 columns: four times faster, the same operations on every value."""
    by_column = coefficients[:, :3]
    squares = _horner(by_column[(slice(None), slice(None)) + (None,) * (dx.ndim - 1)], dx, 1) ** 2
    return np.sqrt(squares[0] + squares[1] + squares[2])


def _horner(coefficients: np.ndarray, dx: np.ndarray, derivative: int) -> np.ndarray:
    """Cubic pieces (4 powers, highest first; then any shape) or their derivative at offsets dx from their knots
    (dx broadcasting against one power's coefficients)."""
    c3, c2, c1, c0 = coefficients
    if derivative == 0:
        return ((c3 * dx + c2) * dx + c1) * dx + c0
    return (3.0 * c3 * dx + 2.0 * c2) * dx + c1


@dataclass
class OffsetCurve:
    """The curve `offset` mm beside a lamella's centreline (0 for the centreline itself), with its arc length.

    The length element ratio ds_o/ds is taken from the centreline's k_g and tau_g at the samples and
    integrated by the trapezoid rule: its error is o times that of k_g, far below 0.01 mm per metre.
    """

    geometry: LamellaGeometry
    offset: float
    ratio: np.ndarray
    s_at_samples: np.ndarray

    @classmethod
    def of(cls, geometry: LamellaGeometry, offset: float, stretch: np.ndarray | float = 1.0) -> "OffsetCurve":
        """The offset curve; `stretch` (per sample) scales its length element, e.g. to undo the helix contraction."""
        return OffsetCurves.of([geometry], [offset], [stretch]).curves[0]

    @property
    def length(self) -> float:
        return float(self.s_at_samples[-1])


@dataclass(frozen=True)
class OffsetCurves:
    """Many offset curves made together, their samples in flat arrays (curve k's rows from first[k]), as
    `offset_arc_lengths` reads them; each of `curves` holds views into those arrays."""

    curves: list[OffsetCurve]
    ratio: np.ndarray
    s_at_samples: np.ndarray
    first: np.ndarray

    @classmethod
    def of(cls, geometries: list[LamellaGeometry], offsets: list[float],
           stretches: list[np.ndarray | float]) -> "OffsetCurves":
        """`OffsetCurve.of` of every (geometry, offset, stretch), written curve by curve into the flat arrays (a curve's
        few thousand samples stay in the CPU cache through all the steps, which whole-network arrays would not)."""
        sizes = [len(geo.s) for geo in geometries]
        bounds = np.cumsum([0] + sizes).tolist()
        ratio, s_at = np.empty(bounds[-1]), np.empty(bounds[-1])
        curves = []
        for geo, offset, stretch, a, b in zip(geometries, offsets, stretches, bounds[:-1], bounds[1:]):
            here = ratio[a:b]
            np.hypot(1.0 - offset * geo.k_g, offset * geo.tau_g, out=here)
            here *= stretch
            s_at[a] = 0.0
            np.cumsum(np.diff(geo.s) * (here[1:] + here[:-1]) / 2.0, out=s_at[a + 1:b])
            curves.append(OffsetCurve(geo, float(offset), here, s_at[a:b]))
        first = np.array(bounds[:-1], dtype=int)
        return cls(curves, ratio, s_at, first)


def offset_arc_lengths(table: SplineTable, curves: OffsetCurves, fit_of_curve: np.ndarray, curve: np.ndarray,
                       tau: np.ndarray, location: Location | None = None) -> np.ndarray:
    """Arc length along offset curve curves.curves[curve[i]] (beside fit fit_of_curve[curve[i]] of `table`) from its
    start to parameter tau[i], for many queries at once (negative before the start, past `length` after the end).

    Within a sample interval the length element ratio is taken as linear in the centreline's arc length. Pass the
    `location` of the parameters in `table` (`SplineTable.locate`) when it is known.
    """
    fit = fit_of_curve[curve]
    _, piece, along = table.arc_length(fit, tau, location)
    knot = table.first_knot[fit] + piece
    step = table.s_at_knots[knot + 1] - table.s_at_knots[knot]
    row = curves.first[curve] + piece
    ratio, s_at = curves.ratio, curves.s_at_samples
    ratio_here = ratio[row] + (ratio[row + 1] - ratio[row]) * along / step
    return s_at[row] + along * (ratio[row] + ratio_here) / 2.0


def closest_approach(table: SplineTable, first: np.ndarray, tau_first: np.ndarray, offset_first: np.ndarray,
                     second: np.ndarray, tau_second: np.ndarray, offset_second: np.ndarray,
                     iterations: int = 6, reach: float = 0.0,
                     near: Location | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, Location]:
    """Where the offset curve beside fit first[i] of `table` comes closest to the one beside fit second[i], near the guesses.

    Solves all crossings together by Gauss-Newton on |p(a) - q(b)|^2 (Jacobian from the centrelines, see
    `SplineTable.offset_points`: each step shrinks the error about a hundredfold), all queries of all fits in
    one evaluation per iteration. Parameters stay within `reach` of each curve's ends; `near` may give the location
    of nearby parameters (first's, then second's), where the search for the guesses' pieces starts. Returns both
    parameters, the remaining gap (mm): a crossing of curves on one surface has a gap near zero, and the
    `Location` of the parameters (first's, then second's) for further queries there.
    """
    index = np.concatenate([first, second])
    tau = np.concatenate([tau_first, tau_second]).astype(float)
    offset = np.concatenate([offset_first, offset_second]).astype(float)
    low = table.knots[table.first_knot[index]] - reach
    high = table.knots[table.first_knot[index] + table.pieces[index]] + reach
    m = len(first)
    location = near
    for step in range(iterations + 1):
        location = table.locate(index, tau, location)  # after the first step few parameters change piece
        points, derivs = table.offset_points(index, tau, offset, location)
        gap = points[:m] - points[m:]
        if step == iterations:
            break
        dp, dq = derivs[:m], derivs[m:]
        a11 = np.einsum("ij,ij->i", dp, dp)
        a22 = np.einsum("ij,ij->i", dq, dq)
        a12 = -np.einsum("ij,ij->i", dp, dq)
        b1 = -np.einsum("ij,ij->i", gap, dp)
        b2 = np.einsum("ij,ij->i", gap, dq)
        det = a11 * a22 - a12 * a12
        det = np.where(np.abs(det) < 1e-12 * a11 * a22, np.inf, det)
        tau[:m] += (b1 * a22 - a12 * b2) / det
        tau[m:] += (a11 * b2 - a12 * b1) / det
        tau = np.clip(tau, low, high)
    return tau[:m], tau[m:], np.linalg.norm(gap, axis=1), location
