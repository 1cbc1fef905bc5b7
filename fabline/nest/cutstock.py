"""One-dimensional cutting stock for straight strips: lengths packed into rows of a fixed length.

First-fit decreasing gives a floor; column generation on the LP relaxation (scipy's HiGHS for the
master, a bounded-knapsack dynamic programme for pricing) gives the LP lower bound, and a
time-limited integer programme over the generated patterns (HiGHS again) usually closes the gap.
The best of these packings is returned together with the bound.
"""

from __future__ import annotations

import bisect
import math
import time
from dataclasses import dataclass

import numpy as np
from scipy.optimize import Bounds, LinearConstraint, linprog, milp

# Knapsack resolution: lengths are rounded up and the capacity down to this grid (mm), so every
# pattern the DP finds is feasible in exact lengths too.
DP_RESOLUTION = 1.0


@dataclass
class RowPacking:
    """Rows of item indices, the LP lower bound on the number of rows, and which method won."""

    rows: list[list[int]]
    lower_bound: int
    lp_value: float
    method: str


def first_fit_decreasing(sizes: np.ndarray, capacity: float) -> list[list[int]]:
    """Plain first-fit decreasing: each item, longest first, into the first row with room."""
    order = np.argsort(-np.asarray(sizes, dtype=float), kind="stable")
    remaining = np.empty(len(sizes))
    rows: list[list[int]] = []
    for item in order:
        room = remaining[:len(rows)] >= sizes[item] - 1e-9
        if room.any():
            row = int(np.argmax(room))
        else:
            row = len(rows)
            rows.append([])
            remaining[row] = capacity
        rows[row].append(int(item))
        remaining[row] -= sizes[item]
    return rows


def pack_rows(sizes: np.ndarray, capacity: float, time_limit: float = 10.0) -> RowPacking:
    """Pack items of `sizes` into as few rows of `capacity` as possible; also return the LP lower bound on rows."""
    sizes = np.asarray(sizes, dtype=float)
    if len(sizes) == 0:
        return RowPacking([], 0, 0.0, "empty")
    deadline = time.monotonic() + time_limit
    ffd, generator, lp_value, bound = _relaxation(sizes, capacity, time_limit)
    if generator is None:
        return RowPacking(ffd, bound, lp_value, "first-fit decreasing")
    # Column generation used up to 40 % of the time; the integer programme over its patterns may use the
    # next 30 %, and diving (fix a pattern, re-price the rest) what is left.
    best, method = ffd, "first-fit decreasing"
    heuristics = ((generator.residual_rounding, "column generation + rounding"),
                  (lambda: generator.integer_solution(time.monotonic() + 0.3 * time_limit), "column generation + HiGHS MIP"),
                  (lambda: generator.dive(deadline), "column generation + diving"))
    for heuristic, name in heuristics:
        if len(best) == bound:
            break
        candidate = heuristic()
        if candidate is not None and len(candidate) < len(best):
            best, method = candidate, name
    return RowPacking(best, bound, lp_value, method)


def row_lower_bound(sizes: np.ndarray, capacity: float, time_limit: float = 10.0) -> int:
    """The LP lower bound on the rows `pack_rows` needs, without the packing heuristics that follow it."""
    sizes = np.asarray(sizes, dtype=float)
    return _relaxation(sizes, capacity, time_limit)[3] if len(sizes) else 0


def _relaxation(sizes: np.ndarray, capacity: float,
                time_limit: float) -> tuple[list[list[int]], "_ColumnGeneration | None", float, int]:
    """First-fit decreasing, then, unless it meets the area bound, column generation over its patterns (in 40 %
    of `time_limit`): FFD's rows, the generator (None when FFD is optimal), the LP value and the lower bound."""
    if sizes.max() > capacity + 1e-9:
        raise ValueError("an item is longer than the row")
    ffd = first_fit_decreasing(sizes, capacity)
    area_bound = math.ceil(sizes.sum() / capacity - 1e-9)
    if len(ffd) == area_bound:
        return ffd, None, float(sizes.sum() / capacity), area_bound
    generator = _ColumnGeneration(sizes, capacity)
    for row in ffd:
        generator.add_pattern_of(row)
    lp_value, bound = generator.solve(time.monotonic() + 0.4 * time_limit)
    return ffd, generator, lp_value, max(bound, area_bound)


