"""The `fabline.parts/1` format: flat parts in their own frame, the interface from unroll to nest and export.

A contour is a closed list of vertices [x, y] or [x, y, bulge], millimetres, last vertex equal to the
first. `bulge` (default 0) is the DXF bulge of the segment from that vertex to the next: tan(angle/4)
of the arc it spans, positive counter-clockwise, so arcs stay arcs all the way to DXF and G-code.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fabline.errors import FablineError
from fabline.fileio import MAX_MM, read_json, write_json
from fabline.unroll.collector import collector_paused

SCHEMA = "fabline.parts/1"
PART_KINDS = ("strip", "curved-strip", "washer", "clamp", "joint", "support")
MIN_PART_MM = 0.01
"""A part's outline narrower than this (across its vertices, either way) is smaller than any kerf: it cannot be cut."""


class Polylines(Sequence):
    """Many polylines in ONE vertex array: reads as the list of (k, 2) or (k, 3) arrays it stands for.

    A large job engraves hundreds of thousands of short strokes; one array per stroke costs more to make
    (and to load) than the geometry itself. `points` holds every vertex, `starts` the row where each
    polyline begins; indexing and iteration give views into `points`, `+` gives a plain list.
    """

    __slots__ = ("points", "starts")

    def __init__(self, points: np.ndarray, starts: np.ndarray) -> None:
        self.points = points
        self.starts = np.asarray(starts, dtype=np.intp)

    @classmethod
    def of(cls, polylines: Sequence[np.ndarray]) -> "Polylines | list[np.ndarray]":
        """The polylines in one array; a plain list when their vertex widths differ (one array holds one width)."""
        if isinstance(polylines, Polylines):
            return polylines
        arrays = [np.asarray(line, dtype=float) for line in polylines]
        if not arrays:
            return cls(np.zeros((0, 2)), np.zeros(0, dtype=np.intp))
        if len({a.shape[1] for a in arrays}) > 1:
            return arrays
        counts = np.array([len(a) for a in arrays])
        return cls(np.concatenate(arrays), np.cumsum(counts) - counts)

    def bounds(self) -> list[int]:
        """Row bounds of the polylines as plain ints: polyline k is points[bounds[k]:bounds[k + 1]]."""
        return self.starts.tolist() + [len(self.points)]

    def __len__(self) -> int:
        return len(self.starts)

    def __getitem__(self, index):
        if isinstance(index, slice):
            return list(self)[index]
        k = range(len(self.starts))[index]  # negative indices and IndexError as a list has them
        end = self.starts[k + 1] if k + 1 < len(self.starts) else len(self.points)
        return self.points[self.starts[k]:end]

    def __iter__(self) -> Iterator[np.ndarray]:
        bounds = self.bounds()
        return (self.points[a:b] for a, b in zip(bounds[:-1], bounds[1:]))

    def __add__(self, other: Sequence[np.ndarray]) -> list[np.ndarray]:
        return list(self) + list(other)

    def __radd__(self, other: Sequence[np.ndarray]) -> list[np.ndarray]:
        return list(other) + list(self)

    def __repr__(self) -> str:
        return f"Polylines({len(self)} polylines, {len(self.points)} vertices)"


@dataclass
class Slot:
    """A joint slot: the node it serves and its closed outline; `edge` is "top"/"bottom" when it opens there."""

    node: str
    outline: np.ndarray
    edge: str | None = None


