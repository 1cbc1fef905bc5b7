"""The `fabline.parts/1` format: flat parts in their own frame, the interface from unroll to nest and export.

A contour is a closed list of vertices [x, y] or [x, y, bulge], millimetres, last vertex equal to the
first. `bulge` (default 0) is the DXF bulge of the segment from that vertex to the next: tan(angle/4)
of the arc it spans, positive counter-clockwise, so arcs stay arcs all the way to DXF and G-code.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fabline.errors import FablineError
from fabline.fileio import read_json, write_json

SCHEMA = "fabline.parts/1"
PART_KINDS = ("strip", "curved-strip", "washer", "clamp", "joint")


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
    `text` are engrave polylines, `nodes` the node positions along the strip's x axis. `grain` asks for
    the part's x axis to stay along the sheet's rolling direction (rotation 0 or 180 only).
    """

    id: str
    kind: str
    outline: np.ndarray
    lamella: str | None = None
    holes: list[np.ndarray] = field(default_factory=list)
    slots: list[Slot] = field(default_factory=list)
    marks: list[np.ndarray] = field(default_factory=list)
    text: list[np.ndarray] = field(default_factory=list)
    nodes: list[dict] = field(default_factory=list)
    label: str = ""
    grain: bool = False
    meta: dict = field(default_factory=dict)


@dataclass
class PartSet:
    """All parts of a job, with the profile and material they were made for."""

    parts: list[Part]
    profile: dict = field(default_factory=dict)
    material: str = ""
    source: str = ""
    report: dict = field(default_factory=dict)


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


def parts_to_dict(partset: PartSet) -> dict[str, Any]:
    """The JSON-ready form of a part set."""

    def rows(a: np.ndarray) -> list:
        return np.round(np.asarray(a, dtype=float), 4).tolist()

    return {
        "schema": SCHEMA,
        "units": "mm",
        "source": partset.source,
        "profile": partset.profile,
        "material": partset.material,
        "report": partset.report,
        "parts": [
            {
                "id": p.id, "kind": p.kind, "lamella": p.lamella, "label": p.label, "grain": p.grain,
                "outline": rows(p.outline), "holes": [rows(h) for h in p.holes],
                "slots": [{"node": s.node, "edge": s.edge, "outline": rows(s.outline)} for s in p.slots],
                "marks": [rows(m) for m in p.marks], "text": [rows(t) for t in p.text],
                "nodes": p.nodes, "meta": p.meta,
            }
            for p in partset.parts
        ],
    }


def parts_from_dict(data: Any, source: str = "parts") -> PartSet:
    """Build a part set from its JSON form, checking what nest and export rely on; errors name the part."""
    if not isinstance(data, dict) or data.get("schema") != SCHEMA:
        raise FablineError(f"{source}: not a {SCHEMA} file")
    if data.get("units", "mm") != "mm":
        raise FablineError(f"{source}: units must be mm, got {data.get('units')!r}")
    raw_parts = data.get("parts")
    if not isinstance(raw_parts, list) or not raw_parts:
        raise FablineError(f"{source}: no parts")
    parts, seen = [], set()
    for i, raw in enumerate(raw_parts):
        if not isinstance(raw, dict) or "id" not in raw:
            raise FablineError(f"{source}: parts[{i}] has no id")
        pid = str(raw["id"])
        where = f"{source}: part {pid}"
        if pid in seen:
            raise FablineError(f"{where}: duplicate part id")
        seen.add(pid)
        kind = raw.get("kind")
        if kind not in PART_KINDS:
            raise FablineError(f"{where}: unknown kind {kind!r} (use one of {', '.join(PART_KINDS)})")
        parts.append(Part(
            id=pid, kind=kind, lamella=raw.get("lamella"), label=str(raw.get("label", "")),
            grain=bool(raw.get("grain", False)),
            outline=_contour(raw.get("outline"), f"{where}: outline", closed=True),
            holes=[_contour(h, f"{where}: holes[{k}]", closed=True) for k, h in enumerate(raw.get("holes", []))],
            slots=[Slot(str(s.get("node", "")), _contour(s.get("outline"), f"{where}: slots[{k}]", closed=True), s.get("edge"))
                   for k, s in enumerate(raw.get("slots", []))],
            marks=[_contour(m, f"{where}: marks[{k}]") for k, m in enumerate(raw.get("marks", []))],
            text=[_contour(t, f"{where}: text[{k}]") for k, t in enumerate(raw.get("text", []))],
            nodes=list(raw.get("nodes", [])), meta=dict(raw.get("meta", {})),
        ))
    return PartSet(parts, dict(data.get("profile", {})), str(data.get("material", "")),
                   str(data.get("source", "")), dict(data.get("report", {})))


def load_parts(path: str | os.PathLike) -> PartSet:
    """Load and check a `fabline.parts/1` file."""
    return parts_from_dict(read_json(path), str(path))


def save_parts(partset: PartSet, path: str | os.PathLike) -> None:
    """Write a part set atomically."""
    write_json(path, parts_to_dict(partset), compact=True)


def _contour(raw: Any, where: str, closed: bool = False) -> np.ndarray:
    try:
        value = np.asarray(raw, dtype=float)
    except (TypeError, ValueError):
        raise FablineError(f"{where}: must be a list of [x, y] or [x, y, bulge] vertices") from None
    if value.ndim != 2 or value.shape[1] not in (2, 3) or len(value) < 2:
        raise FablineError(f"{where}: must be a list of [x, y] or [x, y, bulge] vertices")
    if not np.all(np.isfinite(value)):
        raise FablineError(f"{where}: contains NaN or infinite values")
    if closed and (len(value) < 4 or not np.allclose(value[0, :2], value[-1, :2])):
        raise FablineError(f"{where}: must be closed (at least 3 vertices, last equal to first)")
    return value