class _ColumnGeneration:
    """Gilmore-Gomory column generation over the distinct item sizes."""

    def __init__(self, sizes: np.ndarray, capacity: float):
        self.sizes = sizes
        self.capacity = capacity
        rounded = np.round(sizes, 3)
        self.distinct, self.item_type, self.demand = np.unique(rounded, return_inverse=True, return_counts=True)
        # Exact feasibility uses the largest real size of each type.
        self.type_size = np.zeros(len(self.distinct))
        np.maximum.at(self.type_size, self.item_type, sizes)
        self.weights = np.ceil(self.type_size / DP_RESOLUTION - 1e-9).astype(int)
        self.cap_units = int(math.floor(capacity / DP_RESOLUTION + 1e-9))
        self.patterns: list[np.ndarray] = []
        self.seen: set[bytes] = set()
        self.x = np.zeros(0)
        self.duals = np.zeros(len(self.distinct))
        for t in range(len(self.distinct)):
            single = np.zeros(len(self.distinct), dtype=int)
            single[t] = min(self.demand[t], int(capacity // self.type_size[t]))
            self._add(single)

    def _add(self, pattern: np.ndarray) -> bool:
        key = pattern.tobytes()
        if key in self.seen or not pattern.any():
            return False
        self.seen.add(key)
        self.patterns.append(pattern)
        return True

    def add_pattern_of(self, row: list[int]) -> None:
        """Add the pattern of a row found by another method (it is feasible by construction)."""
        self._add(np.bincount(self.item_type[row], minlength=len(self.distinct)).astype(int))

    def _matrix(self) -> tuple[np.ndarray, np.ndarray]:
        """Pattern columns (cost 1) followed by the exchange columns (cost 0).

        Exchange column k lets a slot of type k+1 hold an item of the smaller type k; it is the primal
        side of the dual-optimal inequalities y[k+1] >= y[k] (Ben Amor, Desrosiers and Valerio de
        Carvalho 2006), which removes the dual degeneracy that makes plain column generation tail off.
        """
        types = len(self.distinct)
        exchange = np.zeros((types, max(types - 1, 0)))
        exchange[np.arange(types - 1), np.arange(types - 1)] = 1.0
        exchange[np.arange(1, types), np.arange(types - 1)] = -1.0
        matrix = np.hstack([np.array(self.patterns, dtype=float).T, exchange])
        cost = np.concatenate([np.ones(len(self.patterns)), np.zeros(types - 1)])
        return matrix, cost

    def _master(self) -> tuple[float, np.ndarray, np.ndarray]:
        matrix, cost = self._matrix()
        result = linprog(cost, A_ub=-matrix, b_ub=-self.demand.astype(float), bounds=(0, None), method="highs")
        if result.status != 0:
            raise RuntimeError(f"cutting-stock LP failed: {result.message}")
        return float(result.fun), result.x[:len(self.patterns)], -result.ineqlin.marginals

    def solve(self, deadline: float) -> tuple[float, int]:
        """Generate columns until no pattern prices out or time runs out; return the LP value and the row bound."""
        best_bound = 0.0
        value = math.inf
        while True:
            value, self.x, self.duals = self._master()
            pattern, price = self._price(self.duals)
            # Farley's bound: valid at every iteration, equal to the LP optimum at convergence. Once its
            # ceiling meets the LP value's, more columns cannot raise the integer bound: stop there.
            best_bound = max(best_bound, float(self.duals @ self.demand) / max(price, 1.0))
            converged = price <= 1.0 + 1e-9 or math.ceil(best_bound - 1e-6) >= math.ceil(value - 1e-6)
            if converged or time.monotonic() > deadline or not self._add(pattern):
                break
        return value, math.ceil(best_bound - 1e-6)

    def _price(self, duals: np.ndarray) -> tuple[np.ndarray, float]:
        """Bounded knapsack (binary splitting of copies) maximising the dual value of one row."""
        chunks_type, chunks_count = [], []
        for t in np.flatnonzero(duals > 1e-12):
            copies = min(int(self.demand[t]), self.cap_units // self.weights[t])
            step = 1
            while copies > 0:
                take = min(step, copies)
                chunks_type.append(t)
                chunks_count.append(take)
                copies -= take
                step *= 2
        best = np.zeros(self.cap_units + 1)
        taken = np.zeros((len(chunks_type), self.cap_units + 1), dtype=bool)
        for k, (t, count) in enumerate(zip(chunks_type, chunks_count)):
            w = int(self.weights[t]) * count
            if w > self.cap_units:
                continue
            candidate = best[:-w] + duals[t] * count
            better = candidate > best[w:] + 1e-12
            taken[k, w:] = better
            best[w:] = np.where(better, candidate, best[w:])
        pattern = np.zeros(len(self.distinct), dtype=int)
        cap = int(np.argmax(best))
        value = float(best[cap])
        for k in range(len(chunks_type) - 1, -1, -1):
            if taken[k, cap]:
                t, count = chunks_type[k], chunks_count[k]
                pattern[t] += count
                cap -= int(self.weights[t]) * count
        if pattern @ self.type_size > self.capacity + 1e-9:
            raise RuntimeError("knapsack produced an infeasible pattern")
        return pattern, value

    def _rows_from(self, counts: np.ndarray) -> list[list[int]]:
        """Integer pattern counts -> rows of item indices; the rest by FFD.

        Each slot of a pattern takes the longest remaining item that fits it (its own type first, else a
        shorter one, as the exchange columns allow); slots left empty are dropped.
        """
        order = list(np.argsort(self.sizes, kind="stable"))
        sorted_sizes = list(self.sizes[order])
        rows = []
        for pattern, count in zip(self.patterns, counts):
            for _ in range(int(round(count))):
                row = []
                for t in np.flatnonzero(pattern)[::-1]:
                    for _ in range(pattern[t]):
                        k = bisect.bisect_right(sorted_sizes, self.type_size[t] + 1e-9) - 1
                        if k >= 0:
                            row.append(int(order.pop(k)))
                            sorted_sizes.pop(k)
                if row:
                    rows.append(row)
        if order:
            rows += [[order[i] for i in r] for r in first_fit_decreasing(np.array(sorted_sizes), self.capacity)]
        return rows

    def residual_rounding(self) -> list[list[int]]:
        """Round the LP solution down and pack what is left by first-fit decreasing."""
        return self._rows_from(np.floor(self.x + 1e-9))

    def dive(self, deadline: float) -> list[list[int]]:
        """Diving: fix the LP's integral patterns (or its largest fractional one, rounded up), re-run column
        generation on the demand left, and repeat until all is fixed or time is up (then FFD finishes)."""
        demand, counts = self.demand.copy(), np.zeros(0)
        while demand.any() and time.monotonic() < deadline:
            self.demand = demand
            self.solve(deadline)
            fixed = np.zeros(len(self.patterns))
            fixed[:len(self.x)] = np.floor(self.x + 1e-6)
            if not fixed.any():
                fixed[int(np.argmax(self.x))] = 1.0
            counts = np.concatenate([counts, np.zeros(len(self.patterns) - len(counts))]) + fixed
            demand = np.maximum(0, demand - np.array(self.patterns).T @ fixed.astype(int))
        self.demand = np.bincount(self.item_type, minlength=len(self.distinct))
        return self._rows_from(counts)

    def integer_solution(self, deadline: float) -> list[list[int]] | None:
        """Best integer combination of the generated patterns within the remaining time (HiGHS MIP)."""
        remaining = deadline - time.monotonic()
        if remaining <= 0.2:
            return None
        matrix, cost = self._matrix()
        result = milp(cost, integrality=np.ones(matrix.shape[1]),
                      constraints=LinearConstraint(matrix, lb=self.demand.astype(float)),
                      bounds=Bounds(0, np.inf), options={"time_limit": remaining, "disp": False})
        if result.x is None:
            return None
        return self._rows_from(np.round(result.x[:len(self.patterns)]))
