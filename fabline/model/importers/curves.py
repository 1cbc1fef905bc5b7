"""What every CAD reader hands to the network builder: named, family-tagged polylines, units, a surface.

Also holds the rules shared by the readers: how a layer, group or object name names a family and a
lamella id, how units are settled between the file, the command line and the surface file, and how a
raw polyline is cleaned and checked before crossings are sought.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np
import trimesh

from fabline.errors import FablineError

# "A", "B", "A-017", "B_3", "a12", "FAMILY-A", "Family B", "family_a-7": a family letter, optionally
# after "FAMILY" and a separator, and not followed by another letter ("Arches" names no family).
FAMILY_NAME = re.compile(r"^\s*(?:family[\s_-]*)?([ab])(?![a-z])(.*)$", re.IGNORECASE)

SAGITTA_MM = 0.01
"""Largest distance between a curved CAD entity (spline, arc) and the polyline fabline makes of it."""
MAX_FLATTENED_POINTS = 1_000_000
"""Points an arc, circle, ellipse or bulged polyline may flatten to (a 12 m lamella at 0.01 mm takes about 300)."""
MAX_CURVE_POINTS = 100_000
"""Points one curve may have (a 12 m lamella sampled every 0.12 mm; the crossing search pairs each point with its
neighbours within the tolerance, so a denser curve asks for memory as points times density)."""


@dataclass
class RawCurve:
    """One lamella's centreline as read from a CAD file, before nodes are found."""

    id: str
    family: str
    points: np.ndarray
    where: str
    """Where the curve came from in its file ("line 12", "entity #2F"), for error messages."""


@dataclass
class NamedPoint:
    """A point object of a CAD file (OBJ `p`, DXF POINT) with its names (group, object / layer, XDATA values)."""

    names: list[str]
    xyz: np.ndarray
    where: str


@dataclass
class CurveSource:
    """The curves of one CAD file, the units it declares (None if it declares none), any surface in it, and its
    point objects (named nodes, support markers)."""

    path: str
    curves: list[RawCurve]
    declared_units: str | None
    mesh: trimesh.Trimesh | None = None
    notes: list[str] = field(default_factory=list)
    points: list[NamedPoint] = field(default_factory=list)


def family_and_id(names: list[str]) -> tuple[str | None, str | None]:
    """The family and lamella id named by a curve's names, most specific name first.

    The family is that of the first name that names one; the id is the first such name that says more
    than the family alone ("A-017" is an id, "A" and "FAMILY-A" are not). Nested layer paths
    ("Lamellas::A") are read by their last part.
    """
    family = lamella_id = None
    for name in names:
        name = name.split("::")[-1].strip()
        match = FAMILY_NAME.match(name)
        if not match:
            continue
        family = family or match.group(1).upper()
        if lamella_id is None and match.group(1).upper() == family and match.group(2).strip(" _-"):
            lamella_id = name
    return family, lamella_id


def assign_ids(curves: list[tuple[str, str | None, np.ndarray, str]], path: str) -> list[RawCurve]:
    """Turn (family, id or None, points, where) into RawCurves, numbering the unnamed ones per family.

    Generated ids ("A-001", ...) skip ids the file already uses; a name used twice is an error.
    """
    used: dict[str, str] = {}
    for family, lamella_id, _, where in curves:
        if lamella_id is None:
            continue
        if lamella_id in used:
            raise FablineError(f"{path}: duplicate lamella id {lamella_id} ({used[lamella_id]} and {where})")
        used[lamella_id] = where
    counters = {"A": 0, "B": 0}
    result = []
    for family, lamella_id, points, where in curves:
        if lamella_id is None:
            while True:
                counters[family] += 1
                lamella_id = f"{family}-{counters[family]:03d}"
                if lamella_id not in used:
                    break
            used[lamella_id] = where
        result.append(RawCurve(lamella_id, family, points, where))
    return result


def arc_points(radius: np.ndarray, angle: np.ndarray, sagitta: float) -> float:
    """How many points arcs of `radius` spanning `angle` (radians) flatten to within `sagitta`: each chord spans
    2 acos(1 - sagitta / radius), written as 4 asin(sqrt(sagitta / 2 radius)) so that a huge radius stays finite."""
    radius, angle = np.abs(np.asarray(radius, dtype=float)), np.abs(np.asarray(angle, dtype=float))
    with np.errstate(divide="ignore", invalid="ignore"):
        step = 4.0 * np.arcsin(np.sqrt(np.minimum(sagitta / (2.0 * radius), 0.5)))
        return float(np.sum(np.where(angle > 0, np.ceil(angle / step), 0.0))) + 1.0


