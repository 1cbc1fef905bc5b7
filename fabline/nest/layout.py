"""The `fabline.nesting/1` format: which part lies where on which sheet; the interface from nest to export.

A placed contour is the part's contour rotated by `rotation` degrees (counter-clockwise) about the
part's own origin, then translated by (x, y), in sheet millimetres with the origin at a sheet corner.
`parts_file` names the parts.json the placements refer to, relative to the nesting file's folder.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fabline.errors import FablineError
from fabline.fileio import MAX_MM, finite_number, read_json, write_json
from fabline.naming import file_stem

SCHEMA = "fabline.nesting/1"


@dataclass
class Placement:
    """One part on a sheet."""

    part: str
    x: float
    y: float
    rotation: float = 0.0


@dataclass
class CommonCut:
    """A straight edge shared by two neighbouring parts (common-line cutting): cut once, in sheet coordinates."""

    parts: tuple[str, str]
    start: tuple[float, float]
    end: tuple[float, float]


@dataclass
class Sheet:
    """One sheet with its placements; `stock` names the stock item it was cut from."""

    id: str
    width: float
    height: float
    placements: list[Placement] = field(default_factory=list)
    stock: str = ""
    common_cuts: list[CommonCut] = field(default_factory=list)


@dataclass
class Nesting:
    """A complete nesting: the sheets, the parts file they refer to, and the settings that produced them."""

    sheets: list[Sheet]
    parts_file: str
    kerf: float = 0.0
    gap: float = 0.0
    margin: float = 0.0
    summary: dict = field(default_factory=dict)
    remnants: list[dict] = field(default_factory=list)


def place(points: np.ndarray, placement: Placement) -> np.ndarray:
    """Part-frame points (N, 2+) -> sheet coordinates (N, 2); extra columns such as bulges are kept."""
    points = np.asarray(points, dtype=float)
    a = np.radians(placement.rotation)
    c, s = np.cos(a), np.sin(a)
    out = points.copy()
    out[:, 0] = c * points[:, 0] - s * points[:, 1] + placement.x
    out[:, 1] = s * points[:, 0] + c * points[:, 1] + placement.y
    return out


def nesting_to_dict(nesting: Nesting) -> dict[str, Any]:
    """The JSON-ready form of a nesting."""
    return {
        "schema": SCHEMA,
        "units": "mm",
        "parts_file": nesting.parts_file,
        "kerf": nesting.kerf,
        "gap": nesting.gap,
        "margin": nesting.margin,
        "summary": nesting.summary,
        "remnants": nesting.remnants,
        "sheets": [
            {
                "id": s.id, "width": s.width, "height": s.height, "stock": s.stock,
                "placements": [{"part": p.part, "x": round(p.x, 4), "y": round(p.y, 4), "rotation": p.rotation}
                               for p in s.placements],
                "common_cuts": [{"parts": list(c.parts), "start": list(c.start), "end": list(c.end)}
                                for c in s.common_cuts],
            }
            for s in nesting.sheets
        ],
    }


def nesting_from_dict(data: Any, source: str = "nesting") -> Nesting:
    """Build a nesting from its JSON form; errors name the field and the sheet or placement at fault."""
    if not isinstance(data, dict) or data.get("schema") != SCHEMA:
        raise FablineError(f"{source}: not a {SCHEMA} file")
    if not isinstance(data.get("parts_file"), str):
        raise FablineError(f"{source}: missing 'parts_file'")
    if not data["parts_file"].strip() or "\0" in data["parts_file"]:
        fault = "holds a NUL byte, which no file name can" if "\0" in data["parts_file"] else "is empty"
        raise FablineError(f"{source}: parts_file: {data['parts_file']!r} {fault}: name the parts file, relative to "
                           "the nesting file's folder (parts.json)")
    sheets, stems = [], {}
    for i, raw in enumerate(_typed(data, "sheets", list, source)):
        raw = _object(raw, f"{source}: sheets[{i}]")
        if not isinstance(raw.get("id"), (str, int)) or isinstance(raw.get("id"), bool):
            raise FablineError(f"{source}: sheets[{i}]: 'id' must be a string or an integer")
        where = f"{source}: sheet {raw['id']}"
        sheet = Sheet(str(raw["id"]), _number(raw, "width", where), _number(raw, "height", where),
                      stock=str(raw.get("stock", "")))
        for k, p in enumerate(_typed(raw, "placements", list, where)):
            at = f"{where}: placements[{k}]"
            p = _object(p, at)
            if not isinstance(p.get("part"), (str, int)) or isinstance(p.get("part"), bool):
                raise FablineError(f"{at}: 'part' must name a part (a string)")
            sheet.placements.append(Placement(str(p["part"]), _number(p, "x", at), _number(p, "y", at),
                                              _number(p, "rotation", at, 0.0)))
        for k, c in enumerate(_typed(raw, "common_cuts", list, where)):
            at = f"{where}: common_cuts[{k}]"
            c = _object(c, at)
            parts = c.get("parts")
            if not isinstance(parts, list) or len(parts) != 2:
                raise FablineError(f"{at}: 'parts' must name two parts")
            sheet.common_cuts.append(CommonCut(tuple(map(str, parts)), _point(c, "start", at), _point(c, "end", at)))
        if sheet.width <= 0 or sheet.height <= 0:
            raise FablineError(f"{where}: width and height must be positive")
        stem = file_stem(sheet.id).casefold()
        if stem in stems:
            same = "the same id" if stems[stem] == sheet.id else f"sheet {stems[stem]}: both are file name {stem!r}"
            raise FablineError(f"{where}: collides with {same}; sheet ids must be unique as file names")
        stems[stem] = sheet.id
        sheets.append(sheet)
    if not sheets:
        raise FablineError(f"{source}: 'sheets' is empty: a nesting places its parts on at least one sheet")
    return Nesting(sheets, data["parts_file"], _number(data, "kerf", source, 0.0), _number(data, "gap", source, 0.0),
                   _number(data, "margin", source, 0.0), dict(_typed(data, "summary", dict, source)),
                   list(_typed(data, "remnants", list, source)))


def _typed(raw: dict, key: str, kind: type, where: str) -> Any:
    """raw[key], empty when absent, which must be a list or an object (`kind`)."""
    value = raw.get(key, kind())
    if not isinstance(value, kind):
        raise FablineError(f"{where}: '{key}' must be {'a list' if kind is list else 'an object'}")
    return value


def _object(raw: Any, where: str) -> dict:
    if not isinstance(raw, dict):
        raise FablineError(f"{where}: expected an object, got {raw!r}")
    return raw


def _number(raw: dict, key: str, where: str, default: float | None = None) -> float:
    """raw[key] as a float (`default` when absent; required when there is none): a finite number, at most MAX_MM
    in size (millimetres; degrees for a rotation)."""
    if key not in raw and default is None:
        raise FablineError(f"{where}: missing '{key}'")
    value = raw.get(key, default)
    if not finite_number(value, MAX_MM):
        raise FablineError(f"{where}: '{key}' must be a finite number of at most {MAX_MM:g} in size, got {value!r}")
    return float(value)


def _point(raw: dict, key: str, where: str) -> tuple[float, float]:
    value = raw.get(key)
    if not isinstance(value, list) or len(value) != 2 or not all(finite_number(v, MAX_MM) for v in value):
        raise FablineError(f"{where}: '{key}' must be [x, y], two finite numbers of at most {MAX_MM:g} mm")
    return float(value[0]), float(value[1])


def load_nesting(path: str | os.PathLike) -> Nesting:
    """Load a `fabline.nesting/1` file."""
    return nesting_from_dict(read_json(path), str(path))


def parts_path(nesting_path: str | os.PathLike, nesting: Nesting) -> Path:
    """Where the parts file of a nesting lies: `parts_file` resolved against the nesting file's folder."""
    return Path(nesting_path).parent / nesting.parts_file


def save_nesting(nesting: Nesting, path: str | os.PathLike) -> None:
    """Write a nesting atomically."""
    write_json(path, nesting_to_dict(nesting))