@dataclass
class Part:
    """One flat part to cut. `outline` is the outer contour (edge notches included); `holes` are inner contours.

    `slots` describe the joint slots (already part of the outline when open to an edge), `marks` and
    `text` are engrave polylines (a list of arrays, or the leaner `Polylines` that unroll and `load_parts`
    make), `nodes` the node positions along the strip's x axis. `grain` asks for the part's x axis to stay
    along the sheet's rolling direction (rotation 0 or 180 only).
    """

    id: str
    kind: str
    outline: np.ndarray
    lamella: str | None = None
    holes: list[np.ndarray] = field(default_factory=list)
    slots: list[Slot] = field(default_factory=list)
    marks: Sequence[np.ndarray] = field(default_factory=list)
    text: Sequence[np.ndarray] = field(default_factory=list)
    nodes: list[dict] = field(default_factory=list)
    label: str = ""
    grain: bool = False
    meta: dict = field(default_factory=dict)

    def inner_contours(self) -> list[np.ndarray]:
        """The contours cut inside the part: its holes and its closed slots (edge slots are part of the outline);
        every drawing and toolpath of the part cuts these, so the rule lives with the part."""
        return list(self.holes) + [slot.outline for slot in self.slots if slot.edge is None
                                   and not any(_same_contour(slot.outline, hole) for hole in self.holes)]


@dataclass
class PartSet:
    """All parts of a job, with the profile and material they were made for."""

    parts: list[Part]
    profile: dict = field(default_factory=dict)
    material: str = ""
    source: str = ""
    report: dict = field(default_factory=dict)
    cables: list[dict] = field(default_factory=list)  # bracing cable runs (bought, not cut): `fabline.unroll.cables`
    plates: "PartSet | None" = None  # parts cut from other plate (supports): their own material and thickness
    couplers: list[dict] = field(default_factory=list)  # shear blocks between a pair's strips: `fabline.unroll.couplers`


def _same_contour(a: np.ndarray, b: np.ndarray) -> bool:
    return a.shape == b.shape and bool(np.allclose(a, b, atol=1e-6))


def flatten_contour(contour: np.ndarray, tolerance: float = 0.05) -> np.ndarray:
    """Closed contour with bulges -> plain closed polyline (N, 2), arcs split so the sagitta stays below `tolerance`."""
    contour = np.asarray(contour, dtype=float)
    if contour.shape[1] == 2 or not np.any(contour[:, 2]):
        return contour[:, :2].copy()
    out = []
    for (x0, y0, bulge), (x1, y1) in zip(contour[:-1], contour[1:, :2]):
        out.append((x0, y0))
        if bulge == 0:
            continue
        p0, p1 = np.array([x0, y0]), np.array([x1, y1])
        chord = np.linalg.norm(p1 - p0)
        angle = 4.0 * np.arctan(bulge)
        radius = chord / (2.0 * abs(np.sin(angle / 2.0)))
        max_step = 2.0 * np.arccos(max(-1.0, 1.0 - tolerance / radius))
        steps = max(2, int(np.ceil(abs(angle) / max_step)))
        left = np.array([-(p1 - p0)[1], (p1 - p0)[0]]) / chord
        centre = (p0 + p1) / 2.0 + left * chord / (2.0 * np.tan(angle / 2.0))
        start = np.arctan2(y0 - centre[1], x0 - centre[0])
        for k in range(1, steps):
            a = start + angle * k / steps
            out.append((centre[0] + radius * np.cos(a), centre[1] + radius * np.sin(a)))
    out.append(tuple(contour[-1, :2]))
    return np.array(out)


def parts_to_dict(partset: PartSet, arrays: bool = False) -> dict[str, Any]:
    """The JSON-ready form of a part set; every vertex rounded to 1e-4 mm.

    All vertex arrays of all parts are rounded in one call per vertex width (`_rounded_rows`), not one per
    contour: a large job has hundreds of thousands of them. Rows are lists, or with `arrays` views into the
    rounded table, which orjson writes directly (`save_parts`): the same text without 10 million small lists.
    """
    rows = iter(_rounded_rows([array for part in partset.parts for array in _vertex_arrays(part)], arrays))
    return {
        "schema": SCHEMA,
        "units": "mm",
        "source": partset.source,
        "profile": partset.profile,
        "material": partset.material,
        "report": partset.report,
        "cables": partset.cables,
        "couplers": partset.couplers,
        **({"plates": {"material": partset.plates.material, "profile": partset.plates.profile,
                       "parts": parts_to_dict(partset.plates, arrays)["parts"]}} if partset.plates else {}),
        "parts": [
            {
                "id": p.id, "kind": p.kind, "lamella": p.lamella, "label": p.label, "grain": p.grain,
                "outline": next(rows), "holes": [next(rows) for _ in p.holes],
                "slots": [{"node": s.node, "edge": s.edge, "outline": next(rows)} for s in p.slots],
                "marks": _polyline_rows(p.marks, rows), "text": _polyline_rows(p.text, rows),
                "nodes": p.nodes, "meta": p.meta,
            }
            for p in partset.parts
        ],
    }