def check_flattening(entity, sagitta: float, path: str, where: str) -> None:
    """Refuse, before ezdxf flattens it, an ARC, CIRCLE, ELLIPSE or bulged polyline that would make more than
    MAX_FLATTENED_POINTS points within `sagitta` (model units), or whose size is not a finite number."""
    kind = entity.dxftype()
    if kind in ("ARC", "CIRCLE"):
        span = 2 * np.pi if kind == "CIRCLE" else np.radians((entity.dxf.end_angle - entity.dxf.start_angle) % 360 or 360)
        radius, angle = [entity.dxf.radius], [span]
    elif kind == "ELLIPSE":
        span = (entity.dxf.end_param - entity.dxf.start_param) % (2 * np.pi) or 2 * np.pi
        radius, angle = [np.linalg.norm(tuple(entity.dxf.major_axis)) / max(entity.dxf.ratio, 1e-12)], [span]
    elif kind == "LWPOLYLINE":
        rows = np.asarray(entity.get_points("xyb"), dtype=float).reshape(-1, 3)
        ends = np.vstack([rows[1:, :2], rows[:1, :2]]) if entity.closed else rows[1:, :2]
        bulge = rows[:len(ends), 2]
        chord = np.linalg.norm(ends - rows[:len(ends), :2], axis=1)
        angle = 4.0 * np.arctan(bulge)
        with np.errstate(divide="ignore", invalid="ignore"):
            radius = np.where(bulge != 0, chord / (2.0 * np.abs(np.sin(angle / 2.0))), 0.0)
    else:
        return
    count = arc_points(radius, angle, sagitta)
    if not np.isfinite(count) or not np.all(np.isfinite(radius)) or count > MAX_FLATTENED_POINTS:
        raise FablineError(f"{path}: {where}: radius {np.max(radius):.3g} would flatten to about {count:.2g} points "
                           f"within {sagitta:g}; the limit is {MAX_FLATTENED_POINTS:.0e} points a curve: redraw it "
                           "smaller or as a polyline")


def clean_points(points: np.ndarray, path: str, where: str) -> np.ndarray:
    """Check a polyline for NaN, infinities and zero length, and drop repeated consecutive points."""
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    if len(points) > MAX_CURVE_POINTS:
        raise FablineError(f"{path}: {where}: {len(points)} points; the limit is {MAX_CURVE_POINTS} a curve: "
                           "resample it coarser")
    bad = np.flatnonzero(~np.isfinite(points).all(axis=1))
    if bad.size:
        raise FablineError(f"{path}: {where}: point {bad[0]} contains NaN or infinite values")
    if len(points) < 2:
        raise FablineError(f"{path}: {where}: a curve needs at least two points")
    keep = np.r_[True, np.any(np.diff(points, axis=0) != 0, axis=1)]
    points = points[keep]
    if len(points) < 2:
        raise FablineError(f"{path}: {where}: curve has zero length")
    return points


def settle_units(source: CurveSource, requested: str | None) -> str:
    """The model's units: what the file declares, else `--units`, else metres with a note.

    A file that declares units other than the requested ones is a mixed-units error.
    """
    declared = source.declared_units  # `requested` is a known unit: import_model checked it
    if declared is not None:
        if requested is not None and requested != declared:
            raise FablineError(f"mixed units: {source.path} declares {declared} but --units {requested} was given")
        return declared
    if requested is not None:
        return requested
    source.notes.append(f"{source.path} declares no units; assumed m (give --units to choose)")
    return "m"


def check_surface_units(source: CurveSource, units: str, surface_path: str, surface_units: str | None,
                        mesh: trimesh.Trimesh) -> None:
    """Refuse a surface that declares other units than the curves, or whose size is 10x off theirs."""
    if surface_units is not None and surface_units != units:
        raise FablineError(f"mixed units: {source.path} is in {units} but {surface_path} is in {surface_units}")
    if not source.curves:
        return  # no curves: the network builder names that
    points = np.concatenate([c.points for c in source.curves])
    curve_size = float(np.linalg.norm(np.ptp(points, axis=0)))
    surface_size = float(np.linalg.norm(np.ptp(mesh.vertices, axis=0))) if len(mesh.vertices) else 0.0
    if curve_size == 0 or surface_size == 0:
        return
    ratio = surface_size / curve_size
    if ratio >= 10 or ratio <= 0.1:
        raise FablineError(
            f"mixed units: {surface_path} is {ratio:.3g} times the size of the curves in {source.path} "
            f"({surface_size:.4g} vs {curve_size:.4g}); are both in {units}?")


PLAUSIBLE_SPAN_M = (0.1, 300.0)
"""The largest side of a gridshell's bounding box, metres: from table-top models to the largest strained
gridshells (Mannheim: 80 m). A file without units whose curves fall outside is refused without --units."""


def check_extent(source: CurveSource, units: str, assumed: bool) -> None:
    """Refuse curves whose size is implausible for a gridshell in the units assumed for a file that declares none,
    naming the units that would make it plausible; declared or given units are trusted, with a note."""
    from fabline.model.network import UNIT_TO_MM

    if not source.curves:
        return  # nothing to measure: the network builder says the file has no curves
    points = np.concatenate([c.points for c in source.curves])
    span = float(np.ptp(points, axis=0).max())
    metres = span * UNIT_TO_MM[units] / 1000.0
    low, high = PLAUSIBLE_SPAN_M
    if low <= metres <= high:
        return
    if not assumed:
        source.notes.append(f"the curves span {metres:.4g} m in {units}; unusual for a gridshell "
                            f"({low:g} to {high:g} m): check the units")
        return
    fits = [name for name, mm in UNIT_TO_MM.items() if low <= span * mm / 1000.0 <= high]
    hint = (" (" + ", ".join(f"--units {u} makes it {span * UNIT_TO_MM[u] / 1000.0:.4g} m" for u in fits) + ")"
            if fits else "")
    raise FablineError(f"{source.path}: declares no units, and in {units} its curves would span {metres:.4g} m, "
                       f"implausible for a gridshell ({low:g} to {high:g} m): give --units{hint}")