def _vertex_arrays(part: Part) -> Iterator[np.ndarray]:
    """A part's vertex arrays in the order `parts_to_dict` takes their rows: outline, holes, slot outlines, then
    marks and text (a `Polylines` as its one array, other polylines one array each)."""
    yield part.outline
    yield from part.holes
    for slot in part.slots:
        yield slot.outline
    for polylines in (part.marks, part.text):
        if isinstance(polylines, Polylines):
            yield polylines.points
        else:
            yield from polylines


def _rounded_rows(arrays: list[np.ndarray], as_arrays: bool) -> list:
    """Each array rounded to 1e-4 mm, as JSON rows (or row views), made in one piece per vertex width and cut apart."""
    arrays = [np.asarray(a, dtype=float) for a in arrays]
    out: list = [None] * len(arrays)
    for width in {a.shape[1] for a in arrays}:
        which = [k for k, a in enumerate(arrays) if a.shape[1] == width]
        table = np.round(np.concatenate([arrays[k] for k in which]), 4)
        if not np.all(np.isfinite(table)):
            raise ValueError("parts contain NaN or infinite coordinates")
        rows = table if as_arrays else table.tolist()
        ends = np.cumsum([len(arrays[k]) for k in which]).tolist()
        for k, a, b in zip(which, [0] + ends, ends):
            out[k] = rows[a:b]
    return out


def _polyline_rows(polylines: Sequence[np.ndarray], rows: Iterator) -> list:
    """Engrave polylines as JSON rows, taken from `rows`: a `Polylines` cut from its one array's rows."""
    if not isinstance(polylines, Polylines):
        return [next(rows) for _ in polylines]
    points, bounds = next(rows), polylines.bounds()
    return [points[a:b] for a, b in zip(bounds[:-1], bounds[1:])]


def parts_from_dict(data: Any, source: str = "parts") -> PartSet:
    """Build a part set from its JSON form, checking what nest and export rely on; errors name the part.

    All contours of the file become arrays in one conversion per vertex width (`_ContourPool`); parts get
    views into them, engrave polylines as `Polylines`. Only when that bulk check fails are the contours
    converted one by one, to name the first bad one.
    """
    if not isinstance(data, dict) or data.get("schema") != SCHEMA:
        raise FablineError(f"{source}: not a {SCHEMA} file")
    if data.get("units", "mm") != "mm":
        raise FablineError(f"{source}: units must be mm, got {data.get('units')!r}")
    raw_parts = data.get("parts")
    if not isinstance(raw_parts, list) or not raw_parts:
        raise FablineError(f"{source}: no parts")
    pool, seen, entries = _ContourPool(), set(), []
    for i, raw in enumerate(raw_parts):
        if not isinstance(raw, dict) or not isinstance(raw.get("id"), (str, int)) or isinstance(raw.get("id"), bool):
            raise FablineError(f"{source}: parts[{i}] has no id (a string)")
        pid = str(raw["id"])
        where = f"{source}: part {pid}"
        if pid in seen:
            raise FablineError(f"{where}: duplicate part id")
        seen.add(pid)
        kind = raw.get("kind")
        if not isinstance(raw.get("grain", False), bool):
            raise FablineError(f"{where}: grain must be true or false")
        if kind not in PART_KINDS:
            raise FablineError(f"{where}: unknown kind {kind!r} (use one of {', '.join(PART_KINDS)})")
        slots = _field_list(raw, "slots", where)
        bad_slot = next((k for k, slot in enumerate(slots) if not isinstance(slot, dict)), None)
        if bad_slot is not None:
            raise FablineError(f"{where}: slots[{bad_slot}] must be an object with node, edge and outline")
        entries.append((raw, pid, kind, slots, pool.add([raw.get("outline")], closed=True),
                        pool.add(_field_list(raw, "holes", where), closed=True),
                        pool.add([slot.get("outline") for slot in slots], closed=True),
                        pool.add(_field_list(raw, "marks", where), closed=False),
                        pool.add(_field_list(raw, "text", where), closed=False)))
    if not pool.convert():
        _diagnose(raw_parts, source)
    parts = []
    for raw, pid, kind, slots, outline, holes, slot_outlines, marks, text in entries:
        parts.append(Part(
            id=pid, kind=kind, lamella=raw.get("lamella"), label=str(raw.get("label", "")),
            grain=bool(raw.get("grain", False)), outline=pool.contours(outline)[0], holes=pool.contours(holes),
            slots=[Slot(str(s.get("node", "")), contour, s.get("edge"))
                   for s, contour in zip(slots, pool.contours(slot_outlines))],
            marks=pool.polylines(marks), text=pool.polylines(text),
            nodes=_field_list(raw, "nodes", where), meta=_field(raw, "meta", dict, where),
        ))
    plates = _field(data, "plates", dict, source)
    return PartSet(parts, _field(data, "profile", dict, source), str(data.get("material", "")),
                   str(data.get("source", "")), _field(data, "report", dict, source), _field(data, "cables", list, source),
                   parts_from_dict({**plates, "schema": SCHEMA}, f"{source}: plates") if plates else None,
                   _field(data, "couplers", list, source))


class _ContourPool:
    """The contours of a whole parts file, converted to arrays together: one array per vertex width (2 or 3).

    `add` files raw contours (JSON lists) and returns their references; `convert` makes the arrays and runs
    `_contour`'s checks on all of them at once; then `contours` and `polylines` hand out views.
    """

    def __init__(self) -> None:
        self.raw: dict[int, list] = {}
        self.closed: dict[int, list[bool]] = {}
        self.points: dict[int, np.ndarray] = {}
        self.bounds: dict[int, list[int]] = {}
        self.malformed = False

    def add(self, contours: Any, closed: bool) -> list[tuple[int, int]]:
        """File a field's contours; their (width, index) references, or none once something is malformed."""
        refs = []
        try:
            for contour in contours:
                width = len(contour[0])
                group = self.raw.setdefault(width, [])
                refs.append((width, len(group)))
                group.append(contour)
                self.closed.setdefault(width, []).append(closed)
        except (TypeError, IndexError, KeyError):
            self.malformed = True
        return refs

    def convert(self) -> bool:
        """Convert every width's contours in one call and check them all; False when any is malformed."""
        if self.malformed or not set(self.raw) <= {2, 3}:
            return False
        for width, group in self.raw.items():
            counts = np.array([len(contour) for contour in group])
            try:
                points = np.array([vertex for contour in group for vertex in contour], dtype=float)
            except (TypeError, ValueError):
                return False
            closed = np.array(self.closed[width])
            if (points.ndim != 2 or points.shape[1] != width or counts.min() < 2 or not np.all(np.isfinite(points))
                    or np.abs(points[:, :2]).max() > MAX_MM
                    or np.any(closed & (counts < 4))):
                return False
            first = np.cumsum(counts) - counts
            last = first + counts - 1
            if not np.all(np.isclose(points[first[closed], :2], points[last[closed], :2])):  # as np.allclose
                return False
            self.points[width], self.bounds[width] = points, first.tolist() + [len(points)]
        return True

    def contours(self, refs: list[tuple[int, int]]) -> list[np.ndarray]:
        """The arrays of the referenced contours (views)."""
        return [self.points[w][self.bounds[w][k]:self.bounds[w][k + 1]] for w, k in refs]

    def polylines(self, refs: list[tuple[int, int]]) -> Polylines | list[np.ndarray]:
        """The referenced polylines (one field of one part, filed together) as `Polylines`; a list if widths differ."""
        if not refs:
            return Polylines(np.zeros((0, 2)), np.zeros(0, dtype=np.intp))
        width = refs[0][0]
        if any(w != width for w, _ in refs):
            return self.contours(refs)
        bounds = self.bounds[width][refs[0][1]:refs[-1][1] + 2]
        return Polylines(self.points[width][bounds[0]:bounds[-1]], np.array(bounds[:-1]) - bounds[0])


def _diagnose(raw_parts: list, source: str) -> None:
    """Check the contours one by one, in file order, and raise for the first malformed one, naming it."""
    for raw in raw_parts:
        where = f"{source}: part {raw['id']}"
        _contour(raw.get("outline"), f"{where}: outline", closed=True)
        for k, hole in enumerate(raw.get("holes", [])):
            _contour(hole, f"{where}: holes[{k}]", closed=True)
        for k, slot in enumerate(raw.get("slots", [])):
            _contour(slot.get("outline"), f"{where}: slots[{k}]", closed=True)
        for name in ("marks", "text"):
            for k, line in enumerate(raw.get(name, [])):
                _contour(line, f"{where}: {name}[{k}]")
    raise FablineError(f"{source}: malformed contours")  # not reached: the checks above are the pool's, one by one


def _field_list(raw: dict, name: str, where: str) -> list:
    """A part's list field (holes, slots, marks, text, nodes), empty when absent; anything but a list is an error."""
    return _field(raw, name, list, where)


def _field(raw: dict, name: str, kind: type, where: str) -> Any:
    """A list or object field (`kind`), empty when absent; anything else is an error naming it."""
    value = raw.get(name, kind())
    if not isinstance(value, kind):
        raise FablineError(f"{where}: {name} must be {'a list' if kind is list else 'an object'}, got {value!r:.40}")
    return value


def load_parts(path: str | os.PathLike) -> PartSet:
    """Load and check a `fabline.parts/1` file (the collector paused: the JSON alone is millions of lists)."""
    with collector_paused():
        return parts_from_dict(read_json(path), str(path))


def check_cuttable(partset: PartSet, source: str) -> None:
    """Refuse (FablineError naming the part) a part whose outline is under MIN_PART_MM wide or high: nothing can
    cut it, and nesting it ends in placements no validation accepts."""
    for part in partset.parts:
        width, height = np.ptp(part.outline[:, :2], axis=0)
        if min(width, height) < MIN_PART_MM:
            raise FablineError(f"{source}: part {part.id}: its outline is {width:.3g} x {height:.3g} mm, under "
                               f"{MIN_PART_MM:g} mm across: too small to cut; fix or remove the part")


def save_parts(partset: PartSet, path: str | os.PathLike) -> None:
    """Write a part set atomically (the collector paused, as for loading)."""
    with collector_paused():
        write_json(path, parts_to_dict(partset, arrays=True), compact=True)


def _contour(raw: Any, where: str, closed: bool = False) -> np.ndarray:
    """One contour from JSON, checked: 2 or 3 finite columns, at least 2 vertices (closed: 4, last = first)."""
    try:
        value = np.asarray(raw, dtype=float)
    except (TypeError, ValueError):
        raise FablineError(f"{where}: must be a list of [x, y] or [x, y, bulge] vertices") from None
    if value.ndim != 2 or value.shape[1] not in (2, 3) or len(value) < 2:
        raise FablineError(f"{where}: must be a list of [x, y] or [x, y, bulge] vertices")
    if not np.all(np.isfinite(value)):
        raise FablineError(f"{where}: contains NaN or infinite values")
    if np.abs(value[:, :2]).max() > MAX_MM:
        raise FablineError(f"{where}: a vertex lies more than {MAX_MM / 1e6:g} km from the part's origin")
    if closed and (len(value) < 4 or not np.allclose(value[0, :2], value[-1, :2])):
        raise FablineError(f"{where}: must be closed (at least 3 vertices, last equal to first)")
    return value
